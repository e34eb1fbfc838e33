//! Which flight a saved result was made on: file name, rows, time span and
//! a SHA-256 content hash (DIAGNOSIS.json's `flight`, CONTRACT §3).
//!
//! A diagnosis holds per-channel physics (a sensor's lag, a current's
//! coupling) of one aircraft on one day. Applied to another flight it
//! compensates with physics that flight may not have, so a saved diagnosis
//! records its flight and is refused on any other.

use std::io::Read;
use std::path::Path;

use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use crate::error::{Error, Result};
use crate::ingest::flight_log::FlightLog;

/// What was hashed for [`FlightIdentity::sha256`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum HashedContent {
    /// The input file's bytes (what `sha256sum FLIGHT` prints).
    File,
    /// The flight log as read (column names, times and values), for a log
    /// that did not come from a file.
    Log,
}

/// The flight a result was made on.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FlightIdentity {
    /// The input's file name, without its folder.
    pub file: String,
    /// Rows of the flight log.
    pub rows: usize,
    /// First time, in the file's time unit.
    pub t_start: f64,
    /// Last time.
    pub t_end: f64,
    /// SHA-256, lowercase hex.
    pub sha256: String,
    /// What the hash covers.
    #[serde(default = "file_content")]
    pub hashed: HashedContent,
}

fn file_content() -> HashedContent {
    HashedContent::File
}

impl FlightIdentity {
    /// The identity of `log`: its source file hashed when the file can be
    /// read, otherwise the log's own content.
    pub fn of(log: &FlightLog) -> Result<Self> {
        let source = log.source();
        let (sha256, hashed) = match source.is_file() {
            true => (hash_file(source)?, HashedContent::File),
            false => (hash_log(log), HashedContent::Log),
        };
        let time = log.time_s();
        Ok(FlightIdentity {
            file: source
                .file_name()
                .map_or_else(|| source.display().to_string(), |n| n.to_string_lossy().into_owned()),
            rows: log.len(),
            t_start: time.first().copied().unwrap_or(f64::NAN),
            t_end: time.last().copied().unwrap_or(f64::NAN),
            sha256,
            hashed,
        })
    }

    /// How `other` differs from this flight, in words; `None` when they
    /// are the same flight (same hash of the same kind of content).
    pub fn difference(&self, other: &FlightIdentity) -> Option<String> {
        if self.hashed == other.hashed && self.sha256 == other.sha256 {
            return None;
        }
        let mut differences = Vec::new();
        if self.rows != other.rows {
            differences.push(format!("{} rows against {}", self.rows, other.rows));
        }
        if self.t_start.to_bits() != other.t_start.to_bits() || self.t_end.to_bits() != other.t_end.to_bits() {
            differences.push(format!(
                "times {}–{} against {}–{}",
                self.t_start, self.t_end, other.t_start, other.t_end
            ));
        }
        differences.push(format!(
            "content hash {} against {}",
            short(&self.sha256),
            short(&other.sha256)
        ));
        Some(differences.join(", "))
    }

    /// "name (rows, t_start–t_end)".
    pub fn describe(&self) -> String {
        format!("{} ({} rows, {}–{})", self.file, self.rows, self.t_start, self.t_end)
    }
}

fn short(hash: &str) -> &str {
    &hash[..hash.len().min(12)]
}

fn hex(digest: &[u8]) -> String {
    digest.iter().map(|b| format!("{b:02x}")).collect()
}

/// SHA-256 of a file's bytes, read in 1 MiB blocks.
///
/// A run hashes its input up to three times (the campaign's status, the
/// diagnosis, the model file), each a pass over the whole file on one
/// core, so the process keeps the hashes of the files it read: a file
/// whose path, device, inode, size and modification time are all
/// unchanged is not read again. A write to the file moves its
/// modification time, and a file renamed over it has another inode; a
/// file modified less than `SETTLED` before it was hashed is not kept,
/// since a write within the file system's clock tick (milliseconds here,
/// seconds on some) may leave the time as it was.
pub fn hash_file(path: &Path) -> Result<String> {
    let key = FileKey::of(path).map_err(|e| Error::io(path, "reading (to hash)", e))?;
    if key.modified.is_none() {
        // Without a modification time a change may go unseen.
        return hash_bytes(path);
    }
    if let Some(hash) = HASHED.lock().ok().and_then(|known| known.get(&key).cloned()) {
        return Ok(hash);
    }
    let hashing = std::time::SystemTime::now();
    let hash = hash_bytes(path)?;
    // A file changed while it was hashed, or modified just before, gets no
    // entry: the next call hashes it again.
    let settled = key.modified.is_some_and(|m| m + SETTLED < hashing);
    if settled && FileKey::of(path).is_ok_and(|after| after == key) {
        if let Ok(mut known) = HASHED.lock() {
            if known.len() >= HASHES_KEPT {
                known.clear();
            }
            known.insert(key, hash.clone());
        }
    }
    Ok(hash)
}

/// How long before it is hashed a file must have been last modified for
/// its hash to be kept ([`hash_file`]).
const SETTLED: std::time::Duration = std::time::Duration::from_secs(3);

/// Files whose hashes a process keeps ([`hash_file`]).
const HASHES_KEPT: usize = 256;

static HASHED: std::sync::Mutex<std::collections::BTreeMap<FileKey, String>> =
    std::sync::Mutex::new(std::collections::BTreeMap::new());

/// What tells a file's content has not changed since it was hashed.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord)]
struct FileKey {
    path: std::path::PathBuf,
    device: u64,
    inode: u64,
    size: u64,
    modified: Option<std::time::SystemTime>,
}

impl FileKey {
    fn of(path: &Path) -> std::io::Result<Self> {
        let metadata = std::fs::metadata(path)?;
        #[cfg(unix)]
        let (device, inode) = {
            use std::os::unix::fs::MetadataExt;
            (metadata.dev(), metadata.ino())
        };
        #[cfg(not(unix))]
        let (device, inode) = (0, 0);
        Ok(FileKey {
            path: std::path::absolute(path)?,
            device,
            inode,
            size: metadata.len(),
            modified: metadata.modified().ok(),
        })
    }
}

/// SHA-256 of a file's bytes, read now.
fn hash_bytes(path: &Path) -> Result<String> {
    // A named pipe would block here until something wrote to it.
    let metadata = std::fs::metadata(path).map_err(|e| Error::io(path, "reading (to hash)", e))?;
    if !metadata.is_file() {
        return Err(Error::UnsupportedFormat {
            path: path.to_path_buf(),
            message: "not a regular file (a named pipe, a device or a folder): magcomp reads its inputs more than once, so copy it to a file and give that file".into(),
        });
    }
    let mut file = std::fs::File::open(path).map_err(|e| Error::io(path, "reading (to hash)", e))?;
    let mut hasher = Sha256::new();
    let mut block = vec![0u8; 1 << 20];
    loop {
        let read = file
            .read(&mut block)
            .map_err(|e| Error::io(path, "reading (to hash)", e))?;
        if read == 0 {
            break;
        }
        hasher.update(&block[..read]);
    }
    Ok(hex(&hasher.finalize()))
}

/// SHA-256 of the log's column names, times and values (IEEE-754 bits,
/// little-endian), for a log with no file behind it.
fn hash_log(log: &FlightLog) -> String {
    let mut hasher = Sha256::new();
    hasher.update(log.time_column().as_bytes());
    for t in log.time_s() {
        hasher.update(t.to_le_bytes());
    }
    for channel in log.channels() {
        hasher.update([0]);
        hasher.update(channel.name.as_bytes());
        for v in &channel.values {
            hasher.update(v.to_le_bytes());
        }
    }
    hex(&hasher.finalize())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_file_changed_since_it_was_hashed_is_hashed_again() -> std::result::Result<(), Box<dyn std::error::Error>> {
        let folder = tempfile::tempdir()?;
        let path = folder.path().join("flight.csv");
        let touch = |path: &Path, seconds: i64| -> std::io::Result<()> {
            let now = std::time::SystemTime::now();
            let shift = std::time::Duration::from_secs(seconds.unsigned_abs());
            let time = if seconds < 0 { now - shift } else { now + shift };
            std::fs::File::options().write(true).open(path)?.set_modified(time)
        };
        let abc = "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad";
        let abd = "a52d159f262b2c6ddb724a61840befc36eb30c88877a4030b65cbe86298449c9";
        // A file last modified an hour ago: its hash is kept.
        std::fs::write(&path, "abc")?;
        touch(&path, -3600)?;
        assert_eq!(hash_file(&path)?, abc);
        assert_eq!(hash_file(&path)?, abc, "the kept hash");
        // The same size, written in place, its time moved on.
        std::fs::write(&path, "abd")?;
        touch(&path, -1800)?;
        assert_eq!(hash_file(&path)?, abd);
        // Written in place within the same time, just now: not kept, so a
        // write within the clock's tick cannot leave a stale hash.
        std::fs::write(&path, "abc")?;
        let now = std::fs::metadata(&path)?.modified()?;
        assert_eq!(hash_file(&path)?, abc);
        std::fs::write(&path, "abd")?;
        std::fs::File::options().write(true).open(&path)?.set_modified(now)?;
        assert_eq!(hash_file(&path)?, abd, "a hash kept while the file was fresh");
        // Another file renamed over it.
        let other = folder.path().join("other.csv");
        std::fs::write(&other, "abc")?;
        std::fs::rename(&other, &path)?;
        assert_eq!(hash_file(&path)?, abc);
        Ok(())
    }

    #[test]
    fn the_hash_of_a_file_is_the_standard_sha256() -> std::result::Result<(), Box<dyn std::error::Error>> {
        // FIPS 180-2 test vector: SHA-256("abc").
        let dir = tempfile::tempdir()?;
        let path = dir.path().join("abc.txt");
        std::fs::write(&path, "abc")?;
        assert_eq!(
            hash_file(&path)?,
            "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
        );
        Ok(())
    }
}
