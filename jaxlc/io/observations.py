"""Observed light curves: jaxlc light-curve tables and Mini-MegaTORTORA tracks.

Mini-MegaTORTORA (MMT-9, Special Astrophysical Observatory) publishes tracks as
text: ``#`` header lines (``satellite``, ``track``, ``variability``,
``variability_period`` in seconds, ``npoints``), then whitespace-separated rows
``Date Time StdMag Mag Filter Penumbra Distance Phase Channel`` (UTC, magnitude
normalised to 1,000 km, observed magnitude, filter, penumbra flag, range in km,
phase angle in degrees, camera channel). Fractional seconds are sometimes
missing.

:func:`read_observations` reads either kind into the light-curve table
(``utc, t_s, mag, phase_angle_deg, range_m, visible`` + extra columns), with
``attrs`` holding what the file says about the object.

Example:
    >>> obs = read_observations("tests/data/mmt/10025_10114859.txt")
    >>> obs.attrs["catalogue_period_s"]
    11.7586764
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd

from jaxlc.errors import TableError

MMT_COLUMNS = (
    "Date",
    "Time",
    "StdMag",
    "Mag",
    "Filter",
    "Penumbra",
    "Distance",
    "Phase",
    "Channel",
)


def is_mmt_track(path: str | Path) -> bool:
    """True when the file starts like a Mini-MegaTORTORA track (``# satellite:``)."""
    path = Path(path)
    if path.suffix.lower() in (".csv", ".parquet", ".pq"):
        return False
    try:
        with open(path, encoding="utf-8", errors="replace") as fh:
            first = fh.readline()
    except OSError:
        return False
    return first.lower().startswith("# satellite")


def _number(text: str, path: Path, line_no: int, column: str) -> float:
    try:
        x = float(text)
    except ValueError:
        raise TableError(f"{path}:{line_no}: column {column} = {text!r} is not a number") from None
    if not math.isfinite(x):
        raise TableError(f"{path}:{line_no}: column {column} = {text!r} is not finite")
    return x


def read_mmt(path: str | Path) -> pd.DataFrame:
    """Read a Mini-MegaTORTORA track file.

    Returns:
        Light-curve table: ``utc`` (UTC), ``t_s`` (s from the first sample),
        ``mag`` (observed), ``std_mag`` (normalised to 1,000 km),
        ``phase_angle_deg``, ``range_m``, ``visible`` (all True), ``filter``,
        ``penumbra``, ``channel``. ``attrs``: ``source``, ``norad_id``,
        ``object_name``, ``track_id``, ``catalogue_period_s`` (NaN when the
        header has none), ``frame = "observed"``.

    Raises:
        TableError: naming the file and line of a malformed header or row.
    """
    path = Path(path)
    if not path.is_file():
        raise TableError(f"MMT track {str(path)!r} does not exist")
    header: dict[str, str] = {}
    rows: list[tuple] = []
    with open(path, encoding="utf-8", errors="replace") as fh:
        for line_no, raw in enumerate(fh, start=1):
            line = raw.strip()
            if not line:
                continue
            if line.startswith("#"):
                body = line.lstrip("#").strip()
                if ":" in body:
                    key, _, value = body.partition(":")
                    header[key.strip().lower()] = value.strip()
                continue
            fields = line.split()
            if len(fields) != len(MMT_COLUMNS):
                raise TableError(
                    f"{path}:{line_no}: expected {len(MMT_COLUMNS)} columns "
                    f"({' '.join(MMT_COLUMNS)}), found {len(fields)}: {line[:60]!r}"
                    + (" (truncated file?)" if len(fields) < len(MMT_COLUMNS) else "")
                )
            try:
                utc = pd.Timestamp(f"{fields[0]}T{fields[1]}", tz="UTC")
            except ValueError:
                raise TableError(
                    f"{path}:{line_no}: date/time {fields[0]} {fields[1]!r} is not a UTC time "
                    "(YYYY-MM-DD HH:MM:SS[.ffffff])"
                ) from None
            rows.append(
                (
                    utc,
                    _number(fields[2], path, line_no, "StdMag"),
                    _number(fields[3], path, line_no, "Mag"),
                    fields[4],
                    int(_number(fields[5], path, line_no, "Penumbra")),
                    _number(fields[6], path, line_no, "Distance"),
                    _number(fields[7], path, line_no, "Phase"),
                    int(_number(fields[8], path, line_no, "Channel")),
                )
            )
    if "satellite" not in header:
        raise TableError(f"{path}: no '# satellite:' header line; is this an MMT track file?")
    if not rows:
        raise TableError(f"{path}: no data rows after the header")
    utc, std_mag, mag, filt, pen, dist_km, phase, chan = map(list, zip(*rows, strict=True))
    utc = pd.DatetimeIndex(utc)
    t_s = (utc - utc[0]).total_seconds().to_numpy()
    if np.any(np.diff(t_s) < 0):
        bad = int(np.flatnonzero(np.diff(t_s) < 0)[0]) + 1
        raise TableError(f"{path}: times go backwards at data row {bad + 1}")
    df = pd.DataFrame(
        {
            "utc": utc,
            "t_s": t_s,
            "mag": np.asarray(mag),
            "std_mag": np.asarray(std_mag),
            "phase_angle_deg": np.asarray(phase),
            "range_m": np.asarray(dist_km) * 1e3,
            "visible": np.ones(len(rows), bool),
            "filter": filt,
            "penumbra": np.asarray(pen),
            "channel": np.asarray(chan),
        }
    )
    satellite = header["satellite"].split()
    declared = header.get("npoints")
    if declared is not None and declared.isdigit() and int(declared) != len(df):
        import warnings

        warnings.warn(
            f"{path}: header says npoints = {declared}, file has {len(df)} rows (truncated file?)",
            stacklevel=2,
        )
    period = header.get("variability_period")
    try:
        period_s = float(period) if period else float("nan")
    except ValueError:
        raise TableError(
            f"{path}: header variability_period = {period!r} is not a number of seconds"
        ) from None
    df.attrs.update(
        {
            "source": str(path),
            "frame": "observed",
            "norad_id": satellite[0] if satellite else "",
            "object_name": " ".join(satellite[1:]),
            "track_id": header.get("track", ""),
            "catalogue_period_s": period_s,
        }
    )
    return df


def read_observations(path: str | Path) -> pd.DataFrame:
    """An observed light curve: an MMT track or a table (CSV/Parquet) with ``t_s`` or
    ``utc`` and a magnitude column (a jaxlc light-curve table, or any such table)."""
    from jaxlc.io.tables import read_table
    from jaxlc.io.utc import parse_utc

    if is_mmt_track(path):
        return read_mmt(path)
    if Path(path).suffix.lower() not in (".csv", ".parquet", ".pq"):
        raise TableError(
            f"{path}: neither a light-curve table (.csv/.parquet) nor an MMT track "
            "(text starting with '# satellite:')"
        )
    df = read_table(path)
    if "t_s" not in df.columns:
        if "utc" not in df.columns:
            raise TableError(
                f"{path}: needs a time column, t_s (seconds) or utc (ISO 8601); "
                f"columns: {', '.join(map(str, df.columns))}"
            )
        times = parse_utc(df["utc"], f"{path}: column 'utc'", TableError)
        df["t_s"] = (times - times[0]).total_seconds().to_numpy() if len(df) else []
    return df


def observed_samples(
    obs: pd.DataFrame, column: str = "mag"
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """(t_s, mag, mag_err or None) of the visible, finite samples.

    Raises:
        TableError: when fewer than 10 usable samples remain.
    """
    from jaxlc.io.tables import bool_column, float_column

    where = obs.attrs.get("source", "light curve")
    if column not in obs.columns:
        numeric = [c for c in obs.columns if pd.api.types.is_numeric_dtype(obs[c])]
        raise TableError(
            f"{where}: no column {column!r}; give --column one of {', '.join(numeric) or '—'}"
        )
    t = float_column(obs, "t_s")
    y = float_column(obs, column)
    ok = np.isfinite(t) & np.isfinite(y)
    if "visible" in obs.columns:
        ok &= bool_column(obs, "visible")
    err = None
    if "mag_err" in obs.columns:
        e = float_column(obs, "mag_err")
        ok &= np.isfinite(e) & (e > 0)
        err = e[ok]
    if np.count_nonzero(ok) < 10:
        raise TableError(
            f"{obs.attrs.get('source', 'light curve')}: only {int(np.count_nonzero(ok))} visible "
            "samples with finite magnitudes; at least 10 are needed"
        )
    return t[ok], y[ok], err
