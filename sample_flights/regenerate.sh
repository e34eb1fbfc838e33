#!/usr/bin/env bash
# Regenerates every simulated sample flight from its scenario, then the
# expected pipeline figures (sample_flights/expected/*.json).
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release
sim() { target/release/magcomp simulate "sample_flights/scenarios/$1.toml" --out "sample_flights/$2"; }
sim clean clean.csv
sim clean clean_mcap.mcap
sim magnav_layout magnav_layout.h5
for name in concealed_a concealed_b concealed_c concealed_d; do
    sim "$name" "$name.csv"
done
MAGCOMP_BLESS=1 cargo test --release --test sample_flights
