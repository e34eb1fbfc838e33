//! Campaigns: one run or N shards in separate processes write the same
//! files, every flight exactly once; a killed shard redoes only its
//! unfinished flights; `summarize` merges the statuses.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::time::{Duration, Instant};

use magcomp::simulate::scenario::{RawScenario, Scenario};

fn magcomp(args: &[&str], env: &[(&str, &str)]) -> Output {
    let mut command = Command::new(env!("CARGO_BIN_EXE_magcomp"));
    command.args(args);
    for variable in magcomp::campaign::SCHEDULER_INDEX_VARIABLES {
        command.env_remove(variable);
    }
    command.envs(env.iter().copied());
    let output = command.output().unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!stderr.contains("panicked"), "magcomp panicked: {stderr}");
    output
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

/// A short simulated flight (one box, one survey line) of `seed`.
fn simulated(path: &Path, seed: u64) {
    let mut raw = RawScenario {
        seed,
        ..RawScenario::default()
    };
    raw.survey.line_count = 1;
    raw.survey.line_length_m = 3000.0;
    let flight = magcomp::simulate::simulate(&Scenario::try_from(raw).unwrap()).unwrap();
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    magcomp::formats::write_flight_log(&flight.log, path).unwrap();
}

/// A campaign folder: seven simulated flights, two of them in a manifest
/// with their aircraft and day, two sharing the stem `flight` in dated
/// folders, the rest swept by a pattern that also matches the manifest's;
/// and one file that is no flight. Returns the folder's pipeline files for
/// the output folders `one` and `three`.
fn campaign(folder: &Path) -> (PathBuf, PathBuf) {
    for (index, name) in ["flights/f1.csv", "flights/f2.csv", "flights/f3.csv", "flights/f4.csv"]
        .iter()
        .enumerate()
    {
        simulated(&folder.join(name), 31 + index as u64);
    }
    simulated(&folder.join("flights/2026-06-01/flight.csv"), 41);
    simulated(&folder.join("flights/2026-06-02/flight.csv"), 42);
    std::fs::write(folder.join("flights/broken.csv"), "tt,mag_1_uc\nnot,numbers\n").unwrap();
    std::fs::write(
        folder.join("manifest.csv"),
        "input,aircraft,date\n\
         flights/f1.csv,C-GMAG,2026-06-01\n\
         flights/f2.csv,C-GMAG,2026-06-03\n",
    )
    .unwrap();
    let config = |output: &str| {
        let path = folder.join(format!("{output}.toml"));
        let text = format!(
            "[output]\ndirectory = \"{output}\"\n\n\
             [campaign]\nmanifest = \"manifest.csv\"\ninputs = [\"flights/*.csv\", \"flights/*/flight.csv\"]\n"
        );
        std::fs::write(&path, text).unwrap();
        path
    };
    (config("one"), config("three"))
}

/// Every file of `folder` by name, status files with the fields that
/// differ run to run (wall time, shard) taken out.
fn contents(folder: &Path) -> BTreeMap<String, Vec<u8>> {
    let mut files = BTreeMap::new();
    for entry in std::fs::read_dir(folder).unwrap() {
        let path = entry.unwrap().path();
        let name = path.file_name().unwrap().to_string_lossy().into_owned();
        let mut bytes = std::fs::read(&path).unwrap();
        if name.ends_with("_status.json") {
            let mut status: serde_json::Value = serde_json::from_slice(&bytes).unwrap();
            let object = status.as_object_mut().unwrap();
            object.remove("elapsed_s").unwrap();
            object.remove("shard").unwrap();
            bytes = serde_json::to_vec_pretty(&status).unwrap();
        }
        files.insert(name, bytes);
    }
    files
}

/// Asserts that two output folders' [`contents`] hold the same files,
/// byte for byte.
fn same_files(a: &BTreeMap<String, Vec<u8>>, b: &BTreeMap<String, Vec<u8>>, between: &str) {
    assert_eq!(a.keys().collect::<Vec<_>>(), b.keys().collect::<Vec<_>>(), "{between}");
    for (name, bytes) in a {
        assert!(bytes == &b[name], "{name} differs between {between}");
    }
}

fn status(folder: &Path, flight: &str) -> serde_json::Value {
    let text = std::fs::read_to_string(folder.join(format!("{flight}_status.json"))).unwrap();
    serde_json::from_str(&text).unwrap()
}

const FLIGHTS: [&str; 7] = [
    "flights_2026-06-01_flight",
    "flights_2026-06-02_flight",
    "broken",
    "f1",
    "f2",
    "f3",
    "f4",
];

#[test]
fn three_shards_write_byte_for_byte_what_one_run_writes() {
    let folder = tempfile::tempdir().unwrap();
    let (one, three) = campaign(folder.path());

    // One flight at a time, and four at once: the same bytes.
    let single = magcomp(&["run", one.to_str().unwrap()], &[("RAYON_NUM_THREADS", "1")]);
    let four_config = folder.path().join("four.toml");
    let one_text = std::fs::read_to_string(&one).unwrap();
    std::fs::write(&four_config, one_text.replace("\"one\"", "\"four\"")).unwrap();
    let four = magcomp(&["run", four_config.to_str().unwrap()], &[("RAYON_NUM_THREADS", "4")]);
    assert!(
        text(&four.stdout).contains("7 flights, 4 at once: one for each of the 4 worker threads"),
        "{}",
        text(&four.stdout)
    );
    // The file that is no flight fails, alone, and says so.
    assert_ne!(single.status.code(), Some(0));
    assert!(
        text(&single.stderr).contains("1 of 7 flights failed"),
        "{}",
        text(&single.stderr)
    );

    // Three shards at once, as a job array starts them; one takes its
    // index from a Kubernetes Indexed Job's variable.
    let three_text = three.to_str().unwrap().to_string();
    let shards: Vec<std::thread::JoinHandle<Output>> = (0..3)
        .map(|k| {
            let config = three_text.clone();
            std::thread::spawn(move || match k {
                2 => magcomp(&["run", &config, "--shard", "auto/3"], &[("JOB_COMPLETION_INDEX", "2")]),
                _ => magcomp(&["run", &config, "--shard", &format!("{k}/3")], &[]),
            })
        })
        .collect();
    let outputs: Vec<Output> = shards.into_iter().map(|s| s.join().unwrap()).collect();
    for (k, output) in outputs.iter().enumerate() {
        assert!(
            text(&output.stdout).contains(&format!("shard {k}/3:")),
            "{}",
            text(&output.stdout)
        );
    }

    let (one_out, three_out) = (folder.path().join("one"), folder.path().join("three"));
    let (single_files, sharded_files) = (contents(&one_out), contents(&three_out));
    let four_files = contents(&folder.path().join("four"));
    same_files(&single_files, &four_files, "one and four flights at once");
    // The run's table lists the flights in the campaign's order, however
    // they finished.
    let table = |stdout: &[u8]| {
        let all = text(stdout);
        all[all.rfind("\nflight ").unwrap()..].to_string()
    };
    assert_eq!(table(&single.stdout), table(&four.stdout));
    same_files(&single_files, &sharded_files, "one run and three shards");
    // Every flight has its status, done by exactly one shard; the split
    // is within one flight of even.
    let mut per_shard = [0usize; 3];
    for flight in FLIGHTS {
        let done_by = status(&three_out, flight)["shard"].as_str().unwrap().to_string();
        let k: usize = done_by.split('/').next().unwrap().parse().unwrap();
        per_shard[k] += 1;
        assert_eq!(status(&one_out, flight)["shard"], "0/1");
    }
    assert_eq!(per_shard.iter().sum::<usize>(), 7);
    assert!(per_shard.iter().all(|&n| n == 2 || n == 3), "{per_shard:?}");
    assert_eq!(status(&one_out, "broken")["state"], "failed");
    assert_eq!(status(&one_out, "f3")["state"], "done");
    assert_eq!(status(&one_out, "f1")["aircraft"], "C-GMAG");

    // The summaries of both are the same bytes, and say what happened.
    for out in [&one_out, &three_out] {
        let summary = magcomp(&["summarize", out.to_str().unwrap()], &[]);
        assert_eq!(summary.status.code(), Some(0), "{}", text(&summary.stderr));
        assert!(text(&summary.stdout).contains("7 flights: 6 done, 1 failed"));
    }
    for name in [
        "campaign_summary.csv",
        "campaign_summary.html",
        "campaign_coefficients.csv",
    ] {
        let (a, b) = (
            std::fs::read(one_out.join(name)).unwrap(),
            std::fs::read(three_out.join(name)).unwrap(),
        );
        assert!(a == b, "{name} differs");
    }
    let table = std::fs::read_to_string(one_out.join("campaign_summary.csv")).unwrap();
    let rows: Vec<&str> = table.lines().collect();
    // Six flights of two scalar channels each, and the failed one.
    assert_eq!(rows.len(), 1 + 6 * 2 + 1, "{table}");
    let broken = rows.iter().find(|r| r.starts_with("broken,")).unwrap();
    assert!(broken.contains(",failed,"), "{broken}");
    // The aircraft named twice is followed over time, in date order.
    let coefficients = std::fs::read_to_string(one_out.join("campaign_coefficients.csv")).unwrap();
    let flights: Vec<&str> = coefficients
        .lines()
        .skip(1)
        .map(|l| l.split(',').nth(2).unwrap())
        .collect();
    assert!(flights.iter().all(|f| *f == "f1" || *f == "f2"), "{coefficients}");
    let first_f2 = flights.iter().position(|f| *f == "f2").unwrap();
    assert!(flights[..first_f2].iter().all(|f| *f == "f1") && first_f2 > 0);
}

#[test]
fn a_killed_run_redoes_only_its_unfinished_flights() {
    let folder = tempfile::tempdir().unwrap();
    let (one, _) = campaign(folder.path());
    let out = folder.path().join("one");
    let config = one.to_str().unwrap();

    // Kill the run as soon as its first flight is done.
    let mut child = Command::new(env!("CARGO_BIN_EXE_magcomp"))
        .args(["run", config])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let started = Instant::now();
    let finished = |out: &Path| -> Vec<String> {
        FLIGHTS
            .iter()
            .filter(|f| out.join(format!("{f}_status.json")).exists())
            .map(|f| f.to_string())
            .collect()
    };
    while finished(&out).is_empty() && started.elapsed() < Duration::from_secs(300) {
        std::thread::sleep(Duration::from_millis(5));
    }
    child.kill().unwrap();
    child.wait().unwrap();
    let before_kill = finished(&out);
    assert!(
        !before_kill.is_empty() && before_kill.len() < FLIGHTS.len(),
        "{before_kill:?}"
    );
    let kept: BTreeMap<String, Vec<u8>> = before_kill
        .iter()
        .map(|f| (f.clone(), std::fs::read(out.join(format!("{f}_status.json"))).unwrap()))
        .collect();

    // Run again: the finished flights are skipped (their statuses keep
    // their bytes, wall time included); every other one is done now.
    let again = magcomp(&["run", config], &[]);
    let stdout = text(&again.stdout);
    for flight in FLIGHTS {
        let status_bytes = std::fs::read(out.join(format!("{flight}_status.json"))).unwrap();
        match kept.get(flight) {
            Some(bytes) if flight != "broken" => {
                assert!(&status_bytes == bytes, "{flight} was redone");
            }
            _ => assert!(status(&out, flight)["state"].is_string()),
        }
    }
    let skipped = stdout.matches("up to date, skipped").count();
    assert_eq!(
        skipped,
        before_kill.iter().filter(|f| *f != "broken").count(),
        "{stdout}"
    );
    // No temporary file of the killed run is left.
    let litter: Vec<String> = std::fs::read_dir(&out)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".tmp"))
        .collect();
    assert!(litter.is_empty(), "{litter:?}");

    // A third run does nothing but the failed flight; a changed input is
    // redone; --force redoes everything.
    let third = text(&magcomp(&["run", config], &[]).stdout);
    assert_eq!(third.matches("up to date, skipped").count(), 6, "{third}");
    simulated(&folder.path().join("flights/f3.csv"), 99);
    let fourth = text(&magcomp(&["run", config], &[]).stdout);
    assert_eq!(fourth.matches("up to date, skipped").count(), 5, "{fourth}");
    assert!(!fourth.contains("flights/f3.csv: outputs current"), "{fourth}");
    let forced = text(&magcomp(&["run", config, "--force"], &[]).stdout);
    assert_eq!(forced.matches("up to date, skipped").count(), 0, "{forced}");
}

/// `examples/slurm/run.sbatch` run by bash as three array tasks would, and
/// the command of `examples/k8s/indexed-job.yaml` as three pods would: both
/// write what one run writes.
#[test]
fn the_slurm_and_kubernetes_examples_split_the_campaign_as_their_schedulers_would() {
    let folder = tempfile::tempdir().unwrap();
    let (slurm_config, k8s_config) = campaign(folder.path());
    let examples = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples");
    let binary_folder = Path::new(env!("CARGO_BIN_EXE_magcomp")).parent().unwrap();
    let path = format!(
        "{}:{}",
        binary_folder.display(),
        std::env::var("PATH").unwrap_or_default()
    );

    // The Slurm script, one array task at a time (an array numbered 1..3).
    for task in 1..=3 {
        let output = Command::new("bash")
            .arg(examples.join("slurm/run.sbatch"))
            .env("PATH", &path)
            .env("SLURM_ARRAY_TASK_ID", task.to_string())
            .env("SLURM_ARRAY_TASK_MIN", "1")
            .env("SLURM_ARRAY_TASK_COUNT", "3")
            .env("SLURM_CPUS_PER_TASK", "1")
            .env("SLURM_SUBMIT_DIR", folder.path())
            .env("MAGCOMP_CONFIG", &slurm_config)
            .env_remove("JOB_COMPLETION_INDEX")
            .output()
            .unwrap();
        assert!(
            text(&output.stdout).contains(&format!("shard {}/3:", task - 1)),
            "{}{}",
            text(&output.stdout),
            text(&output.stderr)
        );
    }

    // The Indexed Job's command, its N matching its completions, run once
    // per index with the volume's path made this folder's.
    let job = std::fs::read_to_string(examples.join("k8s/indexed-job.yaml")).unwrap();
    let field = |name: &str| -> String {
        let line = job
            .lines()
            .find(|l| l.trim_start().starts_with(&format!("{name}:")))
            .unwrap();
        line.split_once(':').unwrap().1.trim().to_string()
    };
    let command: Vec<String> = serde_json::from_str(&field("command")).unwrap();
    let completions: usize = field("completions").parse().unwrap();
    assert_eq!(command[..3], ["magcomp", "run", "/campaign/pipeline.toml"]);
    assert_eq!(command[3..], ["--shard".to_string(), format!("auto/{completions}")]);
    for index in 0..3 {
        let output = Command::new(&command[0])
            .arg(&command[1])
            .arg(&k8s_config)
            .args(["--shard", "auto/3"])
            .env("PATH", &path)
            .env("JOB_COMPLETION_INDEX", index.to_string())
            .env_remove("SLURM_ARRAY_TASK_ID")
            .output()
            .unwrap();
        assert!(
            text(&output.stdout).contains(&format!("shard {index}/3:")),
            "{}",
            text(&output.stderr)
        );
    }

    let (slurm, k8s) = (
        contents(&folder.path().join("one")),
        contents(&folder.path().join("three")),
    );
    let statuses = slurm.keys().filter(|n| n.ends_with("_status.json")).count();
    assert_eq!(statuses, FLIGHTS.len());
    assert!(slurm == k8s, "the two schedulers' splits wrote different files");
}

/// One input left under two output names (a flight renamed when another
/// with its stem left the campaign, as `a/flight.csv` goes from
/// `a_flight` to `flight`) is one flight the table would count twice:
/// `summarize` names both outputs and the input they share, and a
/// campaign of distinct flights gets no such line.
#[test]
fn summarize_names_one_input_counted_under_two_names() {
    let folder = tempfile::tempdir().unwrap();
    let folder = folder.path();
    simulated(&folder.join("a/flight.csv"), 51);
    simulated(&folder.join("b/flight.csv"), 52);
    let config = folder.join("pipeline.toml");
    std::fs::write(
        &config,
        "[output]\ndirectory = \"out\"\n[campaign]\ninputs = [\"*/flight.csv\"]\n[diagnose]\napply = \"never\"\n",
    )
    .unwrap();
    let out = folder.join("out");
    let run = || {
        let output = magcomp(&["run", config.to_str().unwrap()], &[]);
        assert!(output.status.success(), "{}", text(&output.stderr));
    };
    let summarize = || {
        let output = magcomp(&["summarize", out.to_str().unwrap()], &[]);
        assert!(output.status.success(), "{}", text(&output.stderr));
        text(&output.stdout)
    };
    run();
    let first = summarize();
    println!("{first}");
    assert!(!first.contains("has the same content"), "{first}");
    std::fs::remove_dir_all(folder.join("b")).unwrap();
    run();
    assert!(out.join("flight_status.json").exists() && out.join("a_flight_status.json").exists());
    let second = summarize();
    println!("{second}");
    assert!(second.contains("warning: a_flight: its input"), "{second}");
    assert!(second.contains("has the same content as that of 'flight'"), "{second}");
    assert!(second.contains("warning: flight: its input"), "{second}");
    assert!(!second.contains("warning: b_flight: its input"), "{second}");
}

/// A done flight whose quality JSON lists no channel keeps its row in the
/// summary, with the reason in words, not a row of blanks.
#[test]
fn summarize_names_a_done_flight_without_channels() {
    let folder = tempfile::tempdir().unwrap();
    let folder = folder.path();
    simulated(&folder.join("flight.csv"), 53);
    let config = folder.join("pipeline.toml");
    std::fs::write(
        &config,
        "[output]\ndirectory = \"out\"\n[campaign]\ninputs = [\"flight.csv\"]\n[diagnose]\napply = \"never\"\n",
    )
    .unwrap();
    let output = magcomp(&["run", config.to_str().unwrap()], &[]);
    assert!(output.status.success(), "{}", text(&output.stderr));
    let out = folder.join("out");
    let quality_path = out.join("flight_quality.json");
    let mut quality: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&quality_path).unwrap()).unwrap();
    assert!(!quality["channels"].as_array().unwrap().is_empty());
    quality["channels"] = serde_json::json!([]);
    std::fs::write(&quality_path, serde_json::to_string(&quality).unwrap()).unwrap();
    let output = magcomp(&["summarize", out.to_str().unwrap()], &[]);
    assert!(output.status.success(), "{}", text(&output.stderr));
    let summary = text(&output.stdout);
    println!("{summary}");
    assert!(
        summary.contains("flight_quality.json lists no compensated channel"),
        "{summary}"
    );
}

/// A `**` pattern walks a folder with links back up (two at one level, so
/// that following them would list without end) once, and a pipeline named
/// by a relative path finds the flights its patterns match beside it.
#[test]
#[cfg(unix)]
fn a_glob_through_looping_links_lists_each_flight_once_from_a_relative_pipeline() {
    let folder = tempfile::tempdir().unwrap();
    let campaign = folder.path().join("survey");
    simulated(&campaign.join("flights/day1/a.csv"), 61);
    simulated(&campaign.join("flights/b.csv"), 62);
    std::os::unix::fs::symlink(".", campaign.join("flights/loop1")).unwrap();
    std::os::unix::fs::symlink("..", campaign.join("flights/day1/loop2")).unwrap();
    std::os::unix::fs::symlink("../..", campaign.join("flights/day1/loop3")).unwrap();
    std::fs::write(
        campaign.join("pipeline.toml"),
        "[output]\ndirectory = \"out\"\n[campaign]\ninputs = [\"flights/**/*.csv\"]\n[diagnose]\napply = \"never\"\n",
    )
    .unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_magcomp"))
        .args(["run", "survey/pipeline.toml"])
        .current_dir(folder.path())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let started = Instant::now();
    while child.try_wait().unwrap().is_none() {
        if started.elapsed() > Duration::from_secs(120) {
            child.kill().unwrap();
            panic!("magcomp run walked the looping links for over 120 s");
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    let output = child.wait_with_output().unwrap();
    assert!(
        output.status.success(),
        "{}\n{}",
        text(&output.stdout),
        text(&output.stderr)
    );
    let mut statuses: Vec<String> = std::fs::read_dir(campaign.join("out"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|name| name.ends_with("_status.json"))
        .collect();
    statuses.sort();
    assert_eq!(statuses, ["a_status.json", "b_status.json"], "{}", text(&output.stdout));
}
