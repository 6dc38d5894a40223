"""The parsed dataset config: shape classes, geometry source, noise, sizes.

What a dataset config file holds once :mod:`jaxlc.dataset.config_file` has
read and checked it. Every array of a dataset is a pure function of a
:class:`DatasetConfig` (its :meth:`~DatasetConfig.fingerprint` includes the
mesh files), the seed and the curve index.
"""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
import json
from pathlib import Path

from jaxlc.errors import JaxlcError
from jaxlc.geometry.observe import Visibility
from jaxlc.rendering.options import RenderOptions


class DatasetError(JaxlcError):
    """A dataset config or store is malformed, incomplete or inconsistent."""


#: Largest number of curves of one dataset.
MAX_COUNT = 1_000_000_000
#: Most samples (curves × samples per curve) in one shard: a shard is rendered in
#: the memory of one worker, about 1.5 kB per sample (1.3 GB for 200 × 3,600).
MAX_SHARD_SAMPLES = 1_000_000


@dataclasses.dataclass(frozen=True)
class MaterialPrior:
    """One ``[[class.material]]`` entry: a BRDF with a range per parameter.

    ``rd``/``rs`` are drawn uniformly, ``nu``/``nv`` log-uniformly (uniformly
    when the range includes 0); ``nv = None`` means nv = nu (isotropic).
    """

    part: str
    brdf: str
    rd: tuple[float, float]
    rs: tuple[float, float] | None = None
    nu: tuple[float, float] | None = None
    nv: tuple[float, float] | None = None
    tangent: tuple[float, float, float] = (0.0, 0.0, 1.0)


@dataclasses.dataclass(frozen=True)
class TumblePrior:
    """A ``[class.tumble]`` table: the class tumbles torque-free instead of spinning.

    Attributes:
        inertia_kg_m2: per body axis x, y, z a (low, high) principal moment
            (log-uniform; any common scale; every corner of the box obeys the
            triangle inequality).
        mode: ``"SAM"``, ``"LAM"`` or ``"any"`` (each with probability ½).
        excitation: (low, high) in [0, 1) (uniform): 0 a principal-axis spin,
            → 1 the separatrix (:func:`jaxlc.body.tumble.tumble_from_invariants`).

    The class's ``period_s`` is then the precession period (the mean period of
    the rotation about L), its pole the direction of L.
    """

    inertia_kg_m2: tuple[tuple[float, float], ...]
    mode: str = "any"
    excitation: tuple[float, float] = (0.0, 0.9)

    def corners(self):
        """The 8 corners of the inertia box, (3,) tuples."""
        return list(itertools.product(*self.inertia_kg_m2))


@dataclasses.dataclass(frozen=True)
class ShapeClass:
    """A shape class: mesh, material priors, size and spin priors, render options.

    Attributes:
        name: label of the class.
        mesh_path: the mesh file.
        mesh_scale: the scene's ``[object] scale`` (file units → m; 1 for a bare mesh).
        weight: relative frequency.
        scale: (low, high) size factor on top of ``mesh_scale`` (uniform).
        period_s: (low, high) spin period (log-uniform); a tumble's precession period.
        body_axis: spin axis in the body frame (unit); None for a tumbling class.
        materials: material priors, one per part or ``"*"``.
        render: shadows and blur options (a scene's ``[render]`` table).
        tumble: the class tumbles (torque-free) with these priors; None: it spins.
    """

    name: str
    mesh_path: Path
    mesh_scale: float
    weight: float
    scale: tuple[float, float]
    period_s: tuple[float, float]
    body_axis: tuple[float, float, float] | None
    materials: tuple[MaterialPrior, ...]
    render: RenderOptions
    tumble: TumblePrior | None = None


@dataclasses.dataclass(frozen=True)
class SyntheticSource:
    """Synthetic phase-angle tracks (:func:`jaxlc.synthetic_geometry`), ranges per curve."""

    phase_start_deg: tuple[float, float]
    phase_end_deg: tuple[float, float]
    range_start_m: tuple[float, float]
    range_end_m: tuple[float, float] | None
    sun_dec_deg: tuple[float, float] = (-23.44, 23.44)
    tilt_deg: tuple[float, float] = (-90.0, 90.0)
    start_utc: str = "2019-07-07T12:00:00Z"


@dataclasses.dataclass(frozen=True)
class PassSource:
    """Real passes: objects of TLE files seen from sites over a window.

    A pool of pass geometry tables is computed once per run (stored in the
    dataset); each curve draws a pass and a start offset within it.
    """

    tle_paths: tuple[Path, ...]
    norad: tuple[int, ...] | None
    sites: tuple[str, ...]
    start_utc: str
    days: float
    search_step_s: float = 10.0
    rules: Visibility = dataclasses.field(default_factory=Visibility)
    min_pass_s: float = 60.0
    max_passes: int = 500


@dataclasses.dataclass(frozen=True)
class NoiseModel:
    """Photon, sky, read and scintillation noise (see :mod:`jaxlc.dataset.noise`)."""

    zero_point_mag: float
    sky_e_per_s: float = 0.0
    read_noise_e: float = 0.0
    aperture_m: float | None = None
    altitude_m: float | None = None
    airmass: float | None = None


@dataclasses.dataclass(frozen=True)
class DatasetConfig:
    """A parsed dataset config (see the module docstring for the file format)."""

    count: int
    samples: int
    cadence_s: float
    exposure_s: float
    shard_size: int
    seed: int
    batch_size: int
    classes: tuple[ShapeClass, ...]
    geometry: SyntheticSource | PassSource
    noise: NoiseModel | None
    text: str = ""
    source: str = "<config>"

    @property
    def n_shards(self) -> int:
        return -(-self.count // self.shard_size)

    def shard_rows(self, shard: int) -> range:
        """Curve indices of shard ``shard``."""
        if not 0 <= shard < self.n_shards:
            raise DatasetError(f"shard {shard} does not exist (0 … {self.n_shards - 1})")
        return range(shard * self.shard_size, min((shard + 1) * self.shard_size, self.count))

    def fingerprint(self) -> str:
        """Hash of everything the arrays depend on (the parsed config and the mesh files)."""

        def plain(x):
            if dataclasses.is_dataclass(x):
                return {f.name: plain(getattr(x, f.name)) for f in dataclasses.fields(x)}
            if isinstance(x, tuple | list):
                return [plain(v) for v in x]
            if isinstance(x, Path):
                return str(x)
            return x

        data = plain(dataclasses.replace(self, text="", source=""))
        h = hashlib.sha256(json.dumps(data, sort_keys=True, default=repr).encode())
        for c in self.classes:
            h.update(hashlib.sha256(c.mesh_path.read_bytes()).digest())
        return h.hexdigest()[:32]
