"""The two table contracts (ARCHITECTURE.md): geometry in, light curve out.

Tables are ``pandas.DataFrame`` objects; CSV or Parquet is chosen by the file
extension. Metadata (at least ``frame``) travels as leading ``# key: value``
lines in CSV and as schema metadata in Parquet, and lives in ``df.attrs``.

Geometry table columns (one row per sample, inertial frame, metres):
``utc, t_s, rso_{x,y,z}_m, sun_{x,y,z}_m, obs_{x,y,z}_m`` required;
``exposure_s, elevation_deg, sun_elevation_deg, shadow_nu, visible`` optional
(defaults: the scene's exposure, NaN, NaN, 1, True).

Light-curve table columns:
``utc, t_s, mag, flux_w_m2, phase_angle_deg, range_m, exposure_s, visible``
(+ optional ``mag_err``); invisible rows keep NaN ``mag`` and ``flux_w_m2``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from jaxlc.errors import TableError
from jaxlc.geometry.eclipse import R_EARTH_M
from jaxlc.io.files import TABLE_FORMATS, atomic_output
from jaxlc.io.utc import format_utc, parse_utc
from jaxlc.rendering.photometry import AU_M

POSITION_COLUMNS = tuple(f"{b}_{c}_m" for b in ("rso", "sun", "obs") for c in "xyz")
GEOMETRY_REQUIRED = ("utc", "t_s", *POSITION_COLUMNS)
GEOMETRY_OPTIONAL = {
    "exposure_s": np.nan,  # NaN: use the scene's [sensor] exposure_s
    "elevation_deg": np.nan,
    "sun_elevation_deg": np.nan,
    "shadow_nu": 1.0,
    "visible": True,
}
GEOMETRY_COLUMNS = (*GEOMETRY_REQUIRED, *GEOMETRY_OPTIONAL)
LIGHTCURVE_COLUMNS = (
    "utc",
    "t_s",
    "mag",
    "flux_w_m2",
    "phase_angle_deg",
    "range_m",
    "exposure_s",
    "visible",
)
#: Tolerated mismatch between ``t_s`` and the ``utc`` column (seconds).
TIME_TOLERANCE_S = 1e-3
#: Frames the renderer understands: ``GCRS`` (geocentric, from ``jaxlc geometry``) and
#: ``synthetic`` (object-centred, from ``jaxlc geometry synthetic``); a table
#: without a frame is taken as GCRS.
FRAMES = ("GCRS", "synthetic")
#: Object–Sun distance allowed (AU): the Earth's orbit spans 0.983–1.017 AU.
SUN_DISTANCE_AU = (0.95, 1.05)
#: Smallest geocentric distance of an object or an observer in a GCRS table (m):
#: the Earth's polar radius less 50 km (a ground site is ≥ 6.35e6 m from the centre).
MIN_GEOCENTRIC_M = 6.30e6
KM_HINT = " (positions look like kilometres: the columns are in metres, multiply by 1000)"


def _format(path: Path) -> str:
    fmt = TABLE_FORMATS.get(path.suffix.lower())
    if fmt is None:
        raise TableError(f"{path}: unknown table extension {path.suffix!r}; use .csv or .parquet")
    return fmt


# ---------------------------------------------------------------------------
# Reading and writing


def read_table(path: str | Path) -> pd.DataFrame:
    """Read a CSV or Parquet table with its metadata in ``df.attrs`` (no validation)."""
    path = Path(path)
    fmt = _format(path)
    if not path.is_file():
        raise TableError(f"table file {str(path)!r} does not exist")
    try:
        if fmt == "parquet":
            import pyarrow.parquet as pq

            table = pq.read_table(path)
            meta = {
                k.decode(): v.decode()
                for k, v in (table.schema.metadata or {}).items()
                if not k.startswith(b"pandas")
            }
            df = table.to_pandas()
        else:
            meta, skip = {}, 0
            with open(path, encoding="utf-8") as fh:
                for line in fh:
                    if not line.startswith("#"):
                        break
                    skip += 1
                    key, sep, value = line[1:].partition(":")
                    if sep:
                        meta[key.strip()] = value.strip()
            df = pd.read_csv(path, skiprows=skip)
    except TableError:
        raise
    except Exception as exc:
        raise TableError(f"{path}: cannot read table: {exc}") from exc
    df.attrs.update(meta)
    df.attrs["source"] = str(path)
    return df


def write_table(df: pd.DataFrame, path: str | Path) -> Path:
    """Write a table atomically as CSV or Parquet (by extension), with its metadata."""
    path = Path(path)
    fmt = _format(path)
    meta = {k: str(v) for k, v in df.attrs.items() if k != "source"}
    with atomic_output(path) as tmp:
        if fmt == "parquet":
            import pyarrow as pa
            import pyarrow.parquet as pq

            table = pa.Table.from_pandas(df, preserve_index=False)
            merged = dict(table.schema.metadata or {})
            merged.update({k.encode(): v.encode() for k, v in meta.items()})
            pq.write_table(table.replace_schema_metadata(merged), tmp)
        else:
            with open(tmp, "w", encoding="utf-8", newline="") as fh:
                for k, v in meta.items():
                    fh.write(f"# {k}: {v}\n")
                df.to_csv(fh, index=False, float_format="%.17g", lineterminator="\n")
    return path


def geometry_frame(
    start_utc: pd.Timestamp,
    t_s,
    rso_m,
    sun_m,
    obs_m,
    exposure_s=np.nan,
    elevation_deg=np.nan,
    sun_elevation_deg=np.nan,
    shadow_nu=1.0,
    visible=True,
    frame: str = "GCRS",
) -> pd.DataFrame:
    """A geometry table from arrays: rows at ``start_utc + t_s`` (float64 s),
    positions (T, 3) in m, and per-row (T,) or constant optional columns."""
    t = np.asarray(t_s, np.float64)
    df = pd.DataFrame({"utc": format_utc(start_utc + pd.to_timedelta(t, unit="s")), "t_s": t})
    for name, arr in (("rso", rso_m), ("sun", sun_m), ("obs", obs_m)):
        arr = np.asarray(arr, np.float64)
        for k, c in enumerate("xyz"):
            df[f"{name}_{c}_m"] = arr[:, k]
    df["exposure_s"] = exposure_s
    df["elevation_deg"] = elevation_deg
    df["sun_elevation_deg"] = sun_elevation_deg
    df["shadow_nu"] = shadow_nu
    df["visible"] = visible
    df.attrs["frame"] = frame
    return df


# ---------------------------------------------------------------------------
# Validation


def _where(df: pd.DataFrame) -> str:
    return df.attrs.get("source", "geometry table")


def _row_hint(df, row: int) -> str:
    src = df.attrs.get("source", "")
    if src.lower().endswith(".csv"):
        n_meta = sum(1 for k in df.attrs if k != "source")
        return f"row {row} (line {row + n_meta + 2} of the file)"
    return f"row {row}"


def float_column(df, name) -> np.ndarray:
    """Column ``name`` as float64; a non-number is a :class:`TableError` naming its row."""
    try:
        return pd.to_numeric(df[name], errors="raise").to_numpy(dtype=np.float64)
    except (ValueError, TypeError):
        bad = pd.to_numeric(df[name], errors="coerce").isna() & df[name].notna()
        row = int(np.flatnonzero(bad.to_numpy())[0])
        raise TableError(
            f"{_where(df)}: column {name!r} has a non-number {df[name].iloc[row]!r} at "
            f"{_row_hint(df, row)}"
        ) from None


def bool_column(df, name) -> np.ndarray:
    """Column ``name`` as bool (true/false, 1/0); anything else is a :class:`TableError`."""
    col = df[name]
    if col.dtype == bool:
        return col.to_numpy()
    mapping = {"true": True, "false": False, "1": True, "0": False, "1.0": True, "0.0": False}
    text = col.astype(str).str.strip().str.lower()
    out = text.map(mapping)
    if out.isna().any():
        row = int(np.flatnonzero(out.isna().to_numpy())[0])
        raise TableError(
            f"{_where(df)}: column {name!r} must be true/false, got {col.iloc[row]!r} at "
            f"{_row_hint(df, row)}"
        )
    return out.to_numpy(dtype=bool)


def validate_geometry(df: pd.DataFrame) -> pd.DataFrame:
    """Check a geometry table and return a clean copy with every column present.

    Numbers become float64, ``visible`` bool, ``utc`` ISO strings; optional
    columns get their defaults; other columns are kept after the contract's.
    Positions may be NaN only on invisible rows.

    Raises:
        TableError: naming the table, the column, the row and the value.
    """
    where = _where(df)
    missing = [c for c in GEOMETRY_REQUIRED if c not in df.columns]
    if missing:
        raise TableError(
            f"{where}: missing column(s) {', '.join(missing)}; a geometry table needs "
            f"{', '.join(GEOMETRY_REQUIRED)} (see ARCHITECTURE.md){separator_hint(df)}"
        )
    out = pd.DataFrame(index=pd.RangeIndex(len(df)))
    out.attrs.update(df.attrs)
    for name in ("t_s", *POSITION_COLUMNS):
        out[name] = float_column(df, name)
    for name, default in GEOMETRY_OPTIONAL.items():
        if name == "visible":
            out[name] = bool_column(df, name) if name in df.columns else True
        else:
            out[name] = float_column(df, name) if name in df.columns else default
    times = parse_utc(df["utc"], f"{where}: column 'utc'", TableError)
    out.insert(0, "utc", format_utc(times) if len(df) else [])
    for name in df.columns:  # extra columns (e.g. sgp4_error) travel unchanged
        if name not in out.columns:
            out[name] = df[name].to_numpy()

    t = out["t_s"].to_numpy()
    vis = out["visible"].to_numpy()
    _check(df, ~np.isfinite(t), "t_s", "must be finite")
    if len(t) > 1:
        _check(df, np.r_[False, np.diff(t) < 0], "t_s", "must not decrease")
    if len(t):
        elapsed = (times - times[0]).total_seconds().to_numpy()
        _check(
            df,
            np.abs(elapsed - (t - t[0])) > TIME_TOLERANCE_S,
            "t_s",
            "disagrees with the utc column by more than 1 ms",
        )
    for name in POSITION_COLUMNS:
        _check(df, vis & ~np.isfinite(out[name].to_numpy()), name, "must be finite on visible rows")
    pos = {b: out[[f"{b}_{c}_m" for c in "xyz"]].to_numpy() for b in ("rso", "sun", "obs")}
    with np.errstate(over="ignore"):  # absurd positions overflow: refused as implausible
        for other in ("sun", "obs"):
            dist = np.linalg.norm(pos[other] - pos["rso"], axis=1)
            _check(
                df,
                vis & ~(dist > 0),
                f"{other}_x_m",
                f"puts the {other} at the object (zero distance)",
            )
        _check_plausible(df, pos, vis)
    nu = out["shadow_nu"].to_numpy()
    _check(df, vis & ~((nu >= 0) & (nu <= 1)), "shadow_nu", "must be in [0, 1]")
    exp = out["exposure_s"].to_numpy()
    _check(df, exp < 0, "exposure_s", "must be ≥ 0")
    return out


def separator_hint(df: pd.DataFrame) -> str:
    """A hint when a CSV was read as one column: its separator is not a comma."""
    if len(df.columns) == 1:
        name = str(df.columns[0])
        for sep, what in ((";", "semicolons"), ("\t", "tabs"), (" ", "spaces")):
            if sep in name.strip():
                return f"; the file is separated by {what}: CSV tables need commas"
    return ""


def _check_frame(df: pd.DataFrame) -> str:
    frame = str(df.attrs.get("frame", "GCRS")).strip()
    known = {f.lower(): f for f in FRAMES}
    if frame.lower() not in known:
        raise TableError(
            f"{_where(df)}: frame {frame!r} is not one the renderer understands "
            f"({', '.join(FRAMES)}); convert Earth-fixed positions (ITRF/ITRS/ECEF/TEME) to GCRS "
            "(e.g. astropy ITRS → GCRS) or make the table with `jaxlc geometry`; positions "
            "already in another inertial frame (ICRF, J2000) are within 0.1″ of GCRS: "
            "write '# frame: GCRS'"
        )
    return known[frame.lower()]


def _check_plausible(df: pd.DataFrame, pos: dict, vis: np.ndarray) -> None:
    """Refuse positions that cannot be metres in the table's frame (on visible rows)."""
    frame = _check_frame(df)
    if not np.any(vis):
        return
    sun_au = np.linalg.norm(pos["sun"] - pos["rso"], axis=1) / AU_M
    lo, hi = SUN_DISTANCE_AU
    km = KM_HINT if np.any(vis & (abs(sun_au * 1e3 - 1) < 0.05)) else ""
    _check(
        df,
        vis & ~((sun_au >= lo) & (sun_au <= hi)),
        "sun_x_m",
        f"puts the Sun {np.nanmin(np.where(vis, sun_au, np.nan)):.3g} AU from the object; "
        f"it must be {lo}–{hi} AU{km}",
    )
    if frame != "GCRS":
        return
    for body, name in (("rso", "object"), ("obs", "observer")):
        r_m = np.linalg.norm(pos[body], axis=1)
        km = KM_HINT if np.any(vis & (r_m < R_EARTH_M / 100)) else ""
        _check(
            df,
            vis & ~(r_m >= MIN_GEOCENTRIC_M),
            f"{body}_x_m",
            f"puts the {name} inside the Earth (geocentric distance < "
            f"{MIN_GEOCENTRIC_M:.3g} m){km}; GCRS positions are metres from the Earth's centre",
        )


def _check(df, bad: np.ndarray, column: str, message: str):
    if np.any(bad):
        row = int(np.flatnonzero(bad)[0])
        value = df[column].iloc[row] if column in df.columns else None
        value = value.item() if isinstance(value, np.generic) else value
        raise TableError(
            f"{_where(df)}: column {column!r} = {value!r} at {_row_hint(df, row)} {message} "
            f"({int(np.count_nonzero(bad))} row(s) affected)"
        )


def read_geometry(path: str | Path) -> pd.DataFrame:
    """Read and validate a geometry table (CSV or Parquet)."""
    return validate_geometry(read_table(path))


def read_lightcurve(path: str | Path) -> pd.DataFrame:
    """Read a light-curve table and check its required columns."""
    df = read_table(path)
    missing = [c for c in LIGHTCURVE_COLUMNS if c not in df.columns]
    if missing:
        raise TableError(
            f"{path}: missing light-curve column(s) {', '.join(missing)}{separator_hint(df)}"
        )
    df["visible"] = bool_column(df, "visible")
    return df
