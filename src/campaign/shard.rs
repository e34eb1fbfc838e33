//! Which flights of a campaign one copy of a job array processes.

use crate::config::FlightJob;
use crate::error::{Error, Result};

/// The environment variables a scheduler gives each task of an array its
/// index in, read in this order by `--shard auto/N`: Slurm job arrays,
/// Kubernetes Indexed Jobs, AWS Batch array jobs.
pub const SCHEDULER_INDEX_VARIABLES: [&str; 3] = [
    "SLURM_ARRAY_TASK_ID",
    "JOB_COMPLETION_INDEX",
    "AWS_BATCH_JOB_ARRAY_INDEX",
];

/// Shard `index` of `count`: the flights whose position in the campaign,
/// sorted by output name, is `index` modulo `count`.
///
/// Sorting by output name (the file stem, or the path when stems repeat)
/// makes the split the same on every machine and for every order the
/// flights were listed in, and round-robin keeps the shards within one
/// flight of each other in size.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Shard {
    /// K, from 0.
    pub index: usize,
    /// N, at least 1.
    pub count: usize,
}

impl Default for Shard {
    fn default() -> Self {
        Shard { index: 0, count: 1 }
    }
}

impl std::fmt::Display for Shard {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

impl Shard {
    /// Parses `K/N`, or `auto/N` with K from the first of
    /// [`SCHEDULER_INDEX_VARIABLES`] that `variable` gives. Slurm's index
    /// counts from `SLURM_ARRAY_TASK_MIN` when that is set, so
    /// `--array=1-N` works as well as `--array=0-(N-1)`.
    pub fn parse(text: &str, variable: impl Fn(&str) -> Option<String>) -> Result<Self> {
        let bad = |message: String| Error::Config {
            source_name: "--shard".into(),
            message,
        };
        let (index, count) = text
            .split_once('/')
            .ok_or_else(|| bad(format!("{text:?}: write K/N (e.g. 0/4) or auto/N")))?;
        let count: usize = count
            .trim()
            .parse()
            .ok()
            .filter(|&n| n >= 1)
            .ok_or_else(|| bad(format!("{text:?}: N must be a whole number of shards, at least 1")))?;
        let (index, from) = match index.trim() {
            "auto" => scheduler_index(&variable).map_err(bad)?,
            k => (
                k.parse::<usize>()
                    .map_err(|_| bad(format!("{text:?}: K must be a whole number from 0, or auto")))?,
                String::new(),
            ),
        };
        if index >= count {
            return Err(bad(format!(
                "{text:?}: shard {index}{from} is not below N = {count}; shards count from 0 to {} (Slurm: --array=0-{})",
                count - 1,
                count - 1
            )));
        }
        Ok(Shard { index, count })
    }

    /// The positions in `flights` of this shard's flights, in list order.
    pub fn select(&self, flights: &[FlightJob]) -> Vec<usize> {
        let mut order: Vec<usize> = (0..flights.len()).collect();
        order.sort_by(|&a, &b| {
            (&flights[a].output_name, &flights[a].input).cmp(&(&flights[b].output_name, &flights[b].input))
        });
        let mut mine: Vec<usize> = order
            .into_iter()
            .enumerate()
            .filter(|(position, _)| position % self.count == self.index)
            .map(|(_, flight)| flight)
            .collect();
        mine.sort_unstable();
        mine
    }
}

/// The array index the scheduler gave, and where it came from (for
/// messages).
fn scheduler_index(variable: &impl Fn(&str) -> Option<String>) -> std::result::Result<(usize, String), String> {
    for name in SCHEDULER_INDEX_VARIABLES {
        let Some(value) = variable(name) else { continue };
        let number = |text: &str| text.trim().parse::<usize>().ok();
        let index = number(&value).ok_or_else(|| format!("auto: {name} = {value:?} is not a whole number"))?;
        let first = match name {
            "SLURM_ARRAY_TASK_ID" => variable("SLURM_ARRAY_TASK_MIN").as_deref().and_then(number),
            _ => None,
        };
        return match first {
            Some(first) if first <= index => Ok((
                index - first,
                format!(" ({name} {index} − SLURM_ARRAY_TASK_MIN {first})"),
            )),
            Some(first) => Err(format!(
                "auto: {name} = {index} is below SLURM_ARRAY_TASK_MIN = {first}"
            )),
            None => Ok((index, format!(" (from {name})"))),
        };
    }
    Err(format!(
        "auto: none of {} is set; give the index yourself (--shard K/N), or run under a job array",
        SCHEDULER_INDEX_VARIABLES.join(", ")
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn env<'a>(pairs: &'a [(&'a str, &'a str)]) -> impl Fn(&str) -> Option<String> + 'a {
        move |name| pairs.iter().find(|(n, _)| *n == name).map(|(_, v)| v.to_string())
    }

    #[test]
    fn the_index_comes_from_the_argument_or_the_scheduler() {
        let none = env(&[]);
        assert_eq!(Shard::parse("2/3", &none).unwrap(), Shard { index: 2, count: 3 });
        assert_eq!(
            Shard::parse("auto/4", env(&[("JOB_COMPLETION_INDEX", "3")])).unwrap(),
            Shard { index: 3, count: 4 }
        );
        assert_eq!(
            Shard::parse("auto/4", env(&[("AWS_BATCH_JOB_ARRAY_INDEX", "0")])).unwrap(),
            Shard { index: 0, count: 4 }
        );
        // Slurm arrays numbered 1..N count from their minimum.
        let slurm = env(&[("SLURM_ARRAY_TASK_ID", "4"), ("SLURM_ARRAY_TASK_MIN", "1")]);
        assert_eq!(Shard::parse("auto/4", slurm).unwrap(), Shard { index: 3, count: 4 });
        for (text, says) in [
            ("3/3", "not below N = 3"),
            ("1/0", "at least 1"),
            ("x/3", "whole number from 0"),
            ("3", "write K/N"),
            ("auto/2", "none of SLURM_ARRAY_TASK_ID"),
        ] {
            let message = Shard::parse(text, &none).unwrap_err().to_string();
            assert!(message.contains(says), "{text}: {message}");
        }
        let late = env(&[("JOB_COMPLETION_INDEX", "5")]);
        assert!(Shard::parse("auto/5", late)
            .unwrap_err()
            .to_string()
            .contains("not below N = 5"));
    }

    #[test]
    fn the_shards_split_the_flights_exactly_once_whatever_their_order() {
        let names = ["e", "a", "d", "b", "c", "g", "f"];
        let flights: Vec<FlightJob> = names.iter().map(|n| FlightJob::new(format!("{n}.csv"))).collect();
        let mut reversed = flights.clone();
        reversed.reverse();
        for count in 1..=8 {
            let mut seen: Vec<String> = Vec::new();
            for index in 0..count {
                let shard = Shard { index, count };
                let mine: Vec<String> = shard
                    .select(&flights)
                    .into_iter()
                    .map(|i| flights[i].output_name.clone())
                    .collect();
                let mut again: Vec<String> = shard
                    .select(&reversed)
                    .into_iter()
                    .map(|i| reversed[i].output_name.clone())
                    .collect();
                let mut sorted = mine.clone();
                sorted.sort();
                again.sort();
                assert_eq!(sorted, again, "shard {shard}: the list's order changed the split");
                assert!(mine.len() <= names.len().div_ceil(count) && mine.len() >= names.len() / count);
                seen.extend(mine);
            }
            seen.sort();
            assert_eq!(seen, ["a", "b", "c", "d", "e", "f", "g"], "N = {count}");
        }
    }
}
