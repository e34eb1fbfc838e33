"""The numpy anchor of `cargo bench --bench fit`: a Tolles-Lawson fit as
a Python user writes it with numpy and scipy, on the bench's synthetic
flight, timed at 1e5 and 1e6 rows.

Two figures per size, median of several runs:
- fixed λ: the 18 terms, each band-passed (4th-order Butterworth,
  0.1-0.9 Hz, forward and backward), and one ridge solve
  (AᵀA + λI) x = Aᵀy;
- PRESS: the same, then λ chosen from 50 by leave-one-out PRESS, each
  λ's hat diagonal from the SVD of the band-passed terms.

Usage: python3 ridge_numpy.py [rows ...]   (prints one line per figure)
"""

import sys
import time

import numpy as np
from scipy import signal


def synthetic_field(rows):
    """The bench's flight (benches/fit.rs `synthetic_field`)."""
    k = np.arange(rows)
    t = k / 10.0
    roll, pitch, yaw = 0.17 * np.sin(t * 0.9), 0.09 * np.cos(t * 1.1), t * 0.01
    b = np.stack(
        [
            20_000.0 * np.cos(yaw) + 900.0 * roll,
            20_000.0 * np.sin(yaw) + 700.0 * pitch,
            47_000.0 - 300.0 * roll * pitch,
        ]
    )
    total = np.sqrt((b * b).sum(axis=0))
    interference = 2.0 * b[0] / total - 1.5 * b[1] / total + 3e-4 * b[0] * b[2] / total
    noise = 0.01 * (((k * 7919) % 1000) / 500.0 - 1.0)
    return b, total + interference + noise


def terms(b, rate_hz=10.0):
    """Permanent (3), induced (6) and eddy (9) terms of the field b."""
    total = np.sqrt((b * b).sum(axis=0))
    c = b / total
    dc = np.gradient(c, 1.0 / rate_hz, axis=1)
    columns = [c[0], c[1], c[2]]
    for i in range(3):
        for j in range(i, 3):
            columns.append(total * c[i] * c[j])
    for i in range(3):
        for j in range(3):
            columns.append(total * c[i] * dc[j])
    return np.stack(columns, axis=1)


def band_passed(x, rate_hz=10.0):
    sos = signal.butter(4, [0.1, 0.9], btype="bandpass", fs=rate_hz, output="sos")
    return signal.sosfiltfilt(sos, x, axis=0)


def fixed_lambda(b, y, lam=1e-4):
    a = band_passed(terms(b))
    yf = band_passed(y)
    gram = a.T @ a
    return np.linalg.solve(gram + lam * np.trace(gram) / gram.shape[0] * np.eye(gram.shape[0]), a.T @ yf)


def press(b, y, grid=50):
    a = band_passed(terms(b))
    yf = band_passed(y)
    u, s, vt = np.linalg.svd(a, full_matrices=False)
    uty = u.T @ yf
    u2 = u * u
    best = None
    for lam in np.logspace(-8, 2, grid) * s[0] ** 2:
        shrink = s * s / (s * s + lam)
        fitted = u @ (shrink * uty)
        hat = u2 @ shrink
        value = np.mean(((yf - fitted) / (1.0 - hat)) ** 2)
        if best is None or value < best[0]:
            best = (value, lam)
    lam = best[1]
    return vt.T @ (s / (s * s + lam) * uty)


def median_ms(run, repeats):
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        run()
        times.append(time.perf_counter() - start)
    times.sort()
    return 1e3 * times[len(times) // 2]


def main():
    sizes = [int(a) for a in sys.argv[1:]] or [100_000, 1_000_000]
    for rows in sizes:
        b, y = synthetic_field(rows)
        repeats = 5 if rows <= 100_000 else 3
        fixed = median_ms(lambda: fixed_lambda(b, y), repeats)
        chosen = median_ms(lambda: press(b, y), repeats)
        print(f"numpy {np.__version__} / scipy: {rows} rows, 18 terms: fixed λ {fixed:.1f} ms, PRESS over 50 λ {chosen:.1f} ms")


if __name__ == "__main__":
    main()
