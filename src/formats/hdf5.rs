//! HDF5 flight logs in the MagNav challenge layout (pure Rust, `hdf5`
//! feature).
//!
//! The SGL / MagNav challenge files (`Flt1002_train.h5` and the like) hold
//! one one-dimensional dataset per field at the root, sampled at 10 Hz,
//! named with the SGL field names (`tt`, `mag_1_uc`, `flux_b_x`,
//! `ins_pitch`, …) plus a few scalars (`N`, `dt`). Every numeric dataset as
//! long as the time dataset becomes a channel; others are skipped. Older
//! files call the heading `ins_azim`; it maps to `ins_yaw`.

use std::path::Path;

use hdf5_pure::{DType, File, FileBuilder};

use super::columns::ColumnNames;
use super::destination::{stage, Staged};
use crate::compensate::Compensation;
use crate::error::{Error, Result};
use crate::ingest::flight_log::{Channel, FlightLog};
use crate::messages::{Reading, Warning};

/// Older MagNav files' names for CONTRACT names.
const ALIASES: [(&str, &str); 1] = [("ins_azim", "ins_yaw")];

fn corrupt(path: &Path, message: String) -> Error {
    Error::UnsupportedFormat {
        path: path.to_path_buf(),
        message,
    }
}

/// Reads an HDF5 flight log in the MagNav challenge layout.
pub fn read_hdf5(path: &Path, names: &ColumnNames) -> Result<FlightLog> {
    // A damaged file must give an error, whatever the reader does with it.
    let read = std::panic::catch_unwind(|| read_datasets(path, &names.time));
    let (time_s, datasets, warnings) = read.map_err(|_| {
        corrupt(
            path,
            "the HDF5 file is corrupt (its structure could not be parsed)".into(),
        )
    })??;
    let channels = datasets
        .into_iter()
        .filter_map(|(name, values)| {
            let name = ALIASES
                .iter()
                .find(|(old, _)| *old == name)
                .map_or(name, |(_, new)| new.to_string());
            let role = names.role_of(&name)?;
            Some(Channel { name, role, values })
        })
        .collect();
    Ok(FlightLog::new(path, names.time.clone(), time_s, channels)?.with_reading_warnings(warnings))
}

/// The time dataset, the channels' datasets, and what was not read.
type Datasets = (Vec<f64>, Vec<(String, Vec<f64>)>, Vec<Warning>);

/// The time dataset `time_name` of the HDF5 file at `path`, s; an error
/// when it is missing, cannot be decoded, or is empty.
fn read_time(file: &Decoders, path: &Path, time_name: &str) -> Result<Vec<f64>> {
    if file.pure.dataset(time_name).is_err() {
        return Err(Error::MissingColumn {
            path: path.to_path_buf(),
            role: "time",
            looked_for: format!("a root dataset '{time_name}'"),
            hint: "MagNav challenge files keep time in 'tt'; name another in [columns] time = \"...\".".into(),
        });
    }
    let time_s = file.read(time_name).map_err(|why| undecoded(path, time_name, &why))?;
    if time_s.is_empty() {
        return Err(Error::NoData {
            path: path.to_path_buf(),
            problem: format!("the time dataset '{time_name}' is empty"),
        });
    }
    Ok(time_s)
}

/// The file's two decoders: hdf5-pure, which reads the layouts MagNav's
/// files and magcomp's own use, and rust-hdf5, opened only when the first
/// cannot decode a dataset (HDF5 2.0's layout version 5, which h5py writes
/// with `libver="latest"`, and the szip and bitshuffle+LZ4 filters).
struct Decoders<'a> {
    path: &'a Path,
    pure: File,
    other: std::cell::OnceCell<std::result::Result<rust_hdf5::H5File, String>>,
}

impl Decoders<'_> {
    /// The dataset `name` as numbers, or both decoders' reasons why not
    /// (the second's last: it has the last word on the cause).
    fn read(&self, name: &str) -> std::result::Result<Vec<f64>, (String, String)> {
        let first = match self.pure.dataset(name).and_then(|d| d.read_f64()) {
            Ok(values) => return Ok(values),
            Err(e) => e.to_string(),
        };
        let other = self
            .other
            .get_or_init(|| rust_hdf5::H5File::open(self.path).map_err(|e| e.to_string()));
        let second = match other {
            Ok(file) => file
                .dataset(name)
                .map_err(|e| e.to_string())
                .and_then(|d| read_numbers(&d)),
            Err(why) => Err(why.clone()),
        };
        second.map_err(|second| (first, second))
    }
}

/// A one-dimensional numeric dataset read by rust-hdf5, as f64.
fn read_numbers(dataset: &rust_hdf5::H5Dataset) -> std::result::Result<Vec<f64>, String> {
    use rust_hdf5::{ByteOrder, DatatypeMessage as T};
    fn widened<V: rust_hdf5::types::H5Type + Copy + Into<f64>>(
        d: &rust_hdf5::H5Dataset,
    ) -> std::result::Result<Vec<f64>, String> {
        Ok(d.read_raw::<V>()
            .map_err(|e| e.to_string())?
            .into_iter()
            .map(Into::into)
            .collect())
    }
    fn wide<V: rust_hdf5::types::H5Type + Copy>(
        d: &rust_hdf5::H5Dataset,
        to: fn(V) -> f64,
    ) -> std::result::Result<Vec<f64>, String> {
        Ok(d.read_raw::<V>()
            .map_err(|e| e.to_string())?
            .into_iter()
            .map(to)
            .collect())
    }
    let datatype = dataset.datatype().map_err(|e| e.to_string())?;
    match datatype {
        T::FloatingPoint {
            size: 8,
            byte_order: ByteOrder::LittleEndian,
            ..
        } => widened::<f64>(dataset),
        T::FloatingPoint {
            size: 4,
            byte_order: ByteOrder::LittleEndian,
            ..
        } => widened::<f32>(dataset),
        T::FixedPoint {
            size,
            signed,
            byte_order: ByteOrder::LittleEndian,
            ..
        } => match (size, signed) {
            (1, true) => widened::<i8>(dataset),
            (1, false) => widened::<u8>(dataset),
            (2, true) => widened::<i16>(dataset),
            (2, false) => widened::<u16>(dataset),
            (4, true) => widened::<i32>(dataset),
            (4, false) => widened::<u32>(dataset),
            (8, true) => wide::<i64>(dataset, |v| v as f64),
            (8, false) => wide::<u64>(dataset, |v| v as f64),
            _ => Err(format!("{size}-byte integers are not read")),
        },
        other => Err(format!("its element type is not read ({})", type_words(&other))),
    }
}

/// A datatype in a few words.
fn type_words(datatype: &rust_hdf5::DatatypeMessage) -> String {
    let words = format!("{datatype:?}");
    words.split([' ', '{', '(']).next().unwrap_or_default().to_string()
}

/// Why dataset `name` of the file at `path` cannot be read, with the fix
/// that fits: a compression filter neither decoder has is named as such,
/// anything else is damage.
fn undecoded(path: &Path, name: &str, (first, second): &(String, String)) -> Error {
    let filter = (first.contains("unsupported filter") && second.contains("unsupported feature"))
        || second.contains("filter id");
    let why = format!("{first}; read again with a second decoder: {second}");
    let fix = match filter {
        true => "it is compressed with a filter magcomp does not decode (magcomp reads gzip/deflate, shuffle, \
                 fletcher32, lzf, szip, scale-offset and bitshuffle+LZ4): rewrite the file with one of those, for example \
                 `h5repack -f GZIP=4 in.h5 out.h5`",
        false => "the file is damaged or cut short: copy it again from its source",
    };
    corrupt(path, format!("dataset '{name}' cannot be read ({why}); {fix}"))
}

fn read_datasets(path: &Path, time_name: &str) -> Result<Datasets> {
    let pure = File::open(path).map_err(|e| corrupt(path, format!("not a readable HDF5 file: {e}")))?;
    let file = Decoders {
        path,
        pure,
        other: std::cell::OnceCell::new(),
    };
    let mut names = file
        .pure
        .root()
        .datasets()
        .map_err(|e| corrupt(path, format!("cannot list the root datasets: {e}")))?;
    names.sort();
    let time_s = read_time(&file, path, time_name)?;
    let mut not_read: Vec<String> = Vec::new();
    let series = sampled_series(&file.pure, names, time_name, &mut not_read);
    check_time_length(path, time_name, time_s.len(), &series)?;
    let mut datasets = Vec::new();
    for (name, samples) in series {
        if samples != time_s.len() {
            not_read.push(format!("'{name}' ({samples} samples, not {})", time_s.len()));
            continue;
        }
        let values = file.read(&name).map_err(|why| undecoded(path, &name, &why))?;
        datasets.push((name, values));
    }
    let warnings = match not_read.is_empty() {
        true => Vec::new(),
        false => vec![Reading::DatasetsNotRead {
            file: path.to_path_buf(),
            time: time_name.to_string(),
            datasets: not_read,
        }
        .into()],
    };
    Ok((time_s, datasets, warnings))
}

/// The root datasets `names` (but the time) that hold one number per
/// sample, with their lengths; single values (MagNav's N and dt) are
/// passed over, and the others named in `not_read` with why.
fn sampled_series(
    file: &File,
    names: Vec<String>,
    time_name: &str,
    not_read: &mut Vec<String>,
) -> Vec<(String, usize)> {
    let mut series = Vec::new();
    for name in names.into_iter().filter(|n| n != time_name) {
        let Ok(dataset) = file.dataset(&name) else {
            not_read.push(format!("'{name}' (unreadable)"));
            continue;
        };
        let numeric = matches!(
            dataset.dtype(),
            Ok(DType::F32
                | DType::F64
                | DType::I8
                | DType::I16
                | DType::I32
                | DType::I64
                | DType::U8
                | DType::U16
                | DType::U32
                | DType::U64)
        );
        let shape = dataset.shape().unwrap_or_default();
        let samples = shape.iter().product::<u64>() as usize;
        // Single values (MagNav's N and dt) describe the file, not a sample.
        if samples <= 1 {
            continue;
        }
        if !numeric || shape.len() != 1 {
            not_read.push(format!(
                "'{name}' ({})",
                if numeric {
                    "not one value per sample"
                } else {
                    "not numbers"
                }
            ));
            continue;
        }
        series.push((name, samples));
    }
    series
}

/// Refuses a time dataset whose length most of the file's series do not
/// share: the time, not the data, is then what is damaged, and reading
/// would drop every channel.
fn check_time_length(path: &Path, time_name: &str, time_samples: usize, series: &[(String, usize)]) -> Result<()> {
    let mut counts: std::collections::BTreeMap<usize, usize> = std::collections::BTreeMap::new();
    for (_, samples) in series {
        *counts.entry(*samples).or_default() += 1;
    }
    let Some((&common, &count)) = counts
        .iter()
        .max_by_key(|(length, count)| (**count, std::cmp::Reverse(**length)))
    else {
        return Ok(());
    };
    let matching = counts.get(&time_samples).copied().unwrap_or(0);
    if common == time_samples || count <= matching {
        return Ok(());
    }
    Err(corrupt(
        path,
        format!(
            "the time dataset '{time_name}' has {time_samples} samples, but {count} of the {} data datasets have {common}: \
             the time does not belong to the data, and reading it would drop every channel. Repair '{time_name}' (or name \
             the right time dataset in [columns] time = \"...\")",
            series.len()
        ),
    ))
}

/// Stages `log` in the MagNav challenge layout for `output`: one root
/// dataset per channel and for time, plus `N` (samples) and `dt` (median
/// interval, s). With a compensation, each compensated channel follows
/// under its `added` name (NaN where missing), then the flags as strings.
pub fn stage_hdf5(
    log: &FlightLog,
    added: &[String],
    output: &Path,
    compensation: Option<&Compensation>,
) -> Result<Staged> {
    let mut builder = FileBuilder::new();
    builder.create_dataset(log.time_column()).with_f64_data(log.time_s());
    for channel in log.channels() {
        builder.create_dataset(&channel.name).with_f64_data(&channel.values);
    }
    if let Some(compensation) = compensation {
        let values = compensation.value_columns();
        for (name, column) in added.iter().zip(&values) {
            builder.create_dataset(name).with_f64_data(column);
        }
        if let Some(flags) = added.get(values.len()) {
            let texts: Vec<String> = compensation.flags.iter().map(|f| f.to_string()).collect();
            let texts: Vec<&str> = texts.iter().map(String::as_str).collect();
            builder.create_dataset(flags).with_vlen_strings(&texts);
        }
    }
    builder.create_dataset("N").with_f64_data(&[log.len() as f64]);
    builder.create_dataset("dt").with_f64_data(&[log.median_interval_s()]);
    let bytes = builder
        .finish()
        .map_err(|e| Error::io(output, "encoding HDF5", std::io::Error::other(e.to_string())))?;
    stage(output, |w| std::io::Write::write_all(w, &bytes))
}
