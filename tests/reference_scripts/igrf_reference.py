"""Reference values for tests/simulate_physics.rs: IGRF-14 north, east,
down (nT) from ppigrf 2.1.0 (Laundal), an independent implementation.

    python -m venv v && v/bin/pip install ppigrf==2.1.0 pandas
    v/bin/python tests/reference_scripts/igrf_reference.py
"""
from datetime import datetime
import ppigrf

PLACES = [
    # latitude, longitude (deg), height (km), date
    (45.0, -75.0, 3.0, datetime(2020, 6, 15)),
    (-33.9, 151.2, 0.0, datetime(2025, 1, 1)),
    (64.8, -147.7, 1.5, datetime(2026, 11, 22)),
    (0.0, 0.0, 0.0, datetime(2015, 1, 1)),
    (-80.0, 120.0, 10.0, datetime(2010, 7, 2)),
    (51.5, -0.1, 0.3, datetime(1965, 1, 1)),
]

for lat, lon, h, date in PLACES:
    east, north, up = ppigrf.igrf(lon, lat, h, date)
    # ppigrf interpolates the coefficients linearly in days between the
    # 5-year epochs; give magcomp the decimal year that lands at the same
    # point between them.
    first = 1900 + 5 * ((date.year - 1900) // 5)
    span = (datetime(first + 5, 1, 1) - datetime(first, 1, 1)).days
    year = first + 5 * (date - datetime(first, 1, 1)).days / span
    print(f"({lat}, {lon}, {h * 1000.0}, {year!r}, [{float(north.ravel()[0]):.4f}, {float(east.ravel()[0]):.4f}, {float(-up.ravel()[0]):.4f}]),")
