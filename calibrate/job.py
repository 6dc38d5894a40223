"""Render jobs for the Blender worker: the scene and geometry, resolved to plain data.

The worker (``calibrate/worker.py``, in ``.venv-blender``) imports neither jax
nor jaxlc, so everything is decided here, in the main environment: the mesh
parts as vertex and face arrays (metres, body frame), one Cycles material per
part, and per frame the body → inertial rotation as quaternions (computed by
jaxlc's own attitude model: the two renderers share the spin by construction),
the body-centred Sun and observer directions, the irradiance and the camera.

A job is a folder: ``job.json`` (settings, with the format's ``version``,
:data:`JOB_VERSION`) and ``arrays.npz`` (arrays). The worker checks the
version and every array's shape before it renders anything.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np

from jaxlc import AbstractBRDF, ASGlossy, AshikhminShirley, JaxlcError, Lambert

#: Version of the job format; the worker refuses any other (``calibrate/worker.py``).
JOB_VERSION = 2


@dataclasses.dataclass(frozen=True)
class BlenderOptions:
    """How Cycles renders a light curve.

    Attributes:
        camera: ``"ortho"`` — an orthographic far-field camera: the pixel sum
            B gives the radiant intensity I = B (ortho_scale/N)², no fitted
            constant — or ``"seed"`` — the seed paper's perspective camera at the
            sensor with positions divided by ``scale``, calibrated by a 1 × 1 m
            plate at ``reference_m``.
        resolution: image side N in pixels.
        samples: Cycles samples per pixel.
        bounces: 0 for direct light only (like the facet model), more for
            secondary reflections.
        motion_blur: keyframe the spin over each exposure and let Cycles blur it.
        keyframes: keyframes per exposure with motion blur (default from the
            jaxlc render plan's sub-exposures, at least 2).
        scale: position scale of the seed camera.
        reference_m: distance of the seed camera's calibration plate.
        blackbody: colour the Sun as a 5778 K black body (grey-scale output:
            changes the luminance weighting only).
        seed: Cycles noise seed.
        threads: CPU threads (0: all).
        timeout_s: give up on the worker after this long (default: generous,
            from the frame count and image size).
        keep_images: folder to keep the EXR images in (default: deleted).
    """

    camera: str = "ortho"
    resolution: int = 128
    samples: int = 64
    bounces: int = 0
    motion_blur: bool = False
    keyframes: int | None = None
    scale: float = 1000.0
    reference_m: float = 1.0e4
    blackbody: bool = False
    seed: int = 0
    threads: int = 0
    timeout_s: float | None = None
    keep_images: Path | None = None

    def __post_init__(self):
        checks = [
            ("camera", self.camera in ("ortho", "seed"), "must be 'ortho' or 'seed'"),
            ("resolution", 8 <= self.resolution <= 8192, "must be in [8, 8192]"),
            ("samples", 1 <= self.samples <= 1 << 16, "must be in [1, 65536]"),
            ("bounces", 0 <= self.bounces <= 1024, "must be in [0, 1024]"),
            (
                "keyframes",
                self.keyframes is None or 2 <= self.keyframes <= 256,
                "must be in [2, 256]",
            ),
            ("scale", self.scale > 0, "must be > 0"),
            ("reference_m", self.reference_m > 0, "must be > 0"),
        ]
        for name, ok, why in checks:
            if not ok:
                raise JaxlcError(f"Blender option {name} = {getattr(self, name)!r} {why}")

    def job_settings(self) -> dict:
        return {
            "samples": self.samples,
            "bounces": self.bounces,
            "resolution": self.resolution,
            "seed": self.seed,
            "threads": self.threads,
            "motion_blur": self.motion_blur,
            "blackbody": self.blackbody,
        }


def roughness(n: float) -> float:
    """Cycles roughness of an Ashikhmin–Shirley exponent: (2/(n+2))^¼ (PHYSICS.md §5)."""
    return (2.0 / (n + 2.0)) ** 0.25


def anisotropy(nu: float, nv: float) -> tuple[float, float]:
    """(roughness, anisotropy) of Cycles' Glossy BSDF for exponents (nu, nv).

    Cycles sets α_x = r²/a, α_y = r² a with a = √(1 − 0.9 anisotropy) along its
    tangent; the AS lobe has α = √(2/(n+2)). Cycles' tangent here is radial about
    the material's tangent axis, i.e. along jaxlc's w on surfaces of revolution
    about that axis, so α_x ↔ nv and α_y ↔ nu (elsewhere an approximation).
    """
    ax, ay = math.sqrt(2.0 / (nv + 2.0)), math.sqrt(2.0 / (nu + 2.0))
    r2 = math.sqrt(ax * ay)
    aspect = math.sqrt(ay / ax)
    return math.sqrt(r2), float(np.clip((1.0 - aspect**2) / 0.9, -0.99, 0.99))


def material_spec(part: str, brdf: AbstractBRDF) -> dict:
    """The Cycles material closest to a jaxlc BRDF (exact for lambert and isotropic as-glossy).

    ``ashikhmin-shirley`` becomes Lambert with the AS diffuse term's albedo
    rd(1 − rs) plus the AS lobe with a constant colour rs: Cycles has neither the
    28/23 diffuse shape [1 − (1 − μ/2)⁵]² nor Schlick's Fresnel term, so that
    material differs, most at grazing angles and large phase angles.
    """
    f = lambda x: float(np.asarray(x))  # noqa: E731
    if isinstance(brdf, Lambert):
        return {"part": part, "diffuse": f(brdf.rd), "glossy": 0.0}
    nu, nv = f(brdf.nu), f(brdf.nv)
    rough, aniso = anisotropy(nu, nv) if nu != nv else (roughness(nu), 0.0)
    if isinstance(brdf, ASGlossy):
        return {
            "part": part,
            "diffuse": f(brdf.rd),
            "glossy": f(brdf.rs),
            "roughness": rough,
            "anisotropy": aniso,
        }
    if isinstance(brdf, AshikhminShirley):
        rd, rs = f(brdf.rd), f(brdf.rs)
        return {
            "part": part,
            "diffuse": rd * (1 - rs),
            "glossy": rs,
            "roughness": rough,
            "anisotropy": aniso,
        }
    raise JaxlcError(f"no Cycles material for {type(brdf).__name__}")


def write_job(
    job_dir: Path,
    parts: list[tuple[str, np.ndarray, np.ndarray]],
    materials: list[dict],
    camera: dict,
    settings: dict,
    frames: dict,
    extra: dict | None = None,
) -> Path:
    """Write ``job.json`` and ``arrays.npz`` into ``job_dir``.

    Args:
        parts: (name, vertices (V, 3) m, faces (M, 3)) per mesh part.
        materials: one :func:`material_spec` per part name.
        camera: ``{"mode": "ortho", "ortho_scale": s}`` or ``{"mode": "perspective"}``.
        settings: :meth:`BlenderOptions.job_settings` (+ ``motion_steps``).
        frames: arrays ``quaternions (T, K, 4)``, ``sun_dir``, ``obs_dir`` (T, 3),
            ``irradiance_w_m2``, ``camera_distance`` (T,), and ``fov_rad`` (T,)
            for a perspective camera.
    """
    job_dir = Path(job_dir)
    job_dir.mkdir(parents=True, exist_ok=True)
    arrays = {}
    for k, (_, v, f) in enumerate(parts):
        arrays[f"vertices_{k}"] = np.asarray(v, np.float64)
        arrays[f"faces_{k}"] = np.asarray(f, np.int64)
    for key, value in frames.items():
        arrays[key] = np.asarray(value, np.float64)
    np.savez(job_dir / "arrays.npz", **arrays)
    job = {
        "version": JOB_VERSION,
        "parts": [name for name, _, _ in parts],
        "materials": materials,
        "camera": camera,
        "render": settings,
        **(extra or {}),
    }
    (job_dir / "job.json").write_text(json.dumps(job, indent=1))
    return job_dir
