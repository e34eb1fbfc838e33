//! Where magcomp may write, and a command's outputs committed together.
//!
//! Every output is first written in full to a temporary file in its own
//! folder, named `.magcomp-<process id>@<host>-XXXXXX.tmp`, then renamed over the
//! destination ([`stage`], [`Staged::commit`]). A command stages all its
//! outputs before it renames any and renames the HTML report last
//! ([`OutputSet`]), so a run that fails part way leaves the previous run's
//! files as they were, and a new report means the whole set is new.
//!
//! Before any work, [`prepare`] checks every destination and refuses:
//! - an extension the output's writer does not produce (a flight written to
//!   `.json` or `.parquet`, a report to `.csv`);
//! - a path that is one of the command's inputs, or the same file under
//!   another name (a hard link);
//! - a symbolic link, a folder, a device, a FIFO or a socket;
//! - two outputs on one path;
//! - a folder that cannot be written.
//!
//! A missing folder is created and the user told so. Temporary files left
//! by a process that no longer runs are removed from each destination's
//! folder, once per command (a campaign's output folder may hold
//! thousands of files; it is not listed again for every output).

use std::collections::HashMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

use crate::error::{Error, Result};
use crate::messages::Setup;

/// What an output holds, which decides the extensions it may have.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OutputKind {
    /// A flight log, in the format its extension names: CSV (`.csv`,
    /// `.txt`), Geosoft XYZ, MCAP or (with the `hdf5` feature) HDF5.
    Flight,
    /// Comma-separated text.
    Csv,
    /// JSON.
    Json,
    /// An HTML page.
    Html,
}

impl OutputKind {
    /// The extensions (lowercase, without the dot) this kind is written as.
    pub fn extensions(self) -> &'static [&'static str] {
        match self {
            #[cfg(feature = "hdf5")]
            OutputKind::Flight => &["csv", "txt", "xyz", "mcap", "h5", "hdf5"],
            #[cfg(not(feature = "hdf5"))]
            OutputKind::Flight => &["csv", "txt", "xyz", "mcap"],
            OutputKind::Csv => &["csv"],
            OutputKind::Json => &["json"],
            OutputKind::Html => &["html", "htm"],
        }
    }

    fn describe(self) -> &'static str {
        match self {
            OutputKind::Flight => "a flight log",
            OutputKind::Csv => "comma-separated text",
            OutputKind::Json => "JSON",
            OutputKind::Html => "an HTML page",
        }
    }
}

/// One output a command is about to write.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Destination {
    /// Where it goes.
    pub path: PathBuf,
    /// What it holds.
    pub kind: OutputKind,
    /// What it is, or the option that named it ("--out"), for messages.
    pub named_by: String,
}

impl Destination {
    /// An output at `path` of `kind`, named by `named_by`.
    pub fn new(path: impl Into<PathBuf>, kind: OutputKind, named_by: impl Into<String>) -> Self {
        Destination {
            path: path.into(),
            kind,
            named_by: named_by.into(),
        }
    }
}

fn refuse(path: &Path, problem: impl Into<String>, hint: impl Into<String>) -> Error {
    Error::Output {
        path: path.to_path_buf(),
        problem: problem.into(),
        hint: hint.into(),
    }
}

/// Checks every destination of a command against its `inputs` and each
/// other, before any work is done; creates missing folders. Returns a
/// note for each folder created, for the user.
pub fn prepare(inputs: &[&Path], outputs: &[Destination]) -> Result<Vec<Setup>> {
    // A missing input stops the command before any folder is made.
    for input in inputs {
        std::fs::metadata(input).map_err(|e| Error::io(input, "opening", e))?;
    }
    for output in outputs {
        check_extension(output)?;
        check_name_length(output)?;
        check_not_special(&output.path)?;
        check_not_an_input(output, inputs)?;
    }
    check_distinct(outputs)?;
    let mut notes = Vec::new();
    let mut folders: Vec<PathBuf> = Vec::new();
    for output in outputs {
        let folder = folder_of(&output.path);
        if folders.contains(&folder) {
            continue;
        }
        if let Some(note) = create_folder(&folder, output)? {
            notes.push(note);
        }
        remove_stale_temporaries_once(&folder);
        check_writable(&folder, output)?;
        folders.push(folder);
    }
    Ok(notes)
}

/// Longest file name the common file systems take, bytes (ext4, XFS,
/// APFS, NTFS in UTF-16 units near enough).
const LONGEST_FILE_NAME: usize = 255;

/// Refuses a destination whose file name no file system takes, before
/// anything is written: a flight's outputs are committed together, and a
/// name derived from `--out` (its `_report.json`, say) can be longer than
/// the name given.
fn check_name_length(output: &Destination) -> Result<()> {
    let length = output.path.file_name().map_or(0, |n| n.as_encoded_bytes().len());
    if length <= LONGEST_FILE_NAME {
        return Ok(());
    }
    Err(refuse(
        &output.path,
        format!(
            "{}'s file name is {length} bytes, and file systems take at most {LONGEST_FILE_NAME}",
            output.named_by
        ),
        "Give a shorter output name (the report and JSON files add up to 20 bytes to it); nothing was written.",
    ))
}

fn check_extension(output: &Destination) -> Result<()> {
    let extension = super::lowercase_extension(&output.path);
    let allowed = output.kind.extensions();
    if allowed.contains(&extension.as_str()) {
        return Ok(());
    }
    let named = match extension.is_empty() {
        true => "no extension".to_string(),
        false => format!("the extension '.{extension}'"),
    };
    Err(refuse(
        &output.path,
        format!(
            "{} has {named}, and magcomp writes {} there, which it writes only as {}",
            output.named_by,
            output.kind.describe(),
            list_extensions(allowed)
        ),
        "Give a file name with one of those extensions; nothing was written.",
    ))
}

fn list_extensions(allowed: &[&str]) -> String {
    let dotted: Vec<String> = allowed.iter().map(|e| format!(".{e}")).collect();
    match dotted.split_last() {
        Some((last, rest)) if !rest.is_empty() => format!("{} or {last}", rest.join(", ")),
        _ => dotted.join(""),
    }
}

/// Refuses a destination that exists and is not a regular file: magcomp
/// never writes through a link or over a device, FIFO, socket or folder,
/// nor replaces a read-only file.
fn check_not_special(path: &Path) -> Result<()> {
    let Ok(metadata) = std::fs::symlink_metadata(path) else {
        return Ok(());
    };
    let file_type = metadata.file_type();
    let what = if file_type.is_symlink() {
        "a symbolic link; magcomp does not write through links"
    } else if file_type.is_dir() {
        "a folder"
    } else if !file_type.is_file() {
        "a device, FIFO or socket, not a regular file"
    } else if metadata.permissions().readonly() {
        // The rename that commits an output would replace it whatever its
        // mode (and root may write it anyway): its owner protected it.
        return Err(refuse(
            path,
            "the destination is read-only: its owner protected it, and magcomp does not replace it",
            "Make it writable if it may be replaced, or give another name; nothing was written.",
        ));
    } else {
        return Ok(());
    };
    Err(refuse(
        path,
        format!("the destination is {what}"),
        "Give the path of a regular file (or of one that does not exist yet); nothing was written.",
    ))
}

/// Refuses any of `outputs` that is one of `inputs` (the same file under
/// any name), without the other checks of [`prepare`].
pub fn refuse_inputs(inputs: &[&Path], outputs: &[Destination]) -> Result<()> {
    outputs.iter().try_for_each(|output| check_not_an_input(output, inputs))
}

fn check_not_an_input(output: &Destination, inputs: &[&Path]) -> Result<()> {
    let Ok(written) = std::fs::metadata(&output.path) else {
        return Ok(());
    };
    for input in inputs {
        let same = std::fs::metadata(input).is_ok_and(|read| same_file(&read, &written));
        if same {
            return Err(refuse(
                &output.path,
                format!(
                    "{} is the input {} (the same file), and writing it would replace the recording",
                    output.named_by,
                    input.display()
                ),
                "Write the output under another name; magcomp never writes over its input.",
            ));
        }
    }
    Ok(())
}

#[cfg(unix)]
fn same_file(a: &std::fs::Metadata, b: &std::fs::Metadata) -> bool {
    use std::os::unix::fs::MetadataExt;
    a.dev() == b.dev() && a.ino() == b.ino()
}

#[cfg(not(unix))]
fn same_file(a: &std::fs::Metadata, b: &std::fs::Metadata) -> bool {
    a.len() == b.len() && a.modified().ok() == b.modified().ok() && a.created().ok() == b.created().ok()
}

/// The path an output will have, with its folder resolved (links and `..`)
/// where the folder exists, so that two spellings of one path compare equal.
fn resolved(path: &Path) -> PathBuf {
    let folder = folder_of(path);
    let name = path.file_name().map(PathBuf::from).unwrap_or_default();
    match std::fs::canonicalize(&folder) {
        Ok(folder) => folder.join(name),
        Err(_) => std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf()),
    }
}

fn check_distinct(outputs: &[Destination]) -> Result<()> {
    let mut seen: HashMap<PathBuf, &str> = HashMap::new();
    for output in outputs {
        if let Some(first) = seen.insert(resolved(&output.path), &output.named_by) {
            return Err(refuse(
                &output.path,
                format!("{first} and {} name the same file", output.named_by),
                "Give each output its own path; nothing was written.",
            ));
        }
    }
    Ok(())
}

/// The folder `path` is written in (`.` for a bare file name).
pub fn folder_of(path: &Path) -> PathBuf {
    path.parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."))
        .to_path_buf()
}

fn create_folder(folder: &Path, output: &Destination) -> Result<Option<Setup>> {
    match std::fs::metadata(folder) {
        Ok(metadata) if metadata.is_dir() => Ok(None),
        Ok(_) => Err(refuse(
            &output.path,
            format!("{} is not a folder", folder.display()),
            "Give a path inside a folder; nothing was written.",
        )),
        Err(_) => {
            std::fs::create_dir_all(folder).map_err(|e| Error::io(folder, "creating the output folder", e))?;
            Ok(Some(Setup::FolderCreated {
                folder: folder.to_path_buf(),
                named_by: output.named_by.clone(),
            }))
        }
    }
}

fn check_writable(folder: &Path, output: &Destination) -> Result<()> {
    temporary_in(folder).map(drop).map_err(|e| {
        refuse(
            &output.path,
            format!("the folder {} cannot be written ({e})", folder.display()),
            "Choose a writable folder, or fix its permissions; nothing was written.",
        )
    })
}

/// The prefix of this process's temporary files:
/// `.magcomp-<process id>@<host>-`. The host matters when shards of a
/// campaign on several machines share one output folder: a process id
/// says whether a writer is alive only on its own machine.
fn temporary_prefix() -> String {
    format!(".magcomp-{}@{}-", std::process::id(), host_name())
}

/// This machine's name, with only the characters a file name keeps
/// everywhere (others become `_`); `host` when it cannot be read.
fn host_name() -> String {
    let name = read_host_name().unwrap_or_default();
    let name: String = name
        .chars()
        .map(|c| match c.is_ascii_alphanumeric() || c == '.' || c == '_' {
            true => c,
            false => '_',
        })
        .collect();
    match name.is_empty() {
        true => "host".into(),
        false => name,
    }
}

#[cfg(unix)]
fn read_host_name() -> Option<String> {
    let mut buffer = [0u8; 256];
    // SAFETY: the buffer is valid for its length; gethostname writes at
    // most that many bytes.
    let answer = unsafe { libc::gethostname(buffer.as_mut_ptr().cast(), buffer.len()) };
    if answer != 0 {
        return None;
    }
    let end = buffer.iter().position(|&b| b == 0).unwrap_or(buffer.len());
    Some(String::from_utf8_lossy(&buffer[..end]).into_owned())
}

#[cfg(not(unix))]
fn read_host_name() -> Option<String> {
    std::env::var("COMPUTERNAME").ok()
}

fn temporary_in(folder: &Path) -> std::io::Result<tempfile::NamedTempFile> {
    tempfile::Builder::new()
        .prefix(&temporary_prefix())
        .suffix(".tmp")
        .tempfile_in(folder)
}

/// [`remove_stale_temporaries`] the first time this process prepares
/// outputs in `folder`: a campaign prepares every flight's outputs in one
/// folder of thousands of files, and listing it each time would cost
/// flights × files.
fn remove_stale_temporaries_once(folder: &Path) {
    static CLEANED: std::sync::Mutex<Vec<PathBuf>> = std::sync::Mutex::new(Vec::new());
    let key = std::fs::canonicalize(folder).unwrap_or_else(|_| folder.to_path_buf());
    let mut cleaned = CLEANED.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
    if !cleaned.contains(&key) {
        remove_stale_temporaries(folder);
        cleaned.push(key);
    }
}

/// Removes magcomp's temporary files in `folder` whose process is gone: a
/// run killed while writing leaves its `.magcomp-<pid>@<host>-….tmp`
/// behind. Files of another machine (a shard sharing the folder), and of
/// older versions whose names carry no process id, are removed once a day
/// old. Errors are ignored: the files are only litter.
pub fn remove_stale_temporaries(folder: &Path) {
    let Ok(entries) = std::fs::read_dir(folder) else {
        return;
    };
    for entry in entries.flatten() {
        let name = entry.file_name();
        let Some(name) = name.to_str() else { continue };
        let Some(inner) = name.strip_prefix(".magcomp-").and_then(|n| n.strip_suffix(".tmp")) else {
            continue;
        };
        let stale = match writer(inner) {
            Some((pid, host)) if host.as_ref().is_none_or(|h| *h == host_name()) => !process_is_running(pid),
            // Another machine's writer, or a name of an older version
            // without a process id: litter once a day old.
            _ => older_than_a_day(&entry),
        };
        if stale {
            let _ = std::fs::remove_file(entry.path());
        }
    }
}

/// The process id and host in a temporary file's name between
/// `.magcomp-` and `.tmp`: `<pid>@<host>-<random>`, or `<pid>-<random>`
/// as earlier versions wrote (this machine's).
fn writer(inner: &str) -> Option<(u32, Option<String>)> {
    let (writer, _) = inner.rsplit_once('-')?;
    match writer.split_once('@') {
        Some((pid, host)) => Some((pid.parse().ok()?, Some(host.to_string()))),
        None => Some((writer.parse().ok()?, None)),
    }
}

#[cfg(unix)]
fn process_is_running(pid: u32) -> bool {
    if pid == std::process::id() {
        return true;
    }
    let Ok(pid) = libc::pid_t::try_from(pid) else {
        return false;
    };
    // SAFETY: signal 0 sends nothing; it only asks whether the process
    // exists. EPERM means it exists under another user.
    let answer = unsafe { libc::kill(pid, 0) };
    answer == 0 || std::io::Error::last_os_error().raw_os_error() == Some(libc::EPERM)
}

#[cfg(not(unix))]
fn process_is_running(_pid: u32) -> bool {
    true
}

fn older_than_a_day(entry: &std::fs::DirEntry) -> bool {
    entry
        .metadata()
        .and_then(|m| m.modified())
        .ok()
        .and_then(|t| t.elapsed().ok())
        .is_some_and(|age| age.as_secs() > 86_400)
}

/// An output written in full to a temporary file beside its destination,
/// not yet in place. Dropping it removes the temporary file.
#[must_use = "a staged output is written only when committed"]
#[derive(Debug)]
pub struct Staged {
    temporary: tempfile::NamedTempFile,
    path: PathBuf,
}

impl Staged {
    /// Where it will go.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Renames the temporary file over the destination.
    pub fn commit(self) -> Result<PathBuf> {
        check_not_special(&self.path)?;
        let path = self.path;
        self.temporary
            .persist(&path)
            .map_err(|e| Error::io(&path, "renaming the finished file into place", e.error))?;
        Ok(path)
    }
}

/// Writes `path`'s content to a temporary file in its folder: `write` fills
/// it. The folder must exist ([`prepare`] creates it).
pub fn stage(path: &Path, write: impl FnOnce(&mut BufWriter<&mut File>) -> std::io::Result<()>) -> Result<Staged> {
    check_not_special(path)?;
    let folder = folder_of(path);
    if !folder.is_dir() {
        return Err(refuse(
            path,
            format!("the folder {} does not exist", folder.display()),
            "Create it first; nothing was written.",
        ));
    }
    let mut temporary =
        temporary_in(&folder).map_err(|e| Error::io(&folder, "creating a temporary file in the folder", e))?;
    {
        let mut writer = BufWriter::with_capacity(1 << 20, temporary.as_file_mut());
        write(&mut writer)
            .and_then(|_| std::io::Write::flush(&mut writer))
            .map_err(|e| Error::io(path, "writing", e))?;
    }
    readable_by_all(temporary.as_file()).map_err(|e| Error::io(path, "setting the permissions", e))?;
    Ok(Staged {
        temporary,
        path: path.to_path_buf(),
    })
}

/// Temporary files are private (0600); outputs get the usual 0644.
#[cfg(unix)]
fn readable_by_all(file: &File) -> std::io::Result<()> {
    use std::os::unix::fs::PermissionsExt;
    file.set_permissions(std::fs::Permissions::from_mode(0o644))
}

#[cfg(not(unix))]
fn readable_by_all(_file: &File) -> std::io::Result<()> {
    Ok(())
}

/// The outputs of one command, staged and then committed together.
#[derive(Debug, Default)]
pub struct OutputSet {
    staged: Vec<Staged>,
    last: Vec<Staged>,
}

impl OutputSet {
    /// An empty set.
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds a staged output.
    pub fn add(&mut self, staged: Staged) {
        self.staged.push(staged);
    }

    /// Adds a staged output to be renamed after all others (the report).
    pub fn add_last(&mut self, staged: Staged) {
        self.last.push(staged);
    }

    /// Renames every staged output into place, the ones added last after
    /// the rest; returns their paths in that order.
    pub fn commit(self) -> Result<Vec<PathBuf>> {
        self.staged.into_iter().chain(self.last).map(Staged::commit).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn flight(path: &Path) -> Destination {
        Destination::new(path, OutputKind::Flight, "--out")
    }

    #[test]
    fn an_extension_the_writer_does_not_produce_is_refused() {
        let folder = tempfile::tempdir().unwrap();
        for name in ["out.json", "out.parquet", "out"] {
            let path = folder.path().join(name);
            let error = prepare(&[], &[flight(&path)]).unwrap_err().to_string();
            assert!(error.contains("only as .csv"), "{error}");
        }
        let report = folder.path().join("report.csv");
        let error = prepare(&[], &[Destination::new(&report, OutputKind::Html, "--html")]).unwrap_err();
        assert!(error.to_string().contains(".html or .htm"), "{error}");
        assert!(prepare(&[], &[flight(&folder.path().join("out.XYZ"))]).is_ok());
    }

    #[test]
    fn the_input_is_never_a_destination() {
        let folder = tempfile::tempdir().unwrap();
        let input = folder.path().join("flight.csv");
        std::fs::write(&input, "tt\n1\n").unwrap();
        let error = prepare(&[&input], &[flight(&input)]).unwrap_err().to_string();
        assert!(error.contains("same file"), "{error}");
        let alias = folder.path().join("alias.csv");
        std::fs::hard_link(&input, &alias).unwrap();
        assert!(prepare(&[&input], &[flight(&alias)]).is_err());
        assert_eq!(std::fs::read_to_string(&input).unwrap(), "tt\n1\n");
    }

    #[test]
    fn two_outputs_on_one_path_are_refused() {
        let folder = tempfile::tempdir().unwrap();
        let a = folder.path().join("x.json");
        let b = folder.path().join(".").join("x.json");
        let error = prepare(
            &[],
            &[
                Destination::new(&a, OutputKind::Json, "--report"),
                Destination::new(&b, OutputKind::Json, "--model"),
            ],
        )
        .unwrap_err()
        .to_string();
        assert!(error.contains("--report and --model name the same file"), "{error}");
    }

    #[cfg(unix)]
    #[test]
    fn links_and_devices_are_refused() {
        let folder = tempfile::tempdir().unwrap();
        let target = folder.path().join("target.csv");
        std::fs::write(&target, "kept").unwrap();
        let link = folder.path().join("link.csv");
        std::os::unix::fs::symlink(&target, &link).unwrap();
        assert!(prepare(&[], &[flight(&link)])
            .unwrap_err()
            .to_string()
            .contains("symbolic link"));
        let device = Path::new("/dev/null");
        assert!(check_not_special(device).unwrap_err().to_string().contains("device"));
        assert!(stage(&link, |_| Ok(())).is_err());
        assert_eq!(std::fs::read_to_string(&target).unwrap(), "kept");
    }

    #[test]
    fn a_missing_folder_is_created_and_named() {
        let folder = tempfile::tempdir().unwrap();
        let path = folder.path().join("new").join("out.csv");
        let notes = prepare(&[], &[flight(&path)]).unwrap();
        assert_eq!(
            notes,
            [Setup::FolderCreated {
                folder: folder.path().join("new"),
                named_by: "--out".into()
            }]
        );
        assert!(folder.path().join("new").is_dir());
    }

    #[test]
    fn a_set_is_committed_only_when_every_output_is_staged() {
        let folder = tempfile::tempdir().unwrap();
        let a = folder.path().join("a.csv");
        let b = folder.path().join("b.html");
        std::fs::write(&a, "old a").unwrap();
        std::fs::write(&b, "old b").unwrap();
        let mut set = OutputSet::new();
        set.add(stage(&a, |w| std::io::Write::write_all(w, b"new a")).unwrap());
        let failed = stage(&b, |_| Err(std::io::Error::other("disk full")));
        assert!(failed.is_err());
        drop(set);
        assert_eq!(std::fs::read_to_string(&a).unwrap(), "old a");
        let names: Vec<_> = std::fs::read_dir(folder.path()).unwrap().collect();
        assert_eq!(names.len(), 2, "no temporary file is left");

        let mut set = OutputSet::new();
        set.add_last(stage(&b, |w| std::io::Write::write_all(w, b"new b")).unwrap());
        set.add(stage(&a, |w| std::io::Write::write_all(w, b"new a")).unwrap());
        assert_eq!(set.commit().unwrap(), vec![a.clone(), b.clone()]);
        assert_eq!(std::fs::read_to_string(&b).unwrap(), "new b");
    }

    #[test]
    fn temporaries_of_dead_processes_are_removed() {
        let folder = tempfile::tempdir().unwrap();
        // Process ids are below 2^22 on Linux; this one cannot be running.
        let dead = folder.path().join(".magcomp-4294967-abc123.tmp");
        let alive = folder.path().join(format!("{}abc123.tmp", temporary_prefix()));
        let dead_here = folder
            .path()
            .join(format!(".magcomp-4294967@{}-abc123.tmp", host_name()));
        // A shard on another machine sharing the folder: its process id
        // means nothing here, and its file is young.
        let elsewhere = folder.path().join(".magcomp-4294967@another.host-abc123.tmp");
        let other = folder.path().join(".other-1-x.tmp");
        for path in [&dead, &dead_here, &alive, &elsewhere, &other] {
            std::fs::write(path, "x").unwrap();
        }
        remove_stale_temporaries(folder.path());
        assert!(!dead.exists() && !dead_here.exists());
        assert!(alive.exists() && elsewhere.exists());
        assert!(other.exists());
    }
}
