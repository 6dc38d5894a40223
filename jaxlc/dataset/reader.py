"""Reading a dataset store back: arrays, labels, batches, and what each curve came from.

:func:`open_dataset` (also ``jaxlc.dataset.open``) opens a store written by
:func:`jaxlc.dataset.generate` (layout: :mod:`jaxlc.dataset.store`);
:class:`Dataset` serves its arrays lazily, its labels as a table, shuffled
batches for training loops, and the scene and geometry of any curve
(:meth:`Dataset.scene`, :meth:`Dataset.geometry`) for re-rendering it with
:func:`jaxlc.render` or Blender.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import warnings
from pathlib import Path

import numpy as np
import pandas as pd

from jaxlc.dataset.config import DatasetError
from jaxlc.dataset.store import (
    ARRAYS,
    FORMAT,
    LABELS,
    NOISE_ARRAYS,
    OLD_FORMATS,
    read_pool,
    zarr_module,
)


@dataclasses.dataclass(frozen=True)
class Dataset:
    """A dataset store opened for reading.

    Attributes:
        path: the store.
        attrs: provenance (config text, fingerprint, jaxlc version, git commit,
            classes, units; see :mod:`jaxlc.dataset.store`).
        t_s: (T,) seconds from each curve's first exposure start.
        labels: one row per available curve (index: curve number), columns
            :data:`LABELS`.
        done: (S,) bool, complete shards.
        root: the Zarr group; per-sample arrays are ``ds["mag"]`` etc. —
            lazy (N, T) ``zarr.Array``\\ s (index them to read numpy).

    Per-sample arrays, each (N, T), and their mask ``visible``:

    ==================  =======  ===============================================
    ``visible``         bool     observed and lit: the visibility rules pass
                                 (always for synthetic geometry; elevation, Sun,
                                 Earth shadow for real passes) and the noise-free
                                 flux is > 0 (a sample where no lit facet faces
                                 the observer has no magnitude: not visible)
    ``mag``             float32  apparent magnitude; finite where visible, else NaN
    ``flux_w_m2``       float32  flux at the observer (W/m²); > 0 where visible,
                                 else NaN
    ``phase_angle_deg`` float32  Sun-object-observer angle (deg); finite where
                                 visible (NaN past the end of a short pass)
    ``range_m``         float32  object-observer distance (m); as phase_angle_deg
    ``flux_noisy_w_m2`` float32  with noise (W/m², may be ≤ 0); finite where
                                 visible, else NaN
    ``mag_noisy``       float32  with noise; finite where visible and
                                 ``flux_noisy_w_m2 > 0``, else NaN
    ``mag_err``         float32  expected 1-sigma error (mag), in (0, 100]
                                 where visible, else NaN
    ==================  =======  ===============================================

    The last three exist with a ``[noise]`` table only. No array holds ±inf,
    so ``np.where(visible, x, 0.0)`` is finite for every array but
    ``mag_noisy`` (mask that one with ``np.isfinite``). :meth:`geometry` gives
    the visibility rules' own mask (its ``visible`` column), which also counts
    unlit samples.

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
            ``{"curve": (B,) int, field: (B, T), label: (B,)}``; each field
            is finite where ``visible`` is true (``mag_noisy``: where also
            ``flux_noisy_w_m2 > 0``), see the class docstring.
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
        from jaxlc.dataset.draw import scene_dict, spin_attitude

        row = self.labels.loc[curve]
        cls = self.attrs["classes"][int(row["class_id"])]
        if row["attitude"]:
            attitude = json.loads(row["attitude"])
        else:  # format 2: every curve spins
            attitude = spin_attitude(
                [row[f"body_axis_{c}"] for c in "xyz"],
                row["pole_ra_deg"],
                row["pole_dec_deg"],
                row["period_s"],
                row["phase_deg"],
            )
        return scene_dict(
            row["mesh"],
            row["scale"],
            json.loads(row["materials"]),
            attitude,
            self.attrs["exposure_s"],
            cls["render"],
        )

    def geometry(self, curve: int) -> pd.DataFrame:
        """The geometry table of curve ``curve`` (what it was rendered over)."""
        from jaxlc.geometry.synthetic import synthetic_geometry
        from jaxlc.io.tables import geometry_frame
        from jaxlc.io.utc import utc_timestamp

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
        return geometry_frame(
            utc_timestamp(row["utc_start"]),
            np.arange(t) * cadence,
            rows["rso_m"],
            rows["sun_m"],
            rows["obs_m"],
            exposure,
            rows["elevation_deg"],
            shadow_nu=rows["shadow_nu"],
            visible=rows["visible"],
        )


def open_dataset(path: str | Path, partial: bool = False) -> Dataset:
    """Open a dataset store.

    Args:
        path: the ``.zarr`` folder written by :func:`jaxlc.dataset.generate`.
        partial: accept a store with missing shards (a run still going, or
            killed); only the complete shards' curves are in ``labels``.

    Raises:
        DatasetError: not a dataset, or incomplete without ``partial=True``.
    """
    zarr = zarr_module()
    path = Path(path)
    if not path.exists():
        raise DatasetError(f"dataset {str(path)!r} does not exist")
    try:
        root = zarr.open_group(str(path), mode="r")
        attrs = dict(root.attrs)
    except Exception as exc:
        raise DatasetError(f"{path} is not a Zarr store ({type(exc).__name__}: {exc})") from None
    if attrs.get("format") in OLD_FORMATS:
        warnings.warn(
            f"{path} was written by an older jaxlc (format {attrs['format']!r}): "
            f"{OLD_FORMATS[attrs['format']]}",
            stacklevel=2,
        )
    elif attrs.get("format") != FORMAT:
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
    for name, (dtype, fill, _) in LABELS.items():
        if name not in group:  # a label that an older format lacks
            columns[name] = np.full(len(rows), fill, dtype=object if dtype == "str" else dtype)
            continue
        values = np.asarray(group[name][...])[rows] if len(rows) else np.empty(0)
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
