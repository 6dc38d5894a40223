"""Bulk light-curve datasets for machine learning.

A dataset config (TOML, :mod:`jaxlc.dataset.config_file`) says what to draw;
:func:`generate` renders it into a Zarr store, shard by shard
(:mod:`jaxlc.dataset.runner`, :mod:`jaxlc.dataset.shards`; each curve drawn by
:mod:`jaxlc.dataset.draw`, prepared like any render and evaluated in batches
by :mod:`jaxlc.dataset.bulk`); :func:`open` reads it back
(:mod:`jaxlc.dataset.store`). Every curve is a pure function of (config,
seed, curve index), so a shard — curves ``[k·shard_size, (k+1)·shard_size)``
— is a pure function of (config, shard index), and the arrays do not depend
on how many workers render them.

Example::

    import jaxlc.dataset

    ds = jaxlc.dataset.generate("experiments/configs/bulk_example.toml", "build/bulk.zarr")
    ds = jaxlc.dataset.open("build/bulk.zarr")       # later, or elsewhere
    mag = ds["mag"][:100]                            # (100, T) float32, NaN: not visible
    ds.labels[["class", "period_s", "pole_ra_deg"]]  # one row per curve
"""

from jaxlc.dataset.config import (
    DatasetConfig,
    DatasetError,
    MaterialPrior,
    NoiseModel,
    PassSource,
    ShapeClass,
    SyntheticSource,
)
from jaxlc.dataset.config_file import config_from_dict, load_config
from jaxlc.dataset.draw import Curve, curve_geometry, curve_rng, curve_scene, draw_curve
from jaxlc.dataset.reader import Dataset, open_dataset
from jaxlc.dataset.runner import generate

#: ``jaxlc.dataset.open(path)``: :func:`open_dataset`.
open = open_dataset

__all__ = [
    "Curve",
    "Dataset",
    "DatasetConfig",
    "DatasetError",
    "MaterialPrior",
    "NoiseModel",
    "PassSource",
    "ShapeClass",
    "SyntheticSource",
    "config_from_dict",
    "curve_geometry",
    "curve_rng",
    "curve_scene",
    "draw_curve",
    "generate",
    "load_config",
    "open",
    "open_dataset",
]
