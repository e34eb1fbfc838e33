//! Every way an output could destroy data or land in the wrong format is
//! refused before any work, and a run's outputs are committed together.

use std::path::{Path, PathBuf};
use std::process::Command;

use magcomp::simulate::sample_flight::{generate, write, SampleFlightSpec};

fn small_flight(folder: &Path) -> PathBuf {
    let spec = SampleFlightSpec {
        line_count: 1,
        line_duration_s: 60.0,
        ..SampleFlightSpec::default()
    };
    let csv = folder.join("flight.csv");
    write(&generate(&spec, 3), &csv, &folder.join("flight.windows.json")).unwrap();
    csv
}

/// Runs magcomp in `folder`; returns success and stdout + stderr.
fn magcomp(folder: &Path, args: &[&str]) -> (bool, String) {
    let output = Command::new(env!("CARGO_BIN_EXE_magcomp"))
        .current_dir(folder)
        .args(args)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&output.stdout).into_owned() + &String::from_utf8_lossy(&output.stderr);
    (output.status.success(), text)
}

fn names_in(folder: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(folder)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    names
}

/// Asserts the command fails, names `named` in its message and leaves the
/// folder's files as they were.
fn assert_refused(folder: &Path, args: &[&str], named: &str) {
    let before: Vec<(String, Vec<u8>)> = names_in(folder)
        .into_iter()
        .filter(|n| Path::new(folder).join(n).is_file())
        .map(|n| {
            let bytes = std::fs::read(folder.join(&n)).unwrap();
            (n, bytes)
        })
        .collect();
    let (ok, text) = magcomp(folder, args);
    assert!(!ok, "magcomp {args:?} succeeded:\n{text}");
    assert!(text.contains(named), "magcomp {args:?} does not name {named}:\n{text}");
    assert!(
        text.contains("nothing was written") || text.contains("never writes over"),
        "{text}"
    );
    for (name, bytes) in before {
        assert_eq!(std::fs::read(folder.join(&name)).unwrap(), bytes, "{name} changed");
    }
}

#[test]
fn the_input_is_never_written_over() {
    let folder = tempfile::tempdir().unwrap();
    small_flight(folder.path());
    let dir = folder.path();
    assert_refused(dir, &["compensate", "flight.csv", "--out", "flight.csv"], "flight.csv");
    assert_refused(
        dir,
        &["compensate", "flight.csv", "--out", "./flight.csv"],
        "flight.csv",
    );
    assert_refused(dir, &["convert", "flight.csv", "--out", "flight.csv"], "flight.csv");
    std::fs::hard_link(dir.join("flight.csv"), dir.join("alias.csv")).unwrap();
    assert_refused(dir, &["compensate", "flight.csv", "--out", "alias.csv"], "alias.csv");
    assert_refused(
        dir,
        &[
            "compensate",
            "flight.csv",
            "--out",
            "o.csv",
            "--windows-file",
            "flight.windows.json",
            "--model",
            "flight.windows.json",
        ],
        "flight.windows.json",
    );
    // A settings file that happens to end in .json is an input too.
    std::fs::write(dir.join("settings.json"), "[detect]\nmin_leg_s = 40.0\n").unwrap();
    assert_refused(
        dir,
        &[
            "detect",
            "flight.csv",
            "--out",
            "settings.json",
            "--config",
            "settings.json",
        ],
        "same file",
    );
}

#[test]
fn two_outputs_on_one_path_are_refused() {
    let folder = tempfile::tempdir().unwrap();
    small_flight(folder.path());
    let dir = folder.path();
    assert_refused(
        dir,
        &[
            "compensate",
            "flight.csv",
            "--out",
            "o.csv",
            "--model",
            "m.json",
            "--report",
            "m.json",
        ],
        "name the same file",
    );
    // The report's figures go beside the page, as r.json.
    assert_refused(
        dir,
        &[
            "compensate",
            "flight.csv",
            "--out",
            "o.csv",
            "--html",
            "r.html",
            "--report",
            "r.json",
        ],
        "name the same file",
    );
    assert_refused(
        dir,
        &["diagnose", "flight.csv", "--out", "d.json", "--html", "d.json"],
        "d.json",
    );
}

#[test]
fn the_format_follows_the_extension_or_nothing_is_written() {
    let folder = tempfile::tempdir().unwrap();
    small_flight(folder.path());
    let dir = folder.path();
    for out in ["o.json", "o.parquet", "o", "o.html"] {
        assert_refused(dir, &["compensate", "flight.csv", "--out", out], "only as .csv");
        assert!(!dir.join(out).exists());
    }
    assert_refused(dir, &["convert", "flight.csv", "--out", "o.parquet"], "o.parquet");
    assert_refused(dir, &["detect", "flight.csv", "--out", "d.csv"], "only as .json");
    assert_refused(
        dir,
        &["compensate", "flight.csv", "--out", "o.csv", "--html", "r.pdf"],
        "r.pdf",
    );
    assert_refused(
        dir,
        &["compensate", "flight.csv", "--out", "o.csv", "--report", "q.csv"],
        "q.csv",
    );
    let scenario = Path::new(env!("CARGO_MANIFEST_DIR")).join("sample_flights/scenarios/clean.toml");
    assert_refused(
        dir,
        &["simulate", scenario.to_str().unwrap(), "--out", "s.parquet"],
        "s.parquet",
    );

    // HDF5 output is HDF5: the signature, and the compensated column read back.
    let (ok, text) = magcomp(dir, &["compensate", "flight.csv", "--out", "o.h5", "--plain"]);
    assert!(ok, "{text}");
    let bytes = std::fs::read(dir.join("o.h5")).unwrap();
    assert_eq!(&bytes[..8], b"\x89HDF\r\n\x1a\n", "o.h5 is not HDF5");
    let log = magcomp::formats::read_flight_log(&dir.join("o.h5"), &Default::default()).unwrap();
    let csv = magcomp::formats::read_flight_log(&dir.join("flight.csv"), &Default::default()).unwrap();
    assert_eq!(log.len(), csv.len());
    assert!(log.channel("mag_1_c").is_some(), "the compensated channel is in o.h5");
}

#[cfg(unix)]
#[test]
fn links_fifos_and_devices_are_never_written() {
    let folder = tempfile::tempdir().unwrap();
    small_flight(folder.path());
    let dir = folder.path();
    std::fs::write(dir.join("target.csv"), "kept\n").unwrap();
    std::os::unix::fs::symlink(dir.join("target.csv"), dir.join("link.csv")).unwrap();
    assert_refused(dir, &["compensate", "flight.csv", "--out", "link.csv"], "symbolic link");
    assert!(std::fs::symlink_metadata(dir.join("link.csv"))
        .unwrap()
        .file_type()
        .is_symlink());
    let fifo = dir.join("fifo.csv");
    let made = Command::new("mkfifo").arg(&fifo).status();
    match made {
        Ok(status) if status.success() => {
            assert_refused(dir, &["compensate", "flight.csv", "--out", "fifo.csv"], "FIFO");
        }
        _ => {
            println!("mkfifo is not available: the FIFO case was not run (the device case below covers special files)")
        }
    }
    let (ok, text) = magcomp(dir, &["detect", "flight.csv", "--out", "/dev/full"]);
    assert!(!ok && text.contains("/dev/full"), "{text}");
    assert!(
        !std::fs::metadata("/dev/full").unwrap().is_file(),
        "/dev/full is still a device"
    );
}

#[test]
fn a_missing_folder_is_created_and_said() {
    let folder = tempfile::tempdir().unwrap();
    small_flight(folder.path());
    let (ok, text) = magcomp(folder.path(), &["detect", "flight.csv", "--out", "new/folder/d.json"]);
    assert!(ok, "{text}");
    assert!(text.contains("created the folder new/folder"), "{text}");
    assert!(folder.path().join("new/folder/d.json").is_file());
}

#[test]
fn a_missing_input_makes_no_folder() {
    let folder = tempfile::tempdir().unwrap();
    for args in [
        &["compensate", "absent.csv", "--out", "new/o.csv"][..],
        &["detect", "absent.csv", "--out", "new/d.json"][..],
        &["diagnose", "absent.csv", "--out", "new/d.json"][..],
    ] {
        let (ok, text) = magcomp(folder.path(), args);
        assert!(!ok, "{args:?}: {text}");
        assert!(
            text.contains("absent.csv") && text.contains("Check that the path exists"),
            "{args:?}: {text}"
        );
        assert!(
            !folder.path().join("new").exists(),
            "{args:?} made the output folder: {text}"
        );
    }
}

#[test]
fn a_failed_run_leaves_the_previous_outputs_and_no_temporary_files() {
    let folder = tempfile::tempdir().unwrap();
    small_flight(folder.path());
    let dir = folder.path();
    let args = [
        "compensate",
        "flight.csv",
        "--out",
        "out/o.csv",
        "--model",
        "out/m.json",
        "--plain",
    ];
    let (ok, text) = magcomp(dir, &args);
    assert!(ok, "{text}");
    let before = names_in(&dir.join("out"));
    assert_eq!(before, ["m.json", "o.csv", "o_report.html", "o_report.json"]);
    let csv = std::fs::read(dir.join("out/o.csv")).unwrap();
    // A killed run leaves its temporary file; the process is gone.
    let stale = dir.join("out/.magcomp-4194999-abcdef.tmp");
    std::fs::write(&stale, "partial").unwrap();
    // The report's folder is a file: the run fails before anything is
    // written, whoever runs the test (root can write a read-only folder).
    std::fs::write(dir.join("blocked"), "").unwrap();
    let (ok, text) = magcomp(dir, &[&args[..], &["--html", "blocked/r.html"]].concat());
    assert!(!ok, "{text}");
    assert!(text.contains("blocked"), "{text}");
    assert_eq!(std::fs::read(dir.join("out/o.csv")).unwrap(), csv);
    assert_eq!(
        names_in(&dir.join("out")),
        before,
        "the stale temporary file is removed, nothing else changes"
    );
}

#[test]
fn a_killed_run_never_pairs_a_new_report_with_old_data() {
    let folder = tempfile::tempdir().unwrap();
    small_flight(folder.path());
    let dir = folder.path();
    let args = ["compensate", "flight.csv", "--out", "o.csv", "--plain"];
    let (ok, text) = magcomp(dir, &args);
    assert!(ok, "{text}");
    let modified = |name: &str| std::fs::metadata(dir.join(name)).unwrap().modified().unwrap();
    for delay_ms in [50, 200, 400, 700, 1000] {
        let (csv_before, report_before) = (modified("o.csv"), modified("o_report.html"));
        let mut child = Command::new(env!("CARGO_BIN_EXE_magcomp"))
            .current_dir(dir)
            .args(args)
            .stdout(std::process::Stdio::null())
            .spawn()
            .unwrap();
        std::thread::sleep(std::time::Duration::from_millis(delay_ms));
        let _ = child.kill();
        let _ = child.wait();
        let new_report = modified("o_report.html") != report_before;
        let new_csv = modified("o.csv") != csv_before;
        assert!(
            !new_report || new_csv,
            "killed after {delay_ms} ms: a new report beside the old data"
        );
    }
    let (ok, text) = magcomp(dir, &args);
    assert!(ok, "{text}");
    let litter: Vec<String> = names_in(dir).into_iter().filter(|n| n.ends_with(".tmp")).collect();
    assert!(
        litter.is_empty(),
        "temporary files left after a complete run: {litter:?}"
    );
}

#[test]
fn run_processes_every_flight_and_reports_each() {
    let folder = tempfile::tempdir().unwrap();
    small_flight(folder.path());
    let dir = folder.path();
    std::fs::write(dir.join("broken.csv"), "tt,x\n1,2\n2,3\n").unwrap();
    std::fs::write(
        dir.join("pipeline.toml"),
        "[output]\ndirectory = \"out\"\n[diagnose]\napply = \"never\"\n\
         [[flight]]\ninput = \"broken.csv\"\n[[flight]]\ninput = \"flight.csv\"\n",
    )
    .unwrap();
    let (ok, text) = magcomp(dir, &["run", "pipeline.toml"]);
    assert!(!ok, "a run with a failing flight exits non-zero:\n{text}");
    assert!(
        dir.join("out/flight_compensated.csv").is_file(),
        "the second flight is processed:\n{text}"
    );
    assert!(text.contains("1 of 2 flights failed"), "{text}");
    let table: Vec<&str> = text.lines().skip_while(|l| !l.starts_with("flight ")).collect();
    assert!(
        table
            .iter()
            .any(|l| l.starts_with("broken.csv") && l.contains("FAILED")),
        "{text}"
    );
    assert!(
        table.iter().any(|l| l.starts_with("flight.csv") && l.contains("ok")),
        "{text}"
    );
}

#[cfg(unix)]
#[test]
fn a_read_only_report_folder_stops_the_run_before_anything_is_written() {
    use std::os::unix::fs::PermissionsExt;
    // SAFETY: geteuid only reads the process's user id.
    if unsafe { libc::geteuid() } == 0 {
        println!(
            "running as root, whom folder permissions do not stop: this case is covered by \
             a_failed_run_leaves_the_previous_outputs_and_no_temporary_files (a report folder that is a file)"
        );
        return;
    }
    let folder = tempfile::tempdir().unwrap();
    small_flight(folder.path());
    let dir = folder.path();
    std::fs::create_dir(dir.join("locked")).unwrap();
    std::fs::set_permissions(dir.join("locked"), std::fs::Permissions::from_mode(0o555)).unwrap();
    let (ok, text) = magcomp(
        dir,
        &[
            "compensate",
            "flight.csv",
            "--out",
            "o.csv",
            "--html",
            "locked/r.html",
            "--plain",
        ],
    );
    std::fs::set_permissions(dir.join("locked"), std::fs::Permissions::from_mode(0o755)).unwrap();
    assert!(!ok && text.contains("cannot be written"), "{text}");
    assert!(
        !dir.join("o.csv").exists(),
        "the CSV is not written when the report cannot be"
    );
}

#[test]
fn an_output_name_no_file_system_takes_is_refused_before_anything_is_written() {
    // 251 bytes and ".csv" is a name the disk takes, but the report and
    // JSON named after it are not: the flight's outputs are committed
    // together or not at all, so nothing is written.
    let folder = tempfile::tempdir().unwrap();
    small_flight(folder.path());
    let long = format!("{}.csv", "a".repeat(251));
    assert_refused(
        folder.path(),
        &["compensate", "flight.csv", "--out", &long],
        "at most 255",
    );
    assert!(
        names_in(folder.path()).iter().all(|n| !n.starts_with("aaaa")),
        "{:?}",
        names_in(folder.path())
    );
}

#[test]
fn a_read_only_output_is_not_replaced() {
    let folder = tempfile::tempdir().unwrap();
    small_flight(folder.path());
    let kept = folder.path().join("kept.csv");
    std::fs::write(&kept, "delivered\n").unwrap();
    let mut permissions = std::fs::metadata(&kept).unwrap().permissions();
    permissions.set_readonly(true);
    std::fs::set_permissions(&kept, permissions).unwrap();
    assert_refused(
        folder.path(),
        &["compensate", "flight.csv", "--out", "kept.csv"],
        "read-only",
    );
    assert_eq!(std::fs::read_to_string(&kept).unwrap(), "delivered\n");
}
