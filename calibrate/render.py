"""Light curves rendered by Blender/Cycles, in the same table as ``jaxlc.render``.

Two ways from pixel sums to magnitudes:

``camera = "ortho"`` (default)
    An orthographic camera looks along −v at the object; each pixel is a
    parallel beam, so the radiant intensity is I = B (ortho_scale/N)² W/sr for
    the pixel sum B of an N × N image of radiance, and F = I/d². No fitted
    constant.
``camera = "seed"``
    The seed paper's method: positions divided by ``scale`` (1000), a
    perspective camera at the (scaled) sensor, and a 1 × 1 m white Lambert plate
    at 10 km rendered with the same camera as the reference: its facet-model
    magnitude m_ff and its Blender instrumental magnitude I_mb = −2.5 log10(B_ref Ω_ref / t)
    calibrate every frame, m = m_ff − I_mb + I_m + 5 log10(scale) with
    I_m = −2.5 log10(B Ω / t) and Ω the pixel solid angle of each (zoomed) frame.
    The seed's Eq. (7) writes the same transfer with a distance factor because
    its renders kept the camera at a fixed distance; here the camera sits at the
    sensor, so the pixel sum already falls off as 1/d², and the scale term
    undoes the shortened distances.
"""

from __future__ import annotations

import dataclasses
import math
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

import jaxlc
from calibrate.job import BlenderOptions, material_spec, write_job
from calibrate.runner import default_timeout_s, run_worker
from jaxlc.body.attitude import matrix_to_quaternion
from jaxlc.rendering import photometry

#: The seed's calibration plate: 1 × 1 m, white Lambert, both sides.
PLATE_VERTICES = np.array([[-0.5, -0.5, 0.0], [0.5, -0.5, 0.0], [0.5, 0.5, 0.0], [-0.5, 0.5, 0.0]])
PLATE_FACES = np.array([[0, 1, 2], [0, 2, 3], [0, 2, 1], [0, 3, 2]])


@dataclasses.dataclass(frozen=True)
class Calibration:
    """The seed camera's reference: facet-model and Blender magnitudes of the plate."""

    m_ff: float
    i_mb: float
    pixel_sum: float

    @property
    def constant(self) -> float:
        """m_ff − I_mb: the zero point added to every instrumental magnitude."""
        return self.m_ff - self.i_mb


def mesh_parts(scene: jaxlc.Scene):
    """The scene's mesh (at its scale) part by part, for a Blender job.

    Returns:
        (parts: (name, vertices (V, 3) m, faces (M, 3)) per part, triangle_ids: (M,)
        index of each part's triangles in the mesh, radius: farthest vertex (m)).
    """
    mesh = scene.mesh  # at the scene's scale
    parts, ids = [], []
    for k, name in enumerate(mesh.part_names):
        tri = np.flatnonzero(mesh.face_part == k)
        used, inverse = np.unique(mesh.faces[tri], return_inverse=True)
        parts.append((name, mesh.vertices_m[used], inverse.reshape(-1, 3)))
        ids.append(tri)
    radius = float(np.max(np.linalg.norm(mesh.vertices_m, axis=1)))
    return parts, ids, radius


def keyframe_quaternions(prepared: jaxlc.Prepared) -> np.ndarray:
    """(n, K, 4) body→inertial quaternions at each exposure's K prepared instants."""
    q = matrix_to_quaternion(jaxlc.rotation_matrices(prepared))
    q = q.reshape(prepared.exposures.n_rows, prepared.exposures.subsamples, 4)
    # q and −q are one rotation; keep each exposure's keyframes on one side so that
    # Blender's interpolation between them is the short way round.
    for k in range(1, q.shape[1]):
        flip = np.sum(q[:, k] * q[:, k - 1], axis=1) < 0
        q[flip, k] *= -1.0
    return q


def camera_setup(options: BlenderOptions, radius_m: float, range_m: np.ndarray):
    """The job's camera, its per-frame arrays, and each frame's pixel footprint.

    Returns:
        (camera dict, {"camera_distance", ["fov_rad"]} (n,) arrays, (n,) area in m²
        at the object that one pixel covers, perpendicular to the view).
    """
    n_px = options.resolution
    if options.camera == "ortho":
        ortho = 2.2 * radius_m
        camera = {"mode": "ortho", "ortho_scale": ortho, "clip_end": 10.0 * radius_m + 10.0}
        per_frame = {"camera_distance": np.full(len(range_m), 2.0 * radius_m + 1.0)}
        return camera, per_frame, np.full(len(range_m), (ortho / n_px) ** 2)
    d_blender = np.asarray(range_m) / options.scale
    fov = 2.0 * np.arctan(1.15 * radius_m / d_blender)
    camera = {"mode": "perspective", "clip_start": 1e-3, "clip_end": 10.0 * float(d_blender.max())}
    footprint = (2.0 * d_blender * np.tan(fov / 2.0) / n_px) ** 2
    return camera, {"camera_distance": d_blender, "fov_rad": fov}, footprint


def blender_render(
    scene: jaxlc.Scene | str | Path,
    geometry: pd.DataFrame | str | Path,
    options: BlenderOptions | None = None,
    progress=None,
    work_dir: Path | None = None,
) -> pd.DataFrame:
    """Render a light curve with Cycles.

    Args:
        scene: a scene or its file (same file as ``jaxlc render``).
        geometry: a geometry table or its file.
        options: camera, image size, samples, bounces, motion blur, time-out.
        progress: optional callable(done_frames, total_frames).
        work_dir: folder for the job (default: a temporary one, removed).

    Returns:
        The light-curve table of ``jaxlc.render`` plus ``blender_seconds`` per
        row; ``attrs`` record the renderer and its settings.
    """
    options = options or BlenderOptions()
    # The same preparation as jaxlc.render (float64): rows, directions,
    # irradiance and the attitude at each exposure's instants — the exposure's
    # midpoint, or with motion blur its keyframes from start to end.
    prepared = jaxlc.prepare(scene, geometry, precision="float64")
    keyframes = 1
    if options.motion_blur:
        keyframes = options.keyframes or max(2, prepared.plan.subsamples)
        prepared = jaxlc.prepare(
            prepared.scene,
            prepared.table,
            precision="float64",
            subsamples=keyframes,
            quadrature="endpoints",
        )
    scene, table, geo = prepared.scene, prepared.table, prepared.geometry
    idx = prepared.exposures.rows
    parts, _ids, radius = mesh_parts(scene)
    materials = [
        material_spec(name, brdf)
        for name, brdf in zip(
            [p[0] for p in parts], scene.materials_for([p[0] for p in parts]), strict=True
        )
    ]
    settings = options.job_settings() | {
        "motion_steps": max(1, math.ceil(math.log2(max(keyframes, 1))) + 2)
    }

    pixel_sum = np.full(len(table), np.nan)
    seconds = np.full(len(table), np.nan)
    intensity = np.full(len(table), np.nan)  # I/E, m² sr⁻¹
    calibration = None
    with tempfile.TemporaryDirectory(prefix="jaxlc-blender-") as tmp:
        root = Path(work_dir) if work_dir is not None else Path(tmp)
        if len(idx):
            rng = geo.range_m[idx]
            camera, per_frame, footprint_m2 = camera_setup(options, radius, rng)
            frames = {
                "quaternions": keyframe_quaternions(prepared),
                "sun_dir": geo.sun_dir[idx],
                "obs_dir": geo.obs_dir[idx],
                "irradiance_w_m2": geo.irradiance_w_m2[idx],
                **per_frame,
            }
            extra = {"keep_images": options.keep_images is not None}
            if options.keep_images is not None:
                extra["image_dir"] = str(Path(options.keep_images).resolve())
            job = write_job(root / "object", parts, materials, camera, settings, frames, extra)
            timeout = options.timeout_s or default_timeout_s(
                len(idx), options.resolution, options.samples, keyframes
            )
            result = run_worker(job, timeout, progress)
            pixel_sum[idx] = result["pixel_sum"]
            seconds[idx] = result["seconds"]
            e = geo.irradiance_w_m2[idx]
            if options.camera == "ortho":
                intensity[idx] = result["pixel_sum"] * footprint_m2 / e
            else:
                calibration = seed_calibration(options, root / "reference")
                fov = per_frame["fov_rad"]
                omega = (2.0 * np.tan(fov / 2.0) / options.resolution) ** 2
                instrumental = -2.5 * np.log10(result["pixel_sum"] * omega)
                mag = calibration.constant + instrumental + 5.0 * math.log10(options.scale)
                flux = photometry.C_SUN_VIS_W_M2 * 10 ** (-0.4 * (mag - photometry.M_SUN_V))
                intensity[idx] = flux * rng**2 / e

    out = jaxlc.lightcurve_table(
        table, geo, intensity, blender_pixel_sum=pixel_sum, blender_seconds=seconds
    )
    out.attrs.update(
        {
            "frame": table.attrs.get("frame", "unknown"),
            "scene": scene.source,
            "renderer": "blender cycles (bpy)",
            "camera": options.camera,
            "resolution": str(options.resolution),
            "samples": str(options.samples),
            "bounces": str(options.bounces),
            "motion_blur": f"{options.motion_blur} ({keyframes} keyframes)",
        }
    )
    if calibration is not None:
        out.attrs["seed_calibration"] = f"m_ff {calibration.m_ff:.6f}, I_mb {calibration.i_mb:.6f}"
    return out


def seed_calibration(options: BlenderOptions, job_dir: Path) -> Calibration:
    """Render the seed's reference plate and compare it with the facet model.

    A 1 × 1 m white Lambert plate at ``reference_m`` faces the camera with the
    Sun behind the camera (phase angle 0) at 1 AU: the facet model gives
    m_ff = −26.74 − 2.5 log10((1/π) A / d_r²), Blender the pixel sum B_ref
    with the same camera, zoomed to the plate.
    """
    d_r = options.reference_m
    fov = 2.0 * math.atan(1.15 * math.sqrt(0.5) / d_r)
    frames = {
        "quaternions": np.array([[[1.0, 0.0, 0.0, 0.0]]]),
        "sun_dir": np.array([[0.0, 0.0, 1.0]]),
        "obs_dir": np.array([[0.0, 0.0, 1.0]]),
        "irradiance_w_m2": np.array([photometry.C_SUN_VIS_W_M2]),
        "camera_distance": np.array([d_r]),
        "fov_rad": np.array([fov]),
    }
    settings = options.job_settings() | {"motion_blur": False, "motion_steps": 1}
    camera = {"mode": "perspective", "clip_start": 1e-3, "clip_end": 10.0 * d_r}
    material = [{"part": "plate", "diffuse": 1.0, "glossy": 0.0}]
    job = write_job(
        job_dir, [("plate", PLATE_VERTICES, PLATE_FACES)], material, camera, settings, frames
    )
    result = run_worker(job, default_timeout_s(1, options.resolution, options.samples))
    omega = (2.0 * math.tan(fov / 2.0) / options.resolution) ** 2
    b_ref = float(result["pixel_sum"][0])
    flux_ff = photometry.C_SUN_VIS_W_M2 * (1.0 / math.pi) * 1.0 / d_r**2
    m_ff = float(photometry.magnitude(flux_ff))
    return Calibration(m_ff=m_ff, i_mb=-2.5 * math.log10(b_ref * omega), pixel_sum=b_ref)
