"""Bulk light-curve datasets for machine learning: the front door.

A dataset config (TOML, :mod:`jaxlc.dataset_config`) says what to draw;
:func:`generate` renders it into a Zarr store, shard by shard
(:mod:`jaxlc.generate`, batched by :mod:`jaxlc.bulk_render`); :func:`open`
reads it back (:mod:`jaxlc.datastore`). Every curve is a pure function of
(config, seed, curve index): curve i draws its shape class, size, materials,
spin and geometry from ``numpy.random.SeedSequence(seed, spawn_key=(i,))``
(the i-th child of ``SeedSequence(seed).spawn``), so a shard — curves
``[k·shard_size, (k+1)·shard_size)`` — is a pure function of (config, shard
index), and the arrays do not depend on how many workers render them.

Example::

    import jaxlc.dataset

    ds = jaxlc.dataset.generate("experiments/configs/bulk_example.toml", "build/bulk.zarr")
    ds = jaxlc.dataset.open("build/bulk.zarr")       # later, or elsewhere
    mag = ds["mag"][:100]                            # (100, T) float32, NaN: not visible
    ds.labels[["class", "period_s", "pole_ra_deg"]]  # one row per curve
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np

from jaxlc.dataset_config import (
    DatasetConfig,
    DatasetError,
    MaterialPrior,
    NoiseModel,
    PassSource,
    ShapeClass,
    SyntheticSource,
    config_from_dict,
    load_config,
)

__all__ = [
    "Curve",
    "DatasetConfig",
    "DatasetError",
    "MaterialPrior",
    "NoiseModel",
    "PassSource",
    "ShapeClass",
    "SyntheticSource",
    "config_from_dict",
    "curve_rng",
    "draw_curve",
    "generate",
    "load_config",
    "open",
]


# ---------------------------------------------------------------------------
# Draws: one curve from (config, seed, index)


@dataclasses.dataclass(frozen=True)
class Curve:
    """The drawn parameters of one light curve.

    Attributes:
        index: curve number in the dataset.
        class_id: index into ``config.classes``.
        scale: size factor drawn from the class (× the class's ``mesh_scale``).
        period_s, pole_ra_deg, pole_dec_deg, phase_deg: the spin; the phase is
            at the curve's first sample (t_s = 0).
        materials: one scene ``[[material]]`` dict per class material entry.
        geometry: synthetic: the :func:`jaxlc.synthetic_geometry` keyword
            arguments; passes: ``{"pass_id": p, "offset": k}`` (rows of the pool).
    """

    index: int
    class_id: int
    scale: float
    period_s: float
    pole_ra_deg: float
    pole_dec_deg: float
    phase_deg: float
    materials: tuple[dict, ...]
    geometry: dict


def _uniform(rng, r):
    u = rng.random()
    return r[0] if r[0] == r[1] else r[0] + (r[1] - r[0]) * u


def _log_uniform(rng, r):
    u = rng.random()
    if r[0] == r[1]:
        return r[0]
    if r[0] <= 0.0:
        return r[0] + (r[1] - r[0]) * u
    return math.exp(math.log(r[0]) + (math.log(r[1]) - math.log(r[0])) * u)


def curve_rng(seed: int, index: int, stream: int = 0) -> np.random.Generator:
    """The random stream of curve ``index``: 0 for its parameters, 1 for its noise.

    Stream 0 is ``SeedSequence(seed).spawn(index + 1)[index]``; stream 1 is
    that sequence's first child.
    """
    key = (index,) if stream == 0 else (index, stream - 1)
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=key))


def draw_curve(config: DatasetConfig, index: int, pass_lengths: np.ndarray | None = None) -> Curve:
    """Draw curve ``index`` (a pure function of the config, its seed and ``index``).

    Args:
        config: the dataset config.
        index: curve number, 0 … count − 1.
        pass_lengths: (P,) samples per pass of the pool (real passes only).

    Order of the draws (fixed; a fixed value still takes its draw, so changing
    a range never shifts the others): class, scale, period, pole (z, RA),
    phase, materials (rd, rs, nu, nv per entry), geometry.
    """
    rng = curve_rng(config.seed, index)
    weights = np.array([c.weight for c in config.classes])
    cum = np.cumsum(weights) / weights.sum()
    class_id = min(int(np.searchsorted(cum, rng.random(), side="right")), len(cum) - 1)
    cls = config.classes[class_id]
    scale = _uniform(rng, cls.scale)
    period = _log_uniform(rng, cls.period_s)
    z = 2.0 * rng.random() - 1.0
    ra = 360.0 * rng.random()
    phase = 360.0 * rng.random()
    materials = []
    for m in cls.materials:
        entry = {"part": m.part, "brdf": m.brdf, "rd": _uniform(rng, m.rd)}
        if m.brdf != "lambert":
            entry["rs"] = _uniform(rng, m.rs)
            entry["nu"] = _log_uniform(rng, m.nu)
            nv = _log_uniform(rng, m.nv if m.nv is not None else m.nu)
            entry["nv"] = nv if m.nv is not None else entry["nu"]
            entry["tangent"] = list(m.tangent)
        materials.append(entry)
    g = config.geometry
    if isinstance(g, SyntheticSource):
        start_m = _log_uniform(rng, g.range_start_m)
        end_m = _log_uniform(rng, g.range_end_m if g.range_end_m is not None else g.range_start_m)
        geometry = dict(
            phase_start_deg=_uniform(rng, g.phase_start_deg),
            phase_end_deg=_uniform(rng, g.phase_end_deg),
            range_start_m=start_m,
            range_end_m=end_m if g.range_end_m is not None else start_m,
            sun_ra_deg=360.0 * rng.random(),
            sun_dec_deg=_uniform(rng, g.sun_dec_deg),
            tilt_deg=_uniform(rng, g.tilt_deg),
        )
    else:
        if pass_lengths is None or len(pass_lengths) == 0:
            raise DatasetError("draw_curve: real-pass geometry needs the pool's pass lengths")
        p = int(rng.integers(len(pass_lengths)))
        spare = max(0, int(pass_lengths[p]) - config.samples)
        geometry = dict(pass_id=p, offset=int(rng.integers(spare + 1)))
    return Curve(
        index=index,
        class_id=class_id,
        scale=scale,
        period_s=period,
        pole_ra_deg=ra,
        pole_dec_deg=math.degrees(math.asin(z)),
        phase_deg=phase,
        materials=tuple(materials),
        geometry=geometry,
    )


def generate(
    config: DatasetConfig | str | Path,
    out_path: str | Path,
    workers: int | None = None,
    scheduler: str | None = None,
    count: int | None = None,
    seed: int | None = None,
    progress: bool = True,
    on_shard=None,
):
    """Render a dataset into a Zarr store (resuming one that is partly done).

    See :func:`jaxlc.generate.generate` for the arguments; returns the
    :class:`~jaxlc.datastore.Dataset`.
    """
    from jaxlc.generate import generate as _generate

    return _generate(config, out_path, workers, scheduler, count, seed, progress, on_shard)


def open(path: str | Path, partial: bool = False):
    """Open a dataset store for reading (see :func:`jaxlc.datastore.open_dataset`).

    Example (a training loop)::

        ds = jaxlc.dataset.open("build/bulk.zarr")
        for epoch in range(10):
            for batch in ds.batches(64, seed=epoch):     # dicts of numpy arrays
                x = np.nan_to_num(batch["mag"] - np.nanmedian(batch["mag"], axis=1,
                                                               keepdims=True))
                params, opt = train_step(params, opt, x, batch["class_id"])
    """
    from jaxlc.datastore import open_dataset

    return open_dataset(path, partial=partial)
