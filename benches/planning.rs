//! Planning a campaign: `cargo bench --bench planning`.
//!
//! Every `magcomp run` (and every shard of an array job) reads the whole
//! campaign before it picks its flights: the manifest's rows, the check
//! that no flight is named twice, and each flight's output name. This
//! times `Pipeline::load` on manifests of 2,500 to 40,000 rows (flights in
//! 50 folders, every file stem shared by 50 flights, so the output names
//! take the folder) and prints the time per row, which stays flat when
//! the planning is linear.

use std::time::Instant;

use magcomp::config::Pipeline;

fn main() {
    let folder = tempfile::tempdir().expect("a temporary folder");
    println!("| manifest rows | load | per row |\n|---|---|---|");
    for rows in [2_500usize, 10_000, 40_000] {
        let mut manifest = String::from("input,date\n");
        for k in 0..rows {
            manifest += &format!("flights/day_{:02}/line_{:04}.csv,2026-06-15\n", k % 50, k / 50);
        }
        std::fs::write(folder.path().join("manifest.csv"), manifest).expect("manifest written");
        std::fs::write(
            folder.path().join("pipeline.toml"),
            "[output]\ndirectory = \"out\"\n[campaign]\nmanifest = \"manifest.csv\"\n",
        )
        .expect("settings written");
        let started = Instant::now();
        let pipeline = Pipeline::load(&folder.path().join("pipeline.toml")).expect("the campaign loads");
        let seconds = started.elapsed().as_secs_f64();
        assert_eq!(pipeline.flights.len(), rows);
        println!("| {rows} | {seconds:.3} s | {:.1} µs |", 1e6 * seconds / rows as f64);
    }
}
