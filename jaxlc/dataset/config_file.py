"""The dataset config file (TOML): shape classes, geometry, noise — parsed strictly.

Unknown keys, missing values and bad ranges are :class:`DatasetError`\\ s that
name the file, the table, the key and the value, raised before any work (the
meshes are loaded to check part names). A range is a number (fixed) or
``[low, high]``; reflectances, sizes, phase angles, Sun declinations and tilts
are drawn uniformly, periods, exponents and ranges log-uniformly (see
:func:`jaxlc.dataset.draw_curve`)::

    [dataset]
    count = 200                   # light curves
    samples = 1800                # per light curve
    cadence_s = 1.0               # time between samples
    exposure_s = 1.0              # default: cadence_s
    shard_size = 50               # curves per shard (the unit of work and of resuming)
    seed = 1

    [[class]]                     # shape classes, drawn in proportion to weight
    name = "rocket_body"
    scene = "s4_falcon9"          # a scene file (relative to this file) or a shipped scene
    # mesh = "x.obj"              # … or a mesh with [[class.material]] and body_axis
    weight = 1.0
    scale = [0.8, 1.2]            # size factor (uniform), × the scene's own scale
    period_s = [20.0, 200.0]      # spin period (log-uniform); pole isotropic, phase uniform
    [[class.material]]            # optional with a scene (then replaces its materials)
    part = "*"
    brdf = "ashikhmin-shirley"
    rd = [0.4, 0.7]               # a number or [low, high]: uniform
    rs = 0.1
    nu = [10, 300]                # exponents: log-uniform; nv defaults to nu
    [class.render]                # optional, as a scene's [render] table
    max_subsamples = 64
    # [class.tumble]              # optional: tumble torque-free instead of spinning
    # inertia_kg_m2 = [[0.07, 0.09], [0.95, 1.0], 1.0]  # per body axis (log-uniform)
    # mode = "any"                # "SAM", "LAM" or "any"; period_s: the precession period
    # excitation = [0.05, 0.9]    # 0: principal-axis spin … 1: the separatrix (uniform)

    [geometry]
    source = "synthetic"          # fixed Sun, observer sweeping phase angle
    phase_start_deg = [10, 90]
    phase_end_deg = [30, 150]
    range_start_m = [5e5, 3e6]    # log-uniform (phases: uniform)
    range_end_m = [5e5, 3e6]      # default: constant range
    # source = "passes"           # or real passes: a pool of pass geometry tables,
    # tle = ["data/tle/falcon9_rb.tle"]   # one drawn per curve
    # sites = ["mt-stromlo"]
    # start_utc = "2020-08-09T00:00:00Z"
    # days = 3

    [noise]                       # optional: noisy values kept beside noise-free ones
    zero_point_mag = 21.0         # magnitude giving 1 photo-electron per second
    sky_e_per_s = 200.0
    read_noise_e = 8.0
    aperture_m = 0.5              # scintillation (Young 1967); omit for none
"""

from __future__ import annotations

from pathlib import Path

from jaxlc.dataset.config import (
    MAX_COUNT,
    MAX_SHARD_SAMPLES,
    DatasetConfig,
    DatasetError,
    NoiseModel,
    PassSource,
    SyntheticSource,
)
from jaxlc.dataset.draw import check_extremes
from jaxlc.dataset.shape_class import parse_class
from jaxlc.errors import JaxlcError
from jaxlc.geometry.observe import Visibility
from jaxlc.io.toml import (
    Section,
    in_range,
    read_toml,
    whole,
)
from jaxlc.io.utc import format_utc, utc_timestamp
from jaxlc.scene import EXPOSURE_RANGE_S, resolve_file

#: Sample spacing a dataset may use (s): 1 µs to one day.
CADENCE_RANGE_S = (1e-6, 86_400.0)
#: Blocks of instants per kernel call by default. Fewer calls: the CubeSat class of the
#: standard mix (~40 instants an exposure, its adaptive levels in many small calls)
#: 19.3 → 16.6 ms a curve at 64 instead of 16 on one core; S3, S4 and S6 unchanged (the
#: same bytes either way: a curve never depends on its batch neighbours).
BATCH_SIZE = 64


def load_config(path: str | Path) -> DatasetConfig:
    """Read and validate a dataset config file.

    Raises:
        DatasetError: naming the file, table, key and value of the first problem.
    """
    if Path(path).is_dir():
        raise DatasetError(f"dataset config {str(path)!r} is a folder; give the TOML file in it")
    if not Path(path).exists():
        raise DatasetError(
            f"dataset config {str(path)!r} does not exist; give the path of a TOML file "
            "(examples: experiments/configs/bulk_example.toml)"
        )
    data, text = read_toml(path, DatasetError)
    return config_from_dict(data, source=str(path), base_dir=Path(path).resolve().parent, text=text)


def config_from_dict(
    data: dict, source: str = "<dict>", base_dir: Path | None = None, text: str = ""
) -> DatasetConfig:
    """Validate a dataset config given as a dict (the TOML document's structure).

    Meshes are loaded to check part names, so a wrong part fails here, before
    any rendering.
    """
    top = Section(data, source, DatasetError)
    ds = Section(
        top.get("dataset", dict, what="the [dataset] table"), f"{source}: [dataset]", DatasetError
    )
    count = ds.get("count", int, check=whole(1, MAX_COUNT), what="number of light curves")
    samples = ds.get("samples", int, check=whole(1, 1_000_000), what="samples per light curve")
    cadence = ds.get(
        "cadence_s", float, default=1.0, check=in_range(*CADENCE_RANGE_S), what="seconds"
    )
    exposure = ds.get(
        "exposure_s",
        float,
        default=min(cadence, EXPOSURE_RANGE_S[1]),
        check=in_range(*EXPOSURE_RANGE_S),
        what="seconds",
    )
    shard_size = ds.get("shard_size", int, default=100, check=whole(1, 1_000_000))
    if shard_size * samples > MAX_SHARD_SAMPLES:
        raise DatasetError(
            f"{source}: [dataset]: shard_size × samples = {shard_size:,} × {samples:,} = "
            f"{shard_size * samples:,} samples per shard exceeds {MAX_SHARD_SAMPLES:,} (a shard "
            f"is rendered in one worker's memory); lower shard_size to at most "
            f"{max(1, MAX_SHARD_SAMPLES // samples):,}"
        )
    seed = ds.get("seed", int, check=whole(0, 2**63 - 1), what="a whole number ≥ 0")
    batch = ds.get(
        "batch_size", int, default=BATCH_SIZE, check=whole(1, 4096), what="blocks per kernel call"
    )
    ds.finish()

    entries = top.get("class", list, what="at least one [[class]] table")
    if not entries:
        raise DatasetError(f"{source}: needs at least one [[class]] table")
    classes = []
    for i, entry in enumerate(entries, 1):
        name = entry.get("name", f"#{i}") if isinstance(entry, dict) else f"#{i}"
        classes.append(parse_class(entry, f"{source}: [[class]] #{i} ({name})", base_dir))
    names = [c.name for c in classes]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise DatasetError(f"{source}: [[class]] name = {dup[0]!r} is given twice")

    geo_table = top.get("geometry", dict, what="the [geometry] table")
    geometry = _parse_geometry(geo_table, f"{source}: [geometry]", base_dir)
    noise = None
    if top.has("noise"):
        noise = _parse_noise(top.get("noise", dict), f"{source}: [noise]", geometry)
    top.finish()
    config = DatasetConfig(
        count=count,
        samples=samples,
        cadence_s=cadence,
        exposure_s=exposure,
        shard_size=shard_size,
        seed=seed,
        batch_size=batch,
        classes=tuple(classes),
        geometry=geometry,
        noise=noise,
        text=text,
        source=source,
    )
    check_extremes(config)
    return config


def _parse_geometry(table, where, base_dir):
    sec = Section(table, where, DatasetError)
    source = sec.get("source", str, what="'synthetic' or 'passes'")
    if source == "synthetic":
        geo = SyntheticSource(
            phase_start_deg=sec.range("phase_start_deg", 0.0, 180.0, what="degrees"),
            phase_end_deg=sec.range("phase_end_deg", 0.0, 180.0, what="degrees"),
            range_start_m=sec.range("range_start_m", 0.0, 1e12, positive=True, what="metres"),
            range_end_m=sec.range("range_end_m", 0.0, 1e12, default=None, positive=True),
            sun_dec_deg=sec.range("sun_dec_deg", -90.0, 90.0, default=(-23.44, 23.44)),
            tilt_deg=sec.range("tilt_deg", -180.0, 180.0, default=(-90.0, 90.0)),
            start_utc=_utc(sec.get("start_utc", str, default="2019-07-07T12:00:00Z"), where),
        )
    elif source == "passes":
        from jaxlc.geometry.sites import get_site

        tles = sec.get("tle", "strings", what="TLE file(s)")
        paths = tuple(resolve_file(t, base_dir, f"{where}: tle", DatasetError) for t in tles)
        norad = sec.get("norad", "ints", default=None, what="catalogue numbers")
        sites = sec.get("sites", "strings", what="registered site names (jaxlc sites)")
        for s in sites:
            try:
                get_site(s)
            except JaxlcError as exc:
                raise DatasetError(f"{where}: sites: {exc}") from None
        rules = dict(
            min_elevation_deg=sec.get("min_elevation_deg", float, default=15.0),
            max_sun_elevation_deg=sec.get("max_sun_elevation_deg", float, default=-6.0),
            min_shadow_nu=sec.get("min_shadow_nu", float, default=0.0),
        )
        try:
            visibility = Visibility(**rules)
        except JaxlcError as exc:
            raise DatasetError(f"{where}: {exc}") from None
        geo = PassSource(
            tle_paths=paths,
            norad=norad,
            sites=tuple(s.strip().lower() for s in sites),
            start_utc=_utc(sec.get("start_utc", str, what="window start, ISO 8601"), where),
            days=sec.get(
                "days",
                float,
                check=lambda x: None if 0 < x <= 60 else "must be in (0, 60]",
                what="window length",
            ),
            search_step_s=sec.get(
                "search_step_s", float, default=10.0, check=in_range(0.1, 600.0), what="seconds"
            ),
            rules=visibility,
            min_pass_s=sec.get(
                "min_pass_s", float, default=60.0, check=lambda x: None if x >= 0 else "must be ≥ 0"
            ),
            max_passes=sec.get("max_passes", int, default=500, check=whole(1, 100_000)),
        )
    else:
        raise DatasetError(f"{where}: source = {source!r} must be 'synthetic' or 'passes'")
    sec.finish()
    return geo


def _utc(text: str, where: str) -> str:
    ts = utc_timestamp(text, f"{where}: start_utc", DatasetError)
    return format_utc([ts])[0]


def _parse_noise(table, where, geometry) -> NoiseModel:
    sec = Section(table, where, DatasetError)
    zp = sec.get(
        "zero_point_mag",
        float,
        check=lambda x: None if -10 <= x <= 40 else "must be in [-10, 40]",
        what="magnitude giving 1 photo-electron per second",
    )
    sky = sec.get(
        "sky_e_per_s", float, default=0.0, check=in_range(0.0, 1e12), what="electrons per second"
    )
    read = sec.get("read_noise_e", float, default=0.0, check=in_range(0.0, 1e6), what="electrons")
    aperture = sec.get(
        "aperture_m", float, default=None, check=in_range(1e-3, 100.0), what="metres"
    )
    synthetic = isinstance(geometry, SyntheticSource)
    altitude = airmass = None
    if sec.has("altitude_m") or sec.has("airmass"):
        if not synthetic:
            key = "altitude_m" if "altitude_m" in sec.data else "airmass"
            raise DatasetError(
                f"{where}: {key} applies to synthetic geometry only; real passes use the "
                "site's altitude and the object's elevation"
            )
        altitude = sec.get("altitude_m", float, default=0.0, what="site altitude, metres")
        airmass = sec.get(
            "airmass",
            float,
            default=1.0,
            check=lambda x: None if 1 <= x <= 40 else "must be in [1, 40]",
        )
    sec.finish()
    if synthetic:
        altitude = 0.0 if altitude is None else altitude
        airmass = 1.0 if airmass is None else airmass
    return NoiseModel(zp, sky, read, aperture, altitude, airmass)
