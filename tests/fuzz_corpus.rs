//! The fuzz targets' kept corpora, replayed on stable Rust: every file in
//! `fuzz/corpus/<target>/` goes through the same harness the target runs
//! (`fuzz/fuzz_targets/harness.rs`: every stage, to the report), and must
//! end in a result or an error, never a panic.

use std::path::Path;

#[path = "../fuzz/fuzz_targets/harness.rs"]
mod harness;

/// The kept damaged inputs (`kept_*`: names the fuzzer's own hashes,
/// which .gitignore leaves out, never take), each made from its target's seed, and whether
/// it must reach the report (`true`: a recording cut short or with a
/// damaged chunk is read as far as it is whole, with a warning; a row of
/// units under the header is read as units, with a note) or be refused
/// with an error (`false`). Other kept inputs (found by the
/// fuzzer) need only end without a panic.
const KNOWN: [(&str, bool); 18] = [
    ("kept_header_names_a_column_twice.csv", false),
    ("kept_header_not_utf8.csv", false),
    ("kept_cell_not_utf8.csv", false),
    ("kept_row_one_field_short.csv", false),
    ("kept_carriage_returns_alone.csv", false),
    ("kept_time_backwards.csv", false),
    ("kept_units_row_under_header.csv", true),
    ("kept_cut_mid_row.csv", false),
    ("kept_line_not_utf8.xyz", false),
    ("kept_cut_mid_row.xyz", false),
    ("kept_cut_short.mcap", true),
    ("kept_byte_flipped_mid_file.mcap", true),
    ("kept_cut_short.h5", false),
    // Damaged recordings `tests/mcap_input.rs` builds (MAGCOMP_WRITE_CORPUS
    // writes them here): each is read whole or as far as it is whole, with
    // its warning or note, and then refused: at screening, since the test
    // recording's fluxgate holds one axis constant, or (the one cut short)
    // for a window too short to filter.
    ("kept_cut_at_a_record_boundary.mcap", false),
    ("kept_chunk_index_lost_an_entry.mcap", false),
    ("kept_chunk_fails_its_crc.mcap", false),
    ("kept_topic_on_two_channel_records.mcap", false),
    ("kept_topic_in_an_unknown_encoding.mcap", false),
];

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
    let mut known_seen = 0;
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
            let name = file.file_name().and_then(|n| n.to_str()).unwrap_or_default();
            if let Some((_, expected)) = KNOWN.iter().find(|(known, _)| *known == name) {
                assert_eq!(finished, *expected, "{}: compensated = {finished}", file.display());
                known_seen += 1;
            }
            replayed += 1;
        }
    }
    assert_eq!(
        known_seen,
        KNOWN.len(),
        "a damaged input listed in KNOWN is missing from the corpus"
    );
    println!("{replayed} kept inputs replayed through every stage");
}
