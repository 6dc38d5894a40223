"""Speed and accuracy of the observation geometry (``make bench``).

100 objects (the shipped CubeSat catalogue, 93 objects, with 7 repeated) × one
day at 1 s from Mt Stromlo: SGP4, TEME → GCRS, the Sun, the site, elevations,
the conic shadow, visibility and pass extraction, timed as one
``find_passes`` call and in parts. The accuracy column compares jaxlc's
positions (nutation interpolated from an hourly grid) with skyfield's exact
per-object ``EarthSatellite.at`` on a sub-sample. Writes
``experiments/results/bench_geometry.csv``.

    python experiments/bench_geometry.py [--quick] [--out PATH]
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pandas as pd

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

import jaxlc  # noqa: E402
from jaxlc.geometry import ephemeris  # noqa: E402
from jaxlc.geometry.observe import Visibility, find_passes, observe_chunk  # noqa: E402
from jaxlc.geometry.orbit import propagate_gcrs_m, propagate_teme_km, utc_julian_dates  # noqa: E402
from jaxlc.geometry.sites import get_site  # noqa: E402
from jaxlc.geometry.tle import read_tles  # noqa: E402
from jaxlc.io.tables import write_table  # noqa: E402

TLE_FILE = HERE.parent / "data" / "tle" / "celestrak_cubesat_2025-11.txt"
START = pd.Timestamp("2025-11-20T00:00:00Z")


def timed(fn, repeats):
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    q25, med, q75 = np.percentile(times, [25, 50, 75])
    return out, float(med), float(q75 - q25)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="10 objects × 1 hour (smoke test)")
    parser.add_argument("--out", type=Path, default=HERE / "results" / "bench_geometry.csv")
    args = parser.parse_args(argv)
    n_obj, duration_s, repeats = (10, 3600.0, 2) if args.quick else (100, 86400.0, 3)

    tles = read_tles(TLE_FILE)
    tles = (tles * 2)[:n_obj]
    site = get_site("mt-stromlo")
    n_samples = int(duration_s)
    rules = Visibility()
    rows = []

    def row(stage, seconds, iqr, objects=n_obj, samples=n_samples, **extra):
        rows.append(
            dict(
                stage=stage,
                objects=objects,
                samples_per_object=samples,
                seconds=seconds,
                seconds_iqr=iqr,
                object_samples_per_s=objects * samples / seconds,
                **extra,
            )
        )

    passes, med, iqr = timed(
        lambda: find_passes(tles, site, START, duration_s, 1.0, rules), repeats
    )
    row("find_passes (everything)", med, iqr, passes_found=len(passes))

    # parts, on one chunk of an hour
    offsets = np.arange(0.0, min(3600.0, duration_s))
    t = ephemeris.times(START, offsets)
    jd, fr = utc_julian_dates(t)
    _, med, iqr = timed(lambda: ephemeris.times(START, offsets), repeats)
    row("times + nutation grid", med, iqr, objects=1, samples=len(offsets))
    _, med, iqr = timed(lambda: propagate_teme_km(tles, jd, fr), repeats)
    row("SGP4 (SatrecArray)", med, iqr, samples=len(offsets))
    _, med, iqr = timed(lambda: propagate_gcrs_m(tles, t), repeats)
    row("SGP4 + TEME→GCRS", med, iqr, samples=len(offsets))
    _, med, iqr = timed(lambda: observe_chunk(tles, site, START, offsets, rules), repeats)
    row("observe_chunk (all per-sample geometry)", med, iqr, samples=len(offsets))

    # accuracy against skyfield's exact per-object computation (no interpolation)
    from skyfield.api import EarthSatellite

    ts = ephemeris.timescale()
    sub = np.arange(0.0, duration_s, 97.0)
    t_sub = ephemeris.times(START, sub)
    t_exact = ts.utc(START.year, START.month, START.day, 0, 0, sub)
    r_ours, err = propagate_gcrs_m(tles[:10], t_sub)
    worst = 0.0
    for k, tle in enumerate(tles[:10]):
        ref = EarthSatellite(tle.line1, tle.line2, ts=ts).at(t_exact).position.m.T
        ok = err[k] == 0
        worst = max(worst, float(np.max(np.linalg.norm(r_ours[k][ok] - ref[ok], axis=1))))
    for r in rows:
        r["position_error_vs_skyfield_m"] = worst

    df = pd.DataFrame(rows)
    df.attrs.update(
        {
            "generator": "experiments/bench_geometry.py",
            "jaxlc": jaxlc.__version__,
            "tle_file": TLE_FILE.name,
            "site": site.name,
            "window": f"{START:%Y-%m-%dT%H:%MZ} + {duration_s:g} s at 1 s",
            "cpu_count": str(os.cpu_count()),
            "machine": platform.machine(),
            "date_utc": pd.Timestamp.now(tz="UTC").strftime("%Y-%m-%dT%H:%M:%SZ"),
            "quick": str(args.quick),
        }
    )
    from rich.console import Console
    from rich.table import Table

    table = Table(
        title=f"geometry: {n_obj} objects × {duration_s / 3600:g} h at 1 s (median ± IQR)"
    )
    for col in ("stage", "objects", "samples/object", "seconds", "object-samples/s"):
        table.add_column(col, justify="left" if col == "stage" else "right")
    for r in df.itertuples():
        table.add_row(
            r.stage,
            str(r.objects),
            str(r.samples_per_object),
            f"{r.seconds:.3f} ± {r.seconds_iqr:.3f}",
            f"{r.object_samples_per_s:.3g}",
        )
    console = Console(width=140)
    console.print(table)
    console.print(
        f"{len(passes)} visible passes found; positions within {worst * 1e3:.2f} mm of skyfield's "
        "exact EarthSatellite.at (nutation interpolated from an hourly grid)"
    )
    write_table(df, args.out)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # stale-epoch notes for the repeated objects
        sys.exit(main())
