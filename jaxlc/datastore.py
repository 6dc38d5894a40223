"""The Zarr v3 store of a bulk dataset: layout, shard writes, reading back.

Layout (N curves of T samples, chunks of one shard along N)::

    DATA.zarr/
      zarr.json                 attrs: format, config text, fingerprint, jaxlc version,
                                git commit, classes, shapes, units, noise model
      t_s                 (T,)    float64  seconds from each curve's first exposure start
      mag                 (N, T)  float32  NaN where not visible
      flux_w_m2           (N, T)  float32  W/m² at the observer, NaN where not visible
      phase_angle_deg     (N, T)  float32
      range_m             (N, T)  float32
      visible             (N, T)  bool
      mag_noisy, flux_noisy_w_m2, mag_err   (N, T) float32   only with a [noise] table
      labels/<column>     (N,)    one array per label column (LABELS)
      passes/…                    the pass pool (real-pass geometry only)
      shards/done         (S,)    bool, one chunk per shard: written after the shard's data

A shard's chunks are written whole (each chunk file atomically, by zarr's
local store) and its ``done`` flag last, so a killed run leaves at worst a
shard whose data may be partly new but which is not marked done; the next
run renders it again. :func:`open_dataset` refuses a store with missing
shards unless ``partial=True``.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pandas as pd

from jaxlc.dataset_config import DatasetError

#: Format tag written into every store's attributes.
FORMAT = "jaxlc-dataset/1"

#: Per-sample arrays: dtype, fill value, unit/meaning; the noisy ones only with noise.
ARRAYS = {
    "mag": ("float32", np.nan, "apparent magnitude (noise-free); NaN: not visible"),
    "flux_w_m2": ("float32", np.nan, "visible-band flux at the observer (W/m², noise-free)"),
    "phase_angle_deg": ("float32", np.nan, "Sun-object-observer angle (deg)"),
    "range_m": ("float32", np.nan, "object-observer distance (m)"),
    "visible": ("bool", False, "sample observed (visibility rules; rendered)"),
}
NOISE_ARRAYS = {
    "mag_noisy": ("float32", np.nan, "magnitude with noise; NaN: not visible or flux ≤ 0"),
    "flux_noisy_w_m2": ("float32", np.nan, "flux with noise (W/m², may be ≤ 0)"),
    "mag_err": ("float32", np.nan, "expected 1-sigma magnitude error of the noise model"),
}
#: Per-curve label columns: dtype, fill value, meaning.
LABELS = {
    "class": ("str", "", "shape class name"),
    "class_id": ("int32", -1, "index of the class in attrs['classes']"),
    "mesh": ("str", "", "mesh file"),
    "scale": ("float64", np.nan, "[object] scale of the curve's scene (class scale × size factor)"),
    "materials": ("str", "", "JSON list of the scene [[material]] tables drawn for the curve"),
    "body_axis_x": ("float64", np.nan, "spin axis in the body frame"),
    "body_axis_y": ("float64", np.nan, ""),
    "body_axis_z": ("float64", np.nan, ""),
    "pole_ra_deg": ("float64", np.nan, "spin pole right ascension (deg)"),
    "pole_dec_deg": ("float64", np.nan, "spin pole declination (deg)"),
    "period_s": ("float64", np.nan, "spin period (s)"),
    "phase_deg": ("float64", np.nan, "spin phase at t_s = 0 (deg)"),
    "subsamples": ("int32", 0, "sub-exposures per exposure (motion blur)"),
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
    "visible_samples": ("int32", 0, "number of visible samples"),
    "phase_mean_deg": ("float64", np.nan, "mean phase angle over visible samples"),
    "phase_min_deg": ("float64", np.nan, "min phase angle over visible samples"),
    "phase_max_deg": ("float64", np.nan, "max phase angle over visible samples"),
    "range_mean_m": ("float64", np.nan, "mean range over visible samples"),
}


def git_commit() -> str | None:
    """The checkout's commit (``+dirty`` with local changes), or None outside git."""
    here = Path(__file__).resolve().parent
    try:
        head = subprocess.run(
            ["git", "-C", str(here), "rev-parse", "HEAD"],
            capture_output=True,
            text=True,
            timeout=10,
            check=True,
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "-C", str(here), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True,
            text=True,
            timeout=10,
        ).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return None
    return head + ("+dirty" if dirty else "") if head else None


def _zarr():
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
                "body_axis": list(c.body_axis),
                "render": {
                    "shadows": r.shadows,
                    "shadow_grid": r.shadow.grid,
                    "shadow_spacing": r.shadow.spacing,
                    "shadow_max_subpoints": r.shadow.max_subpoints,
                    "shadow_interpolation": r.shadow.interpolation,
                    "blur": r.blur,
                    "max_subsamples": r.max_subsamples,
                    **({"subsamples": r.subsamples} if r.subsamples is not None else {}),
                },
            }
        )
    return out


def create_store(path: Path, config, pool=None) -> None:
    """Create the empty store of ``config`` at ``path`` (atomically: built beside it, renamed).

    If another process created it meanwhile, that store is kept.
    """
    from jaxlc import __version__

    zarr = _zarr()
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
                name, shape=(n, t), chunks=(config.shard_size, t), dtype=dtype, fill_value=fill
            )
        ts = root.create_array("t_s", shape=(t,), chunks=(t,), dtype="float64")
        ts[:] = np.arange(t) * config.cadence_s
        labels = root.create_group("labels")
        for name, (dtype, fill, _) in LABELS.items():
            labels.create_array(
                name,
                shape=(n,),
                chunks=(config.shard_size,),
                dtype=str if dtype == "str" else dtype,
                fill_value=fill,
            )
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
                "jaxlc_version": __version__,
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
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


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

    root = _zarr().open_group(str(path), mode="r")
    if "passes" not in root:
        return None
    g = root["passes"]
    fields = {k: np.asarray(g[k][...]) for k in (*POOL_ARRAYS, "length", "norad_id", "site_alt_m")}
    for k in ("utc_start", "name", "site"):
        fields[k] = np.asarray(g[k][...]).astype(object).astype(str)
    return PassPool(**fields, cadence_s=float(g.attrs["cadence_s"]))


def check_store(path: Path, config) -> None:
    """Raise unless ``path`` is a dataset store made from this very config."""
    zarr = _zarr()
    try:
        root = zarr.open_group(str(path), mode="r")
        attrs = dict(root.attrs)
    except Exception as exc:
        raise DatasetError(
            f"{path} exists and is not a dataset store ({type(exc).__name__}: {exc}); "
            "choose another output path"
        ) from None
    if attrs.get("format") != FORMAT:
        raise DatasetError(
            f"{path} exists and is not a jaxlc dataset (format {attrs.get('format')!r}); "
            "choose another output path"
        )
    if attrs.get("fingerprint") != config.fingerprint():
        raise DatasetError(
            f"{path} was made from a different config, count, seed or mesh files "
            f"(fingerprint {attrs.get('fingerprint')} ≠ {config.fingerprint()}, from "
            f"{attrs.get('config_source')}); resume with the same config and options, or "
            "write to a new path"
        )


def done_shards(path: str | Path) -> np.ndarray:
    """(S,) bool: which shards are complete."""
    root = _zarr().open_group(str(path), mode="r")
    return np.asarray(root["shards"]["done"][...], dtype=bool)


def write_shard(path: str | Path, shard: int, start: int, arrays: dict, labels: pd.DataFrame):
    """Write one shard's rows ``start …`` of every array and label, then mark it done."""
    root = _zarr().open_group(str(path), mode="r+")
    stop = start + len(labels)
    for name, x in arrays.items():
        root[name][start:stop] = x
    group = root["labels"]
    for name, (dtype, _, _) in LABELS.items():
        values = labels[name].to_numpy()
        group[name][start:stop] = values.astype(object) if dtype == "str" else values
    root["shards"]["done"][shard] = True  # last: a partial shard is never marked done


# ---------------------------------------------------------------------------
# Reading back


@dataclasses.dataclass(frozen=True)
class Dataset:
    """A dataset store opened for reading.

    Attributes:
        path: the store.
        attrs: provenance (config text, fingerprint, jaxlc version, git commit,
            classes, units; see :mod:`jaxlc.datastore`).
        t_s: (T,) seconds from each curve's first exposure start.
        labels: one row per available curve (index: curve number), columns
            :data:`LABELS`.
        done: (S,) bool, complete shards.
        root: the Zarr group; per-sample arrays are ``ds["mag"]`` etc. —
            lazy (N, T) ``zarr.Array``\\ s (index them to read numpy).

    Example:
        >>> ds = jaxlc.dataset.open("build/bulk.zarr")
        >>> mag = ds["mag"][:100]                 # (100, T) float32, NaN = not visible
        >>> ds.labels[["class", "period_s"]].head()
    """

    path: Path
    attrs: dict
    t_s: np.ndarray
    labels: pd.DataFrame
    done: np.ndarray
    root: object

    @property
    def complete(self) -> bool:
        return bool(self.done.all())

    @property
    def arrays(self) -> list[str]:
        """Names of the per-sample (N, T) arrays."""
        names = list(ARRAYS) + (list(NOISE_ARRAYS) if self.attrs.get("noise") else [])
        return names

    def __len__(self) -> int:
        return len(self.labels)

    def __getitem__(self, name: str):
        if name not in self.arrays:
            raise DatasetError(f"{self.path}: no array {name!r}; arrays: {', '.join(self.arrays)}")
        return self.root[name]

    def load(self, name: str) -> np.ndarray:
        """An (n, T) array as numpy, rows of the available curves (``labels.index``)."""
        arr = self[name]
        if self.complete:
            return np.asarray(arr[...])
        size = int(self.attrs["shard_size"])
        parts = [
            np.asarray(arr[k * size : min((k + 1) * size, arr.shape[0])])
            for k in np.flatnonzero(self.done)
        ]
        return np.concatenate(parts) if parts else np.empty((0, arr.shape[1]), arr.dtype)

    def batches(
        self,
        batch_size: int,
        fields=("mag", "visible"),
        labels=("class_id",),
        seed: int | None = None,
        drop_last: bool = False,
        shards_in_memory: int = 4,
    ):
        """Iterate over shuffled mini-batches: dicts of numpy arrays.

        Shards are read whole (one chunk per array), in a shuffled order,
        ``shards_in_memory`` at a time, and their curves shuffled together.

        Args:
            batch_size: curves per batch.
            fields: per-sample arrays to include, each (B, T).
            labels: label columns to include, each (B,).
            seed: shuffling seed (e.g. the epoch); None: no shuffling.
            drop_last: drop a last, smaller batch.
            shards_in_memory: shards read and mixed at a time.

        Yields:
            ``{"curve": (B,) int, field: (B, T), label: (B,)}``.
        """
        if batch_size < 1:
            raise DatasetError(f"batch_size = {batch_size!r} must be ≥ 1")
        unknown = [f for f in fields if f not in self.arrays] + [
            c for c in labels if c not in self.labels.columns
        ]
        if unknown:
            raise DatasetError(f"{self.path}: no array or label column {unknown[0]!r}")
        rng = np.random.default_rng(seed)
        shards = np.flatnonzero(self.done)
        if seed is not None:
            shards = rng.permutation(shards)
        size, n = int(self.attrs["shard_size"]), int(self.attrs["count"])
        carry = None
        for g in range(0, len(shards), max(1, shards_in_memory)):
            group = shards[g : g + shards_in_memory]
            rows = np.concatenate([np.arange(k * size, min((k + 1) * size, n)) for k in group])
            block = {"curve": rows}
            for f in fields:
                arr = self.root[f]
                block[f] = np.concatenate(
                    [np.asarray(arr[k * size : min((k + 1) * size, n)]) for k in group]
                )
            for c in labels:
                block[c] = self.labels[c].loc[rows].to_numpy()
            if seed is not None:
                order = rng.permutation(len(rows))
                block = {k: v[order] for k, v in block.items()}
            if carry is not None:
                block = {k: np.concatenate([carry[k], block[k]]) for k in block}
            m = len(block["curve"])
            full = m - m % batch_size
            for i in range(0, full, batch_size):
                yield {k: v[i : i + batch_size] for k, v in block.items()}
            carry = {k: v[full:] for k, v in block.items()} if full < m else None
        if carry is not None and not drop_last:
            yield carry

    def scene(self, curve: int) -> dict:
        """The scene of curve ``curve`` as a dict for :func:`jaxlc.scene_from_dict`."""
        row = self.labels.loc[curve]
        cls = self.attrs["classes"][int(row["class_id"])]
        return {
            "object": {"mesh": row["mesh"], "scale": float(row["scale"])},
            "material": json.loads(row["materials"]),
            "attitude": {
                "model": "spin",
                "body_axis": [float(row[f"body_axis_{c}"]) for c in "xyz"],
                "pole_ra_deg": float(row["pole_ra_deg"]),
                "pole_dec_deg": float(row["pole_dec_deg"]),
                "period_s": float(row["period_s"]),
                "phase_deg": float(row["phase_deg"]),
            },
            "sensor": {"exposure_s": float(self.attrs["exposure_s"])},
            "render": dict(cls["render"]),
        }

    def geometry(self, curve: int) -> pd.DataFrame:
        """The geometry table of curve ``curve`` (what it was rendered over)."""
        from jaxlc.geometry.synthetic import synthetic_geometry
        from jaxlc.tables import format_utc

        row = self.labels.loc[curve]
        t, cadence = int(self.attrs["samples"]), float(self.attrs["cadence_s"])
        exposure = float(self.attrs["exposure_s"])
        if row["geometry"] == "synthetic":
            return synthetic_geometry(
                duration_s=t * cadence,
                step_s=cadence,
                phase_start_deg=float(row["phase_start_deg"]),
                phase_end_deg=float(row["phase_end_deg"]),
                range_start_m=float(row["range_start_m"]),
                range_end_m=float(row["range_end_m"]),
                exposure_s=exposure,
                start_utc=row["utc_start"],
                sun_ra_deg=float(row["sun_ra_deg"]),
                sun_dec_deg=float(row["sun_dec_deg"]),
                tilt_deg=float(row["tilt_deg"]),
            )
        pool = read_pool(self.path)
        rows = pool.rows(int(row["pass_id"]), int(row["pass_offset"]), t)
        ts = np.arange(t) * cadence
        start = pd.Timestamp(row["utc_start"])
        df = pd.DataFrame({"utc": format_utc(start + pd.to_timedelta(ts, unit="s")), "t_s": ts})
        for b in ("rso", "sun", "obs"):
            for k, c in enumerate("xyz"):
                df[f"{b}_{c}_m"] = rows[f"{b}_m"][:, k]
        df["exposure_s"] = exposure
        df["elevation_deg"] = rows["elevation_deg"]
        df["sun_elevation_deg"] = np.nan
        df["shadow_nu"] = rows["shadow_nu"]
        df["visible"] = rows["visible"]
        df.attrs["frame"] = "GCRS"
        return df


def open_dataset(path: str | Path, partial: bool = False) -> Dataset:
    """Open a dataset store.

    Args:
        path: the ``.zarr`` folder written by :func:`jaxlc.dataset.generate`.
        partial: accept a store with missing shards (a run still going, or
            killed); only the complete shards' curves are in ``labels``.

    Raises:
        DatasetError: not a dataset, or incomplete without ``partial=True``.
    """
    zarr = _zarr()
    path = Path(path)
    if not path.exists():
        raise DatasetError(f"dataset {str(path)!r} does not exist")
    try:
        root = zarr.open_group(str(path), mode="r")
        attrs = dict(root.attrs)
    except Exception as exc:
        raise DatasetError(f"{path} is not a Zarr store ({type(exc).__name__}: {exc})") from None
    if attrs.get("format") != FORMAT:
        raise DatasetError(f"{path} is not a jaxlc dataset (format {attrs.get('format')!r})")
    done = np.asarray(root["shards"]["done"][...], dtype=bool)
    if not done.all() and not partial:
        raise DatasetError(
            f"{path} is incomplete: {int(done.sum())} of {len(done)} shards done; finish it by "
            "running the same `jaxlc generate` command again (it resumes), or open it with "
            "partial=True to read the finished shards"
        )
    size, n = int(attrs["shard_size"]), int(attrs["count"])
    rows = np.concatenate(
        [np.arange(k * size, min((k + 1) * size, n)) for k in np.flatnonzero(done)]
        or [np.empty(0, np.int64)]
    )
    group = root["labels"]
    columns = {}
    for name, (dtype, _, _) in LABELS.items():
        arr = group[name]
        values = np.asarray(arr[...])[rows] if len(rows) else np.empty(0)
        columns[name] = values.astype(object) if dtype == "str" else values
    labels = pd.DataFrame(columns, index=pd.Index(rows, name="curve"))
    with contextlib.suppress(ValueError):
        labels["class"] = pd.Categorical(
            labels["class"], categories=[c["name"] for c in attrs["classes"]]
        )
    return Dataset(
        path=path,
        attrs=attrs,
        t_s=np.asarray(root["t_s"][...]),
        labels=labels,
        done=done,
        root=root,
    )
