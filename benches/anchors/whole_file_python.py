"""The Python anchor of `cargo bench --bench fit -- file`: the whole job
(read the CSV, fit five channels, compensate every row, write the CSV with
the compensated columns added) as a Python user writes it, on the bench's
200,000-row, 100-column file.

Each channel's Tolles-Lawson fit is the one of `ridge_numpy.py`: the 18
terms of the fluxgate's field and the channel, band-passed window by window
(4th-order Butterworth, 0.1-0.9 Hz, forward and backward), one ridge solve
with a fixed λ (no λ search: the cheapest fit). The compensated channel is
the recorded one less the terms of the whole flight times the
coefficients. Two readers and writers are timed, and the faster is the
anchor:
- pandas: `read_csv` (C engine) and `to_csv`;
- pyarrow: `pyarrow.csv.read_csv` (multithreaded) and `write_csv`.

Usage: python3 whole_file_python.py FILE.csv OUT_FOLDER
(prints one line per reader, and `fastest <ms>`)
"""

import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from ridge_numpy import band_passed, terms  # noqa: E402

CHANNELS = [f"mag_{n}_uc" for n in range(1, 6)]
# The bench's windows: 120 s every 300 s, eight of them.
WINDOWS = [(w * 300.0, w * 300.0 + 120.0) for w in range(8)]


def fit_and_compensate(columns, lam=1e-4):
    """The compensated channels, name -> values, from a dict of columns."""
    b = np.stack([columns[f"flux_a_{axis}"] for axis in "xyz"])
    t = columns["tt"]
    whole = terms(b)
    rows = [np.flatnonzero((t >= start) & (t <= end)) for start, end in WINDOWS]
    design = np.concatenate([band_passed(terms(b[:, r])) for r in rows])
    out = {}
    for name in CHANNELS:
        y = columns[name]
        target = np.concatenate([band_passed(y[r]) for r in rows])
        gram = design.T @ design
        ridge = lam * np.trace(gram) / gram.shape[0] * np.eye(gram.shape[0])
        beta = np.linalg.solve(gram + ridge, design.T @ target)
        out[name.replace("_uc", "_c")] = y - whole @ beta
    return out


def with_pandas(path, out):
    import pandas

    frame = pandas.read_csv(path)
    columns = {name: frame[name].to_numpy() for name in ["tt", "flux_a_x", "flux_a_y", "flux_a_z", *CHANNELS]}
    for name, values in fit_and_compensate(columns).items():
        frame[name] = values
    frame.to_csv(out, index=False)


def with_pyarrow(path, out):
    import pyarrow
    import pyarrow.csv

    table = pyarrow.csv.read_csv(path)
    names = ["tt", "flux_a_x", "flux_a_y", "flux_a_z", *CHANNELS]
    columns = {name: table.column(name).to_numpy() for name in names}
    for name, values in fit_and_compensate(columns).items():
        table = table.append_column(name, pyarrow.array(values))
    pyarrow.csv.write_csv(table, out)


def main():
    path, folder = sys.argv[1], sys.argv[2]
    times = []
    for label, job in [("pandas", with_pandas), ("pyarrow", with_pyarrow)]:
        try:
            __import__(label)
        except ImportError:
            print(f"{label}: not installed")
            continue
        out = os.path.join(folder, f"python_{label}.csv")
        runs = []
        for _ in range(3):
            start = time.perf_counter()
            job(path, out)
            runs.append(time.perf_counter() - start)
        runs.sort()
        print(f"{label}: median {1e3 * runs[1]:.0f} ms over 3 runs")
        times.append(1e3 * runs[1])
    if times:
        print(f"fastest {min(times):.0f}")


if __name__ == "__main__":
    main()
