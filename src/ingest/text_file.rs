//! Reading a settings or results file whole, refusing what is no file.

use std::path::Path;

/// The whole text of a file magcomp reads at once (a pipeline or
/// manifest, a scenario, a model, windows, a plan, a status, a quality
/// JSON), refused with `InvalidInput` unless it is a regular file: a
/// named pipe would block the run until something wrote to it, and a
/// device never ends.
pub fn read_text(path: &Path) -> std::io::Result<String> {
    if !std::fs::metadata(path)?.is_file() {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            "not a regular file (a named pipe, a device or a folder); give the path of a file",
        ));
    }
    std::fs::read_to_string(path)
}
