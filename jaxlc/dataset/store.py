"""The Zarr v3 store of a bulk dataset: layout and shard writes (reading: ``reader``).

Layout (N curves of T samples, chunks of one shard along N)::

    DATA.zarr/
      zarr.json                 attrs: format, config text, fingerprint, jaxlc version,
                                git commit, classes, shapes, units, noise model
      t_s                 (T,)    float64  seconds from each curve's first exposure start
      visible             (N, T)  bool     observed and lit (see below)
      mag                 (N, T)  float32  finite where visible, else NaN
      flux_w_m2           (N, T)  float32  W/m² at the observer, > 0 where visible, else NaN
      phase_angle_deg     (N, T)  float32  finite where visible (NaN past a short pass)
      range_m             (N, T)  float32  finite where visible (NaN past a short pass)
      mag_noisy, flux_noisy_w_m2, mag_err   (N, T) float32   only with a [noise] table
      labels/<column>     (N,)    one array per label column (LABELS)
      passes/…                    the pass pool (real-pass geometry only)
      shards/done         (S,)    bool, one chunk per shard: written after the shard's data

``visible`` is the mask of every per-sample feature: the visibility rules
pass (always for synthetic geometry; elevation, Sun and Earth shadow for real
passes) *and* light arrives — the noise-free flux is > 0 in float32 (a
sample where no lit facet faces the observer has no magnitude, and is not
visible). Wherever ``visible`` is true, ``mag``, ``flux_w_m2``,
``phase_angle_deg``, ``range_m``, ``flux_noisy_w_m2`` and ``mag_err`` are
finite; ``mag_noisy`` is finite where, in addition, ``flux_noisy_w_m2 > 0``
(NaN otherwise: a noisy flux ≤ 0 has no magnitude). Wherever it is false the
photometric arrays are NaN. No array holds ±inf.

A shard's chunks are written whole (each chunk file atomically, by zarr's
local store) and its ``done`` flag last, so a killed run leaves at worst a
shard whose data may be partly new but which is not marked done; the next
run renders it again. :func:`open_dataset` refuses a store with missing
shards unless ``partial=True``.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import os
import shutil
from pathlib import Path

import numpy as np
import pandas as pd

from jaxlc.dataset.config import DatasetError
from jaxlc.io.provenance import git_commit, jaxlc_version
from jaxlc.memo import remember

#: Codec of the (N, T) arrays: LZ4 over bit-shuffled values. Against zarr's default
#: (Zstandard, level 0) a shard of the standard mix is written (:func:`write_shard`, its
#: labels included) in ~33 instead of ~42 ms on one core (~27 uncompressed), and 1,000
#: curves of it take 32 instead of 45 MB. (A store written before keeps its own codec:
#: Zarr records it per array.)
ARRAY_CODEC = {"cname": "lz4", "clevel": 5, "shuffle": "bitshuffle"}

#: Format tag written into every store's attributes.
FORMAT = "jaxlc-dataset/3"
#: Earlier formats, readable with a warning (never resumed): format → what differs.
OLD_FORMATS = {
    "jaxlc-dataset/1": (
        "its `visible` includes samples with zero flux (mag = +inf, mag_err = +inf); "
        "use visible & np.isfinite(mag) as the mask, or generate it again"
    ),
    "jaxlc-dataset/2": (
        "it has no attitude or tumble labels (every curve of it spins; its scenes are "
        "rebuilt from the spin labels)"
    ),
}

#: Per-sample arrays: dtype, fill value, unit/meaning; the noisy ones only with noise.
ARRAYS = {
    "mag": ("float32", np.nan, "apparent magnitude (noise-free); finite where visible, else NaN"),
    "flux_w_m2": (
        "float32",
        np.nan,
        "visible-band flux at the observer (W/m², noise-free); > 0 where visible, else NaN",
    ),
    "phase_angle_deg": ("float32", np.nan, "Sun-object-observer angle (deg)"),
    "range_m": ("float32", np.nan, "object-observer distance (m)"),
    "visible": (
        "bool",
        False,
        "observed and lit: visibility rules pass and the noise-free flux is > 0",
    ),
}
NOISE_ARRAYS = {
    "mag_noisy": ("float32", np.nan, "magnitude with noise; NaN: not visible or noisy flux ≤ 0"),
    "flux_noisy_w_m2": ("float32", np.nan, "flux with noise (W/m², may be ≤ 0); NaN: not visible"),
    "mag_err": (
        "float32",
        np.nan,
        "expected 1-sigma magnitude error of the noise model (≤ 100); NaN: not visible",
    ),
}
#: Per-curve label columns: dtype, fill value, meaning.
LABELS = {
    "class": ("str", "", "shape class name"),
    "class_id": ("int32", -1, "index of the class in attrs['classes']"),
    "mesh": ("str", "", "mesh file"),
    "scale": ("float64", np.nan, "[object] scale of the curve's scene (class scale × size factor)"),
    "materials": ("str", "", "JSON list of the scene [[material]] tables drawn for the curve"),
    "attitude": ("str", "", "JSON of the scene [attitude] table at t_s = 0 (spin or tumble)"),
    "body_axis_x": ("float64", np.nan, "spin axis in the body frame; NaN for a tumble"),
    "body_axis_y": ("float64", np.nan, ""),
    "body_axis_z": ("float64", np.nan, ""),
    "pole_ra_deg": ("float64", np.nan, "spin pole right ascension (deg); a tumble: L's"),
    "pole_dec_deg": ("float64", np.nan, "spin pole declination (deg); a tumble: L's"),
    "period_s": ("float64", np.nan, "spin period (s); a tumble: its precession period"),
    "phase_deg": ("float64", np.nan, "spin phase at t_s = 0 (deg); a tumble: about L"),
    "tumble_mode": ("str", "", "tumble: 'SAM' (short-axis) or 'LAM' (long-axis); '' spin"),
    "excitation": ("float64", np.nan, "tumble: 0 principal-axis spin … 1 separatrix (energy)"),
    "body_period_s": ("float64", np.nan, "tumble: period T_ω of ω in the body frame (s)"),
    "precession_period_s": ("float64", np.nan, "tumble: mean period of the rotation about L"),
    "inertia_x_kg_m2": ("float64", np.nan, "tumble: principal moment along body x (any scale)"),
    "inertia_y_kg_m2": ("float64", np.nan, "tumble: principal moment along body y"),
    "inertia_z_kg_m2": ("float64", np.nan, "tumble: principal moment along body z"),
    "subsamples": (
        "int32",
        0,
        "sub-exposures per exposure of the per-curve rule (adaptive blur starts there)",
    ),
    "instants_per_exposure": (
        "float64",
        np.nan,
        "mean sub-exposure instants per rendered exposure, adaptive refinement included",
    ),
    "shadows": ("bool", False, "self-shadowing rendered"),
    "geometry": ("str", "", "'synthetic' or 'pass'"),
    "utc_start": ("str", "", "UTC of the first sample"),
    "phase_start_deg": ("float64", np.nan, "synthetic: phase angle at the first sample"),
    "phase_end_deg": ("float64", np.nan, "synthetic: phase angle at the last sample"),
    "range_start_m": ("float64", np.nan, "synthetic: range at the first sample"),
    "range_end_m": ("float64", np.nan, "synthetic: range at the last sample"),
    "sun_ra_deg": ("float64", np.nan, "synthetic: Sun direction"),
    "sun_dec_deg": ("float64", np.nan, "synthetic: Sun direction"),
    "tilt_deg": ("float64", np.nan, "synthetic: tilt of the observer's plane"),
    "pass_id": ("int32", -1, "passes: index into the pool (passes/)"),
    "pass_offset": ("int32", -1, "passes: first row taken from the pass"),
    "norad_id": ("int64", -1, "passes: catalogue number"),
    "site": ("str", "", "passes: site name"),
    "visible_samples": ("int32", 0, "number of visible samples (observed and lit)"),
    "phase_mean_deg": ("float64", np.nan, "mean phase angle over visible samples"),
    "phase_min_deg": ("float64", np.nan, "min phase angle over visible samples"),
    "phase_max_deg": ("float64", np.nan, "max phase angle over visible samples"),
    "range_mean_m": ("float64", np.nan, "mean range over visible samples"),
}


def zarr_module():
    try:
        import zarr
    except ImportError:
        raise DatasetError(
            "datasets need zarr (and dask/distributed to run on workers): pip install 'jaxlc[dask]'"
        ) from None
    return zarr


def _classes_attr(config) -> list[dict]:
    import hashlib

    out = []
    for c in config.classes:
        r = c.render
        out.append(
            {
                "name": c.name,
                "mesh": str(c.mesh_path),
                "mesh_sha256": hashlib.sha256(c.mesh_path.read_bytes()).hexdigest(),
                "mesh_scale": c.mesh_scale,
                "weight": c.weight,
                "scale": list(c.scale),
                "period_s": list(c.period_s),
                "body_axis": None if c.body_axis is None else list(c.body_axis),
                "tumble": None if c.tumble is None else dataclasses.asdict(c.tumble),
                "render": r.as_table(),
            }
        )
    return out


def create_store(path: Path, config, pool=None) -> bool:
    """Create the empty store of ``config`` at ``path`` (atomically: built beside it, renamed).

    Returns:
        True; False if another process created it meanwhile (that store is kept).
    """
    zarr = zarr_module()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.creating")
    shutil.rmtree(tmp, ignore_errors=True)
    try:
        root = zarr.open_group(str(tmp), mode="w")
        n, t = config.count, config.samples
        arrays = dict(ARRAYS, **(NOISE_ARRAYS if config.noise is not None else {}))
        for name, (dtype, fill, _) in arrays.items():
            root.create_array(
                name,
                shape=(n, t),
                chunks=(config.shard_size, t),
                dtype=dtype,
                fill_value=fill,
                compressors=zarr.codecs.BloscCodec(**ARRAY_CODEC),
            )
        ts = root.create_array("t_s", shape=(t,), chunks=(t,), dtype="float64")
        ts[:] = np.arange(t) * config.cadence_s
        _create_labels(root.create_group("labels"), n, config.shard_size)
        shards = root.create_group("shards")
        shards.create_array(
            "done", shape=(config.n_shards,), chunks=(1,), dtype="bool", fill_value=False
        )
        if pool is not None:
            _write_pool(root.create_group("passes"), pool)
        noise = None if config.noise is None else dataclasses.asdict(config.noise)
        root.attrs.update(
            {
                "format": FORMAT,
                "fingerprint": config.fingerprint(),
                "config_text": config.text,
                "config_source": config.source,
                "jaxlc_version": jaxlc_version(),
                "git_commit": git_commit(),
                "created_utc": pd.Timestamp.now(tz="UTC").strftime("%Y-%m-%dT%H:%M:%SZ"),
                "count": n,
                "samples": t,
                "cadence_s": config.cadence_s,
                "exposure_s": config.exposure_s,
                "shard_size": config.shard_size,
                "n_shards": config.n_shards,
                "seed": config.seed,
                "batch_size": config.batch_size,
                "geometry_source": "synthetic" if pool is None else "passes",
                "noise": noise,
                "classes": _classes_attr(config),
                "arrays": {k: v[2] for k, v in arrays.items()},
                "labels": {k: v[2] for k, v in LABELS.items()},
            }
        )
        try:
            os.rename(tmp, path)
        except OSError:
            if not path.exists():
                raise
            # Another run created it first: use that one (its fingerprint is checked next).
            return False
        return True
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def remove_new_store(path: Path) -> None:
    """Remove a store this run created, as long as none of its shards is done.

    Called when a run fails before it has written anything worth keeping, so
    that no empty store is left behind; a store with finished shards stays
    (running the command again resumes it).
    """
    path = Path(path)
    with contextlib.suppress(Exception):  # unreadable: not ours to judge, keep it
        if (path / "zarr.json").is_file() and not done_shards(path).any():
            shutil.rmtree(path, ignore_errors=True)


def _write_pool(group, pool) -> None:
    from jaxlc.geometry.pool import POOL_ARRAYS

    for key in (*POOL_ARRAYS, "length", "norad_id", "site_alt_m"):
        x = np.asarray(getattr(pool, key))
        a = group.create_array(key, shape=x.shape, chunks=x.shape, dtype=x.dtype)
        a[...] = x
    for key in ("utc_start", "name", "site"):
        x = np.asarray(getattr(pool, key)).astype(object)
        a = group.create_array(key, shape=x.shape, chunks=x.shape, dtype=str)
        a[...] = x
    group.attrs["cadence_s"] = pool.cadence_s


def read_pool(path: str | Path):
    """The pass pool stored in a dataset (None for synthetic geometry)."""
    from jaxlc.geometry.pool import POOL_ARRAYS, PassPool

    root = zarr_module().open_group(str(path), mode="r")
    if "passes" not in root:
        return None
    g = root["passes"]
    fields = {k: np.asarray(g[k][...]) for k in (*POOL_ARRAYS, "length", "norad_id", "site_alt_m")}
    for k in ("utc_start", "name", "site"):
        fields[k] = np.asarray(g[k][...]).astype(object).astype(str)
    return PassPool(**fields, cadence_s=float(g.attrs["cadence_s"]))


def check_store(path: Path, config) -> None:
    """Raise unless ``path`` is a dataset store made from this very config."""
    zarr = zarr_module()
    try:
        root = zarr.open_group(str(path), mode="r")
        attrs = dict(root.attrs)
    except Exception as exc:
        raise DatasetError(
            f"{path} exists and is not a dataset store ({type(exc).__name__}: {exc}); "
            "choose another output path"
        ) from None
    if attrs.get("format") in OLD_FORMATS:
        raise DatasetError(
            f"{path} was written by an older jaxlc (format {attrs['format']!r}, now {FORMAT!r}) "
            "and cannot be resumed; write to a new path (or delete it to start again)"
        )
    if attrs.get("format") != FORMAT:
        raise DatasetError(
            f"{path} exists and is not a jaxlc dataset (format {attrs.get('format')!r}); "
            "choose another output path"
        )
    fingerprint = config.fingerprint()  # reads and hashes every mesh file
    if attrs.get("fingerprint") != fingerprint:
        raise DatasetError(
            f"{path} was made from a different config, count, seed or mesh files "
            f"(fingerprint {attrs.get('fingerprint')} ≠ {fingerprint}, from "
            f"{attrs.get('config_source')}); resume with the same config and options, or "
            "write to a new path"
        )


def add_missing_labels(path: str | Path) -> list[str]:
    """Give a store the label columns that it lacks (one made before they existed; the
    reader fills them for finished shards): before resuming it, in one process.

    Returns:
        The names of the columns added.
    """
    root = zarr_module().open_group(str(path), mode="r+")
    return _create_labels(root["labels"], int(root.attrs["count"]), int(root.attrs["shard_size"]))


def _create_labels(group, count: int, shard_size: int) -> list[str]:
    """Create the :data:`LABELS` columns that ``group`` lacks (all, in a new store), one
    value per curve in chunks of a shard; returns their names."""
    added = []
    for name, (dtype, fill, _) in LABELS.items():
        if name not in group:
            group.create_array(
                name,
                shape=(count,),
                chunks=(shard_size,),
                dtype=str if dtype == "str" else dtype,
                fill_value=fill,
            )
            added.append(name)
    return added


def done_shards(path: str | Path) -> np.ndarray:
    """(S,) bool: which shards are complete."""
    root = zarr_module().open_group(str(path), mode="r")
    return np.asarray(root["shards"]["done"][...], dtype=bool)


#: Opened arrays of the stores this process writes, by path: (identity of the root's
#: metadata file — a store made again differs —, {array path: zarr AsyncArray}).
_OPEN: dict[str, tuple[tuple, dict]] = {}
OPEN_STORES = 4


def write_shard(path: str | Path, shard: int, start: int, arrays: dict, labels: pd.DataFrame):
    """Write one shard's rows ``start …`` of every array and label, then mark it done.

    The arrays and labels are written together in one pass of zarr's event loop (one
    write per array, each waited for in turn, took 74 ms a shard of the standard mix,
    ~5 % of a worker's time); the ``done`` flag is written after all of them. Arrays are
    opened once per store and process (opening them took 15 of 45 ms a shard)."""
    zarr_module()  # a clear error where zarr is missing
    from zarr.api.asynchronous import open_group
    from zarr.core.sync import sync

    stop = start + len(labels)
    columns = {
        f"labels/{name}": labels[name].to_numpy().astype(object)
        if dtype == "str"
        else labels[name].to_numpy()
        for name, (dtype, _, _) in LABELS.items()
    }
    path = Path(path).resolve()
    st = os.stat(path / "zarr.json")
    key, ident = str(path), (st.st_ino, st.st_size, st.st_mtime_ns)
    if key not in _OPEN or _OPEN[key][0] != ident:
        remember(_OPEN, key, (ident, {}), OPEN_STORES)
    handles = _OPEN[key][1]

    async def write_all():
        root = None
        for name in [*arrays, *columns, "shards/done"]:  # opened in turn where new
            if name not in handles:
                root = root or await open_group(str(path), mode="r+")
                handles[name] = await root.getitem(name)
        await asyncio.gather(
            *(handles[n].setitem(slice(start, stop), x) for n, x in {**arrays, **columns}.items())
        )
        await handles["shards/done"].setitem(shard, True)  # last: never a partial shard

    sync(write_all())
