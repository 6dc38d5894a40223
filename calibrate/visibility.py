"""Any jaxlc material rendered exactly for direct light, with Cycles' own shadows.

Cycles cannot take a new BSDF, but for direct sunlight it need not: the Sun is
one known direction per frame, so the radiance of a surface point is
E f_r(n, s, v) (n·s) wherever Cycles says the point is seen and sunlit. The
worker renders each frame twice at one sample per pixel through a point filter
(every pixel is one ray through its centre, so nothing is averaged):

1. *which triangle* each pixel sees: an emission shader whose value is the
   triangle's index (background 0);
2. *whether that point is sunlit*: a white Lambert surface under the Sun with
   no bounces, exactly 0 in shadow or facing away.

It returns, per frame and triangle, the numbers of seen and of seen-and-sunlit
pixels. With the pixel's footprint a at the object (orthographic camera:
(ortho_scale/N)²; the seed's perspective camera: (2 d tan(fov/2)/N)² at its
distance d), facet f's lit-and-seen fraction is

    frac_f = a × (its seen-and-sunlit pixels) / (A_f μ_f),      μ_f = n_f · v > 0,

and the light curve is the facet model's own sum with these fractions as the
facets' weights (:func:`jaxlc.body.facet_model.facet_intensity`): the exact
BRDF of any material, Ashikhmin–Shirley included, with Cycles' visibility.

Exact for direct light up to (a) the sampling of areas by pixel centres, an
error per facet edge that falls as 1/N (512 px by default), and (b) for the
perspective camera, its parallax: the BRDF is evaluated for the central view
direction, which is off by up to the object's radius over the camera's scaled
distance (~1 % of a radian at the seed's scale of 1000; the orthographic
camera has none). No motion blur: one instant per exposure, its midpoint.

A facet that no geometry lies in front of (``Facets.can_shadow`` False) is
seen and lit exactly when it faces the observer and the Sun; by default such
facets get fraction 1 there, and Cycles' pixels decide the others
(``all_facets=True`` takes Cycles' fractions for every facet, which is how
the tests check the pixel path itself on convex bodies).
"""

from __future__ import annotations

import dataclasses
import tempfile
from pathlib import Path

import jax
import numpy as np
import pandas as pd

import jaxlc
from calibrate.job import BlenderOptions, write_job
from calibrate.render import camera_setup, keyframe_quaternions, mesh_parts
from calibrate.runner import default_timeout_s, run_worker
from jaxlc import RenderOptions
from jaxlc.body.facet_model import facet_intensity

#: Image side of the visibility renders (pixels).
DEFAULT_RESOLUTION = 512
#: Below this μ = n·v a facet counts as edge-on (no seen area to divide by).
EDGE_ON_MU = 1e-9


@dataclasses.dataclass(frozen=True)
class Visibility:
    """Cycles' visibility of each facet in each rendered frame.

    Attributes:
        rows: (n,) geometry-table rows rendered (the visible ones).
        lit_seen: (n, F) lit-and-seen fraction of each facet (0 where μ ≤ 0).
        seen: (n, F) seen fraction (lit or not; 0 where μ ≤ 0).
        seen_pixels: (n, F) pixels that see each facet (its front).
    """

    rows: np.ndarray
    lit_seen: np.ndarray
    seen: np.ndarray
    seen_pixels: np.ndarray

    @property
    def pixels(self) -> np.ndarray:
        """(n,) pixels that see the object's facets from the front."""
        return self.seen_pixels.sum(axis=1)


def visibility_options(options: BlenderOptions | None) -> BlenderOptions:
    """The options of a visibility render: one sample, no bounces, no blur."""
    options = options or BlenderOptions(resolution=DEFAULT_RESOLUTION)
    return dataclasses.replace(options, samples=1, bounces=0, motion_blur=False)


def cycles_visibility(
    scene: jaxlc.Scene | str | Path,
    geometry,
    options: BlenderOptions | None = None,
    progress=None,
    all_facets: bool = False,
) -> tuple[jaxlc.Prepared, Visibility]:
    """Per-facet lit-and-seen fractions from Cycles, on the renderer's preparation.

    Args:
        scene, geometry: as :func:`jaxlc.render`.
        options: camera and image size (samples, bounces and blur are ignored).
        progress: optional callable(done_frames, total_frames).
        all_facets: take Cycles' fractions for every facet. By default a facet
            that no geometry lies in front of (``Facets.can_shadow`` False) is
            seen and lit exactly when it faces the observer and the Sun, so it
            gets fraction 1 there and only the others take Cycles' (which are
            noisy for facets seen at grazing angles, a few pixels each).

    Returns:
        (the float64 preparation without shadows or blur, :class:`Visibility`).
    """
    options = visibility_options(options)
    prepared = jaxlc.prepare(
        scene, geometry, RenderOptions(shadows="off", blur="off"), "float64", subsamples=1
    )
    scene, geo = prepared.scene, prepared.geometry
    idx = np.asarray(prepared.exposures.rows)
    _, facets = scene.body
    n_facets = facets.n_facets
    lit_f = np.zeros((len(idx), n_facets))
    seen_f = np.zeros((len(idx), n_facets))
    counts = np.zeros((len(idx), n_facets))
    if len(idx):
        parts, ids, radius = mesh_parts(scene)
        tri_facet = facets.triangle_facet
        # Triangles masked as degenerate are not facets, and Blender keeps one of two
        # triangles on the same vertices (a two-sided plate): leave those out of the
        # job; a pixel that sees a kept triangle from behind is its twin's.
        twin = coincident_twins(scene.mesh.faces)
        dropped = np.zeros(len(tri_facet), bool)
        dropped[twin[twin > np.arange(len(twin))]] = True  # the second of each pair
        kept = [(tri_facet[t] >= 0) & ~dropped[t] for t in ids]
        parts = [(name, v, f[k]) for (name, v, f), k in zip(parts, kept, strict=True)]
        ids = [t[k] for t, k in zip(ids, kept, strict=True)]
        camera, per_frame, footprint_m2 = camera_setup(options, radius, geo.range_m[idx])
        frames = {
            "quaternions": keyframe_quaternions(prepared),
            "sun_dir": geo.sun_dir[idx],
            "obs_dir": geo.obs_dir[idx],
            "irradiance_w_m2": np.ones(len(idx)),
            **per_frame,
            **{f"triangle_ids_{k}": t for k, t in enumerate(ids)},
        }
        materials = [{"part": name, "diffuse": 1.0, "glossy": 0.0} for name, _, _ in parts]
        settings = options.job_settings() | {"motion_steps": 1}
        with tempfile.TemporaryDirectory(prefix="jaxlc-visibility-") as tmp:
            extra = {"visibility": True, "triangles": len(tri_facet)}
            job = write_job(Path(tmp), parts, materials, camera, settings, frames, extra)
            timeout = options.timeout_s or default_timeout_s(len(idx), options.resolution, 2)
            result = run_worker(job, timeout, progress)
        sun_b, obs_b = body_directions(prepared)
        mu, mu0 = obs_b @ facets.normals.T, sun_b @ facets.normals.T  # (n, F)
        for i in range(len(idx)):
            # each triangle's pixels go to its facet, or its twin's when seen from behind
            facing = mu[i, tri_facet] > 0
            target = np.where(facing | (twin < 0), tri_facet, tri_facet[np.maximum(twin, 0)])
            ok = target >= 0
            np.add.at(lit_f[i], target[ok], result["lit_pixels"][i][ok])
            np.add.at(seen_f[i], target[ok], result["seen_pixels"][i][ok])
        counts = seen_f.copy()
        projected = facets.areas_m2 * scene.scale**2 * np.where(mu > EDGE_ON_MU, mu, np.inf)
        lit_f = footprint_m2[:, None] * lit_f / projected
        seen_f = footprint_m2[:, None] * seen_f / projected
        if not all_facets:
            free = ~facets.can_shadow
            seen_f[:, free] = (mu[:, free] > EDGE_ON_MU).astype(float)
            lit_f[:, free] = seen_f[:, free] * (mu0[:, free] > 0)
    return prepared, Visibility(rows=idx, lit_seen=lit_f, seen=seen_f, seen_pixels=counts)


def coincident_twins(faces: np.ndarray) -> np.ndarray:
    """(M,) for the second of two triangles on the same three vertices, the index
    of the first (−1 elsewhere); the first maps to the second likewise."""
    key = np.sort(np.asarray(faces), axis=1)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    twin = np.full(len(key), -1)
    for group in np.flatnonzero(counts == 2):
        a, b = np.flatnonzero(inverse.reshape(-1) == group)
        twin[a], twin[b] = b, a
    return twin


def body_directions(prepared: jaxlc.Prepared) -> tuple[np.ndarray, np.ndarray]:
    """(M, 3) body-frame Sun and observer directions at the prepared instants."""
    r = jaxlc.rotation_matrices(prepared)  # body → inertial
    inputs = prepared.inputs
    sun = np.einsum("mji,mj->mi", r, np.asarray(inputs.sun_dir, np.float64))
    obs = np.einsum("mji,mj->mi", r, np.asarray(inputs.obs_dir, np.float64))
    return sun, obs


def intensity_with_visibility(prepared: jaxlc.Prepared, visibility: Visibility) -> np.ndarray:
    """(n,) I/E (m² sr⁻¹): the facet model's sum weighted by Cycles' fractions."""
    model = prepared.object.model
    n, f = visibility.lit_seen.shape
    weights = np.concatenate([visibility.lit_seen, np.ones((n, model.n_facets - f))], axis=1)
    sun_b, obs_b = body_directions(prepared)
    with jax.enable_x64(True):
        model64 = model.astype(np.float64)
        return np.asarray(facet_intensity(model64, sun_b, obs_b, weights=weights))


def exact_direct_render(
    scene: jaxlc.Scene | str | Path,
    geometry,
    options: BlenderOptions | None = None,
    progress=None,
    all_facets: bool = False,
) -> pd.DataFrame:
    """A light curve of the scene's own materials, exact for direct light, with
    Cycles' visibility (the module docstring): the table of :func:`jaxlc.render`
    plus ``cycles_pixels`` (pixels that see the object)."""
    prepared, vis = cycles_visibility(scene, geometry, options, progress, all_facets)
    table, geo = prepared.table, prepared.geometry
    intensity = np.full(len(table), np.nan)
    pixels = np.full(len(table), np.nan)
    if len(vis.rows):
        intensity[vis.rows] = intensity_with_visibility(prepared, vis)
        pixels[vis.rows] = vis.pixels
    out = jaxlc.lightcurve_table(table, geo, intensity, cycles_pixels=pixels)
    options = visibility_options(options)
    out.attrs.update(
        {
            "frame": table.attrs.get("frame", "unknown"),
            "scene": prepared.scene.source,
            "renderer": "jaxlc facet BRDF × Cycles visibility (direct light, exact BRDF)",
            "camera": options.camera,
            "resolution": str(options.resolution),
        }
    )
    return out
