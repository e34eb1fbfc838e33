//! The fuzz targets' kept corpora, replayed on stable Rust: every file in
//! `fuzz/corpus/<target>/` goes through the same harness the target runs
//! (`fuzz/fuzz_targets/harness.rs`: every stage, to the report), and must
//! end in a result or an error, never a panic.

use std::path::Path;

#[path = "../fuzz/fuzz_targets/harness.rs"]
mod harness;

#[test]
fn every_kept_fuzz_input_runs_through_every_stage_without_a_panic() {
    let corpus = Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz/corpus");
    let targets = [
        ("ingest_csv", "csv"),
        ("ingest_xyz", "xyz"),
        ("ingest_mcap", "mcap"),
        ("ingest_hdf5", "h5"),
    ];
    let mut replayed = 0;
    for (target, extension) in targets {
        let folder = corpus.join(target);
        let mut files: Vec<_> = std::fs::read_dir(&folder)
            .unwrap_or_else(|e| panic!("{}: {e}; the corpora are kept in the repository", folder.display()))
            .map(|entry| entry.unwrap().path())
            .collect();
        files.sort();
        assert!(!files.is_empty(), "{} is empty", folder.display());
        for file in files {
            let bytes = std::fs::read(&file).unwrap();
            println!("{target}: {} ({} bytes)", file.display(), bytes.len());
            let started = std::time::Instant::now();
            let finished = harness::exercise(&bytes, extension);
            println!(
                "  {} in {:.2} s",
                if finished { "compensated" } else { "refused" },
                started.elapsed().as_secs_f64()
            );
            // The seeds are valid flights: they must reach the report, or
            // the targets would fuzz the readers alone.
            let seed = file.file_stem().is_some_and(|stem| stem == "seed");
            assert!(
                !seed || finished,
                "{}: the seed flight did not reach the report",
                file.display()
            );
            replayed += 1;
        }
    }
    println!("{replayed} kept inputs replayed through every stage");
}
