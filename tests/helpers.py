"""Independent references, catalogued once (STYLE.md §8).

Everything here is written straight from the formulas in
``../shared/design/PHYSICS.md`` in plain float64 numpy, without any of the
rearrangements the fast kernel uses (no min(μ0, μ) identity, no tangential
split of 1 − (n·h)², no per-facet coefficient folding), so agreement between
the two is evidence, not repetition.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
#: The shipped meshes and standard scenes (package data).
MESHES = REPO / "jaxlc" / "data" / "meshes"
SCENES = REPO / "jaxlc" / "data" / "scenes"
DATA = Path(__file__).resolve().parent / "data"


def demo_pass(path: Path, start_utc: str, duration_s: float):
    """The demo's real pass (Falcon 9 R/B 45921 over Mt Stromlo) from ``start_utc`` at
    1 Hz with 1 s exposures, made by ``jaxlc geometry pass`` into ``path``; its table."""
    import jaxlc
    from jaxlc.cli import main as cli

    tle = REPO / "data" / "tle" / "falcon9_rb.tle"
    args = ["geometry", "pass", "--tle", str(tle), "--norad", "45921", "--site", "mt-stromlo"]
    args += ["--start", start_utc, "--duration-s", str(duration_s), "--step-s", "1"]
    assert cli([*args, "--exposure-s", "1", "-o", str(path)]) == 0
    return jaxlc.read_geometry(path)


def radec_unit(ra_deg: float, dec_deg: float) -> np.ndarray:
    """The unit vector (3,) of a right ascension and declination (deg)."""
    ra, dec = math.radians(ra_deg), math.radians(dec_deg)
    return np.array([math.cos(dec) * math.cos(ra), math.cos(dec) * math.sin(ra), math.sin(dec)])


def unit(x):
    x = np.asarray(x, dtype=np.float64)
    return x / np.linalg.norm(x, axis=-1, keepdims=True)


def lambert_plate_intensity(n, s, v, area_m2, rd):
    """I/E of a flat Lambert plate: (ρ/π) A (n·s)(n·v), zero unless both cosines > 0."""
    ns, nv = float(np.dot(n, s)), float(np.dot(n, v))
    return rd / math.pi * area_m2 * ns * nv if ns > 0 and nv > 0 else 0.0


def lambert_sphere_intensity(alpha_rad, radius_m, rd):
    """I/E of a Lambert sphere: ρ R² (2/3π)[sin α + (π − α) cos α] (PHYSICS.md §2)."""
    a = np.asarray(alpha_rad, dtype=np.float64)
    return rd * radius_m**2 * 2.0 / (3.0 * math.pi) * (np.sin(a) + (math.pi - a) * np.cos(a))


def ashikhmin_shirley_rho(n, u, w, s, v, rd, rs, nu, nv):
    """ρ_d + ρ_s of the AS BRDF (Linares/Furfaro form), one facet, float64.

    ρ_d = (28 R_d / 23π)(1 − R_s)[1 − (1 − n·s/2)^5][1 − (1 − n·v/2)^5]
    ρ_s = √((n_u+1)(n_v+1))/(8π) · (n·h)^z / [(h·s) max(n·s, n·v)] · F
    z = [n_u (h·u)² + n_v (h·w)²] / [1 − (n·h)²],  F = R_s + (1 − R_s)(1 − h·s)^5
    """
    ns, nvv = np.dot(n, s), np.dot(n, v)
    h = unit(s + v)
    nh, hs = np.dot(n, h), np.dot(h, s)
    rho_d = 28 * rd / (23 * math.pi) * (1 - rs) * (1 - (1 - ns / 2) ** 5) * (1 - (1 - nvv / 2) ** 5)
    sin2 = 1 - nh**2
    z = (nu + nv) / 2 if sin2 < 1e-15 else (nu * np.dot(h, u) ** 2 + nv * np.dot(h, w) ** 2) / sin2
    fresnel = rs + (1 - rs) * (1 - hs) ** 5
    rho_s = math.sqrt((nu + 1) * (nv + 1)) / (8 * math.pi) * nh**z / (hs * max(ns, nvv)) * fresnel
    return rho_d + rho_s


def as_glossy_rho(n, u, w, s, v, rd, rs, nu, nv):
    """Lambert rd/π plus rs times the AS lobe without Fresnel (Cycles Diffuse + Glossy AS)."""
    ns, nvv = np.dot(n, s), np.dot(n, v)
    h = unit(s + v)
    nh, hs = np.dot(n, h), np.dot(h, s)
    sin2 = 1 - nh**2
    z = (nu + nv) / 2 if sin2 < 1e-15 else (nu * np.dot(h, u) ** 2 + nv * np.dot(h, w) ** 2) / sin2
    lobe = math.sqrt((nu + 1) * (nv + 1)) / (8 * math.pi) * nh**z / (hs * max(ns, nvv))
    return rd / math.pi + rs * lobe


def facet_sum_reference(normals, u, w, areas, s, v, rho_fn, params):
    """Σ_f A_f ρ_f (n·s)(n·v) over facets with both cosines > 0, float64 loops.

    Args:
        normals, u, w: (F, 3); areas: (F,); s, v: (3,) body-frame unit vectors;
        rho_fn: one of the ρ functions above; params: (F,) tuples of its
        material arguments (rd, rs, nu, nv).
    """
    total = 0.0
    for f in range(len(areas)):
        ns, nvv = np.dot(normals[f], s), np.dot(normals[f], v)
        if ns > 0 and nvv > 0:
            rho = rho_fn(normals[f], u[f], w[f], s, v, *params[f])
            total += areas[f] * rho * ns * nvv
    return total


def random_unit_vectors(rng, n):
    return unit(rng.normal(size=(n, 3)))


def rotation_matrix_from_quaternion(q):
    """Reference rotation matrix of a scalar-first quaternion via Rodrigues' formula."""
    q = unit(q)
    w, xyz = q[0], q[1:]
    angle = 2 * math.atan2(np.linalg.norm(xyz), w)
    if np.linalg.norm(xyz) < 1e-15:
        return np.eye(3)
    k = xyz / np.linalg.norm(xyz)
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle) * kx + (1 - math.cos(angle)) * kx @ kx


def magnitude_difference(a, b):
    """|Δm| between two positive fluxes or intensities."""
    return np.abs(2.5 * np.log10(np.asarray(a, np.float64) / np.asarray(b, np.float64)))


def pass_geometry(n=6, **kw):
    """A synthetic pass of ``n`` exposures a minute apart (phase 10° → 120°,
    500 → 2,000 km), for the Blender tests; keywords override."""
    import jaxlc

    args = dict(
        duration_s=60.0 * n,
        step_s=60.0,
        phase_start_deg=10,
        phase_end_deg=120,
        sun_dec_deg=35,
        tilt_deg=50,
        range_start_m=5e5,
        range_end_m=2e6,
    )
    args.update(kw)
    return jaxlc.synthetic_geometry(**args)


def roof_over_floor():
    """A two-sided 1 × 1 m roof 1 m above a two-sided 2 × 2 m floor (parts floor, roof)."""
    from jaxlc.body.mesh import TriangleMesh

    floor = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], float)
    roof = np.array([[-0.5, -0.5, 1], [0.5, -0.5, 1], [0.5, 0.5, 1], [-0.5, 0.5, 1]], float)
    v = np.concatenate([floor, roof])
    up = [[0, 1, 2], [0, 2, 3]]
    down = [[0, 2, 1], [0, 3, 2]]
    faces = np.array(up + down + [[a + 4, b + 4, c + 4] for a, b, c in up + down])
    part = np.array([0, 0, 0, 0, 1, 1, 1, 1], np.int32)
    return TriangleMesh(v, faces, part, ("floor", "roof"), "roof-over-floor")
