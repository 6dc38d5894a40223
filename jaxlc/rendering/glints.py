"""Where a glint can happen: the adaptive quadrature's first level, exposure by exposure.

The adaptive quadrature (:mod:`jaxlc.rendering.adaptive`) must start at a level whose
instants are no farther apart than the sharpest specular lobe, or a glint can fall
between every instant of two coarse levels that then agree by chance
(:func:`~jaxlc.rendering.adaptive.first_level_for`). A curve's plan sets that start for
its sharpest lobe, so one mirror-like part made every exposure of the curve start at
7 or 15 instants. A glint needs a facet's normal near the half-vector h of the Sun and
observer directions, though: the lobe (n·h)^n ≈ exp(−θ²/2σ²), σ = 1/√n, is below
exp(−:data:`CLEARANCE_SIGMAS`²/2) ≈ 10⁻⁸ of its peak (a few 10⁻⁶ of a diffuse facet's
brightness) wherever h stays that many lobe widths from the normal. So each exposure
starts at the level that its own possible glints need:

* h is followed in the body frame at P instants spread over the exposure (its
  direction in inertial space is held through the exposure, as the kernel holds it;
  the attitude turns it at most ``rate_rad_s``), so every point of its path lies
  within half a step, ``rate × exposure / (2 (P − 1))``, of one of them;
* a specular facet can glint when its normal comes within CLEARANCE_SIGMAS × its
  widest lobe width (an anisotropic lobe's 1/√min(nu, nv)) plus that half step of
  one of them;
* the exposure's start scale is the sharpest lobe (1/√max(nu, nv)) of the facets that
  can glint, or the diffuse scale when none can; its first and resolved levels follow
  from it as for a whole curve.

An exposure whose h passes near no sharp lobe then starts where gaps of half the
diffuse scale are resolved (a kink between coarse instants can leave two levels agreeing
by chance: the CubeSat, a 12 s spin, 31 mmag at level 1), and later when a facet
turns towards or away from the Sun or observer in it (:func:`turning`): a kink beyond
an exposure's last instant changes no instant, so its end instants must be close to
its ends (:data:`KINK_END_RAD`). No exposure starts later than the curve's
own start. Over the bulk mix's curves against 256 sub-exposures (1 mmag tolerance):
the CubeSat (S5) takes 20.6 instants per exposure instead of 49.4 with the same worst
error (4.0 mmag), the box-wing (S6) 3.6 instead of 5.1; the S4 stage's finely
faceted domes leave no direction clear (:func:`clear_fraction`) and it is unchanged.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from jaxlc.rendering.adaptive import first_level_for
from jaxlc.rendering.blur import DIFFUSE_SCALE_RAD
from jaxlc.rendering.exposures import probe_instants
from jaxlc.rendering.patterson import level_rule

#: Lobe widths between a normal and the half-vector's path beyond which no glint is sought.
CLEARANCE_SIGMAS = 6.0
#: Most instants per exposure at which the half-vector is followed.
MAX_PATH_POINTS = 33
#: Largest angle (rad) the body may turn between an exposure's end and its nearest
#: instant when a facet turns on or off in it: such a kink beyond the last instant
#: changes no instant's value, so two levels agree by chance (the CubeSat, a 57 s spin:
#: a face turning on in the last tenth of a dim exposure, 3.8 mmag at level 1).
KINK_END_RAD = 0.003
#: Exposures per block of the normal × path products (bounds memory).
BLOCK_EXPOSURES = 256
#: Directions of the spiral over which lobe groups are tested for leaving directions
#: clear of glints (:func:`clear_fraction`).
COVERAGE_DIRECTIONS = 4096
#: Least fraction of clear directions for which the per-exposure test is run: below it
#: (the S4 stage's finely faceted domes and nozzle: 0–10 %) the test would cost more
#: than the few exposures it clears save.
MIN_CLEAR_FRACTION = 0.25


def lobe_groups(model) -> list[tuple[float, float, np.ndarray]]:
    """(sharp σ, wide σ, (F_g, 3) distinct unit normals) of the specular facets, by lobe.

    Args:
        model: a :class:`~jaxlc.body.facet_model.FacetModel` (host arrays).
    """
    if not model.use_specular:
        return []
    ks = np.asarray(model.ks, np.float64)
    normals = np.asarray(model.normals, np.float64)
    nu = np.maximum(np.asarray(model.nu, np.float64), 1.0)
    nv = np.maximum(np.asarray(model.nv, np.float64), 1.0)
    sharp = 1.0 / np.sqrt(np.maximum(nu, nv))
    wide = 1.0 / np.sqrt(np.minimum(nu, nv))
    spec = ks > 0
    out = []
    pairs = {(float(a), float(b)) for a, b in zip(sharp[spec], wide[spec], strict=True)}
    for s, w in sorted(pairs):
        if s >= DIFFUSE_SCALE_RAD:
            continue  # no sharper than diffuse turn-on: it never raises the start
        pick = spec & (sharp == s) & (wide == w)
        out.append((s, w, np.unique(np.round(normals[pick], 6), axis=0)))
    return out


@functools.lru_cache(maxsize=32)
def _clear_directions(normals_bytes: bytes, radius_rad: float) -> np.ndarray:
    """(COVERAGE_DIRECTIONS,) whether each direction of a Fibonacci spiral is ≥ the
    radius from every normal."""
    normals = np.frombuffer(normals_bytes).reshape(-1, 3)
    k = np.arange(COVERAGE_DIRECTIONS) + 0.5
    z = 1.0 - 2.0 * k / COVERAGE_DIRECTIONS
    phi = math.pi * (1.0 + math.sqrt(5.0)) * k
    r = np.sqrt(1.0 - z**2)
    dirs = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)
    cos = np.max(dirs @ normals.T, axis=1)
    return np.arccos(np.clip(cos, -1.0, 1.0)) >= radius_rad


def clear_fraction(groups) -> float:
    """The fraction of directions clear of every group's possible glints (cached per
    mesh): a finely faceted curved body's many sharp-lobed normals leave few or none."""
    clear = np.ones(COVERAGE_DIRECTIONS, bool)
    for _, wide, normals in groups:
        key = np.ascontiguousarray(normals, np.float64).tobytes()
        clear &= _clear_directions(key, CLEARANCE_SIGMAS * wide)
    return float(np.mean(clear))


def exposure_start_scales(
    half_body: np.ndarray, step_rad: np.ndarray, groups, base_rad: float = DIFFUSE_SCALE_RAD
) -> np.ndarray:
    """(N,) the sharpest lobe width (rad) that can glint in each exposure, else ``base_rad``.

    Args:
        half_body: (N, P, 3) unit half-vectors in the body frame at P instants of each
            of N exposures.
        step_rad: (N,) the largest angle h turns between two of those instants.
        groups: :func:`lobe_groups`.
    """
    n = half_body.shape[0]
    scale = np.full(n, float(base_rad))
    for sharp, wide, normals in groups:
        for a in range(0, n, BLOCK_EXPOSURES):
            h = half_body[a : a + BLOCK_EXPOSURES]
            cos = np.max(h @ normals.T, axis=(1, 2))  # closest normal over the path
            nearest = np.arccos(np.clip(cos, -1.0, 1.0)) - 0.5 * step_rad[a : a + len(h)]
            can = nearest < CLEARANCE_SIGMAS * wide
            scale[a : a + len(h)][can] = np.minimum(scale[a : a + len(h)][can], sharp)
    return scale


def turning(sun_body: np.ndarray, obs_body: np.ndarray, step_rad: np.ndarray, normals):
    """(N,) whether a facet can turn towards or away from the Sun or the observer (its
    Lambert factor's kink) during each exposure.

    Args:
        sun_body, obs_body: (N, P, 3) body-frame unit vectors at P instants of each exposure.
        step_rad: (N,) the largest angle they turn between two of those instants.
        normals: (F, 3) unit normals of the facets that reflect light.
    """
    out = np.zeros(sun_body.shape[0], bool)
    margin = np.sin(np.minimum(0.5 * step_rad, np.pi / 2))[:, None, None]
    for x in (sun_body, obs_body):
        for a in range(0, len(out), BLOCK_EXPOSURES):
            c = x[a : a + BLOCK_EXPOSURES] @ normals.T  # (n, P, F)
            flips = np.any(np.diff(np.sign(c), axis=1) != 0, axis=1)
            near = np.any(np.abs(c) <= margin[a : a + len(c)], axis=1)
            out[a : a + len(c)] |= np.any(flips | near, axis=1)
    return out


def kink_level(sweep_rad: float) -> int:
    """The least level whose end instants are within :data:`KINK_END_RAD` of the
    exposure's ends at this sweep."""
    k = 1
    while level_rule(k)[0][0] * sweep_rad > KINK_END_RAD and k < 12:
        k += 1
    return k


def start_levels(prepared, inputs_of, last: int, extra: int = 0):
    """(first, resolved) levels of the adaptive quadrature for ``prepared``'s exposures:
    the curve's (ints) when no lobe raises its start, else one per exposure ((N,) arrays).

    Args:
        prepared: a :class:`~jaxlc.rendering.prepare.Prepared` whose plan is adaptive.
        inputs_of: callable(probe :class:`~jaxlc.rendering.exposures.Exposures`) → its
            :class:`~jaxlc.rendering.kernel.KernelInputs` (unpadded; for the attitude's times).
        last: the last level; extra: levels added to the first (a fit's least levels).
    """
    blur = prepared.plan.blur
    sweep = blur.sweep_rad
    first = min(last, first_level_for(sweep, blur.start_scale) + extra)
    resolved = first_level_for(sweep, blur.start_scale / 2)
    groups = lobe_groups(prepared.object.model)
    rows = prepared.exposures.rows
    plain = first_level_for(sweep, DIFFUSE_SCALE_RAD / 2)
    raising = [g for g in groups if first_level_for(sweep, g[0]) > plain]
    if not len(rows) or not raising or clear_fraction(raising) < MIN_CLEAR_FRACTION:
        return first, resolved
    sharpest = min(g[0] for g in groups)
    points = int(min(MAX_PATH_POINTS, max(2, math.ceil(sweep / sharpest) + 1)))
    geo = prepared.geometry
    probe = probe_instants(geo, rows, np.linspace(0.0, 1.0, points), prepared.t0_s)
    rot = np.asarray(prepared.object.attitude.rotation(inputs_of(probe).times), np.float64)
    body = lambda v: np.einsum("mji,mj->mi", rot, v).reshape(len(rows), points, 3)  # noqa: E731
    sun, obs = body(probe.sun_dir), body(probe.obs_dir)
    half = sun + obs
    half /= np.linalg.norm(half, axis=2, keepdims=True)
    step = blur.rate_rad_s * geo.exposure_s[rows] / (points - 1)
    scale = exposure_start_scales(half, step, groups)
    model = prepared.object.model
    lit = (np.asarray(model.kl) + np.asarray(model.kd) + np.asarray(model.ks)) > 0
    kink = turning(sun, obs, step, np.asarray(model.normals, np.float64)[lit])
    # no possible glint: the start of the module docstring; never later than the curve's
    plain_e = np.where(kink, max(plain, kink_level(sweep)), plain)
    levels = {x: first_level_for(sweep, x) for x in np.unique(scale)}
    first_e = np.array([levels[x] for x in scale], np.int64)
    first_e = np.where(scale < DIFFUSE_SCALE_RAD, first_e, np.minimum(plain_e, first - extra))
    halves = {x: first_level_for(sweep, x / 2) for x in np.unique(scale)}
    resolved_e = np.array([halves[x] for x in scale], np.int64)
    return np.minimum(last, first_e + extra), resolved_e
