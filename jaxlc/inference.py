"""Spin-state inference, part 1: the differentiable light-curve model and the MAP search.

Parameters (a flat vector θ, shapes in brackets):

* LM coordinates, ``θ_lm`` (6): pole as an unnormalised 3-vector u (its
  direction is the inertial spin pole; drawn from N(0, I) it is isotropic),
  ln(period_s), rotation phase φ (rad) at the fit epoch, and a magnitude
  offset Δm (the brightness scale: size × albedo errors).
* MCMC coordinates, ``θ_mc`` (6): (λ, sin β) of the pole (isotropic when
  uniform), ln(period_s), φ, Δm and ln(noise_mag), the noise added in
  quadrature to the data's own errors.

The model magnitude of sample i is
``m_i = c_i − 2.5 log10(⟨I/E⟩_i + I_floor) + Δm`` with
``c_i = −26.74 − 2.5 log10(E_i / (d_i² C_sun))`` from the geometry and ⟨I/E⟩
the mean over the exposure's sub-samples of :func:`jaxlc.render.light_curve_intensity`
for the scene's shape and materials spun about its ``body_axis``. Times are
seconds from the fit epoch (the middle sample), which decorrelates φ from the
period and keeps float32 angles precise.

Samples far fainter than the rest (an end-on rocket body can drop 20 mag
in the model, below any detection limit) would dominate a magnitude fit, so
model and data are both softly clipped at ``limit_mag`` (default: the data's
median + 5 mag): ``m → L − w·softplus((L − m)/w)`` with w = 0.1 mag, the
identity for m ≪ L.

The multi-start search (:func:`multistart`) runs ≥ 1,000 Levenberg–Marquardt
solves (optimistix) in one batched solve on a cheap model (facets clustered by
normal, no shadows, 64 of the samples), seeded by the periodogram (P_ls and
2 P_ls); distinct optima become :class:`Mode` objects, refined on the exact
model. :mod:`jaxlc.mcmc` samples around them.
"""

from __future__ import annotations

import dataclasses
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd

from jaxlc import photometry
from jaxlc.attitude import Spin, reference_direction
from jaxlc.errors import JaxlcError
from jaxlc.mesh import Facets
from jaxlc.render import SpaceObject, filter_jit, light_curve_intensity, space_object
from jaxlc.scene import Scene

N_LM = 6
N_MC = 6
MC_NAMES = ("pole_lambda_rad", "pole_sin_beta", "ln_period_s", "phase_rad", "dmag", "ln_noise_mag")


@dataclasses.dataclass(frozen=True)
class FitData:
    """Observed samples with their geometry (host side, float64).

    Attributes:
        t_s: (N,) mid-exposure seconds from ``epoch_utc``.
        mag: (N,) observed magnitudes.
        mag_err: (N,) 1σ errors (zeros when unknown: the noise parameter carries it all).
        sun_dir, obs_dir: (N, 3) unit vectors object→Sun / object→observer, inertial.
        const_mag: (N,) c_i of the module docstring.
        exposure_s: (N,) exposure times.
        epoch_utc: time origin of ``t_s`` and of the fitted phase.
        limit_mag: faint clipping level L (module docstring).
    """

    t_s: np.ndarray
    mag: np.ndarray
    mag_err: np.ndarray
    sun_dir: np.ndarray
    obs_dir: np.ndarray
    const_mag: np.ndarray
    exposure_s: np.ndarray
    epoch_utc: pd.Timestamp
    limit_mag: float = float("inf")

    @property
    def n(self) -> int:
        return len(self.t_s)

    def subset(self, idx) -> FitData:
        idx = np.asarray(idx)
        f = lambda x: x[idx]  # noqa: E731
        return dataclasses.replace(
            self,
            t_s=f(self.t_s),
            mag=f(self.mag),
            mag_err=f(self.mag_err),
            sun_dir=f(self.sun_dir),
            obs_dir=f(self.obs_dir),
            const_mag=f(self.const_mag),
            exposure_s=f(self.exposure_s),
        )


CLIP_WIDTH_MAG = 0.1


def soft_clip(mag, limit_mag):
    """Smoothly clip magnitudes at the faint limit (numpy or JAX)."""
    xp = jnp if isinstance(mag, jax.Array) else np
    w = CLIP_WIDTH_MAG
    if xp is np:
        return limit_mag - w * np.logaddexp(0.0, (limit_mag - np.asarray(mag)) / w)
    return limit_mag - w * jax.nn.softplus((limit_mag - mag) / w)


def fit_data(
    lightcurve: pd.DataFrame,
    geometry: pd.DataFrame,
    column: str = "mag",
    faint_clip_mag: float = 5.0,
) -> FitData:
    """Pair an observed light curve with its geometry table (rows matched by UTC).

    Raises:
        JaxlcError: when rows do not match, or fewer than 20 usable samples remain.
    """
    from jaxlc.render import geometry_arrays
    from jaxlc.tables import validate_geometry

    geometry = validate_geometry(geometry)
    if column not in lightcurve.columns:
        raise JaxlcError(f"light curve has no column {column!r}")
    geo = geometry_arrays(geometry, 1.0)
    g_utc = pd.DatetimeIndex(geometry["utc"])
    l_utc = pd.DatetimeIndex(pd.to_datetime(lightcurve["utc"], utc=True))
    pos = g_utc.get_indexer(l_utc, method="nearest", tolerance=pd.Timedelta("1ms"))
    if np.any(pos < 0):
        first = int(np.flatnonzero(pos < 0)[0])
        raise JaxlcError(
            f"light-curve row {first} (utc {l_utc[first]}) has no geometry row at the same "
            "time; give the geometry table the light curve was observed (or rendered) with"
        )
    mag = lightcurve[column].to_numpy(np.float64)
    ok = np.isfinite(mag) & geo.visible[pos]
    if "visible" in lightcurve.columns:
        ok &= lightcurve["visible"].to_numpy(bool)
    err = (
        lightcurve["mag_err"].to_numpy(np.float64)
        if "mag_err" in lightcurve.columns
        else np.zeros(len(mag))
    )
    ok &= np.isfinite(err) & (err >= 0)
    if np.count_nonzero(ok) < 20:
        raise JaxlcError(
            f"only {int(np.count_nonzero(ok))} visible samples with finite magnitudes; "
            "a spin fit needs at least 20"
        )
    p = pos[ok]
    t_mid = geo.t_start_s[p] + 0.5 * geo.exposure_s[p]
    mid = t_mid[len(t_mid) // 2]
    epoch = geo.origin_utc + pd.Timedelta(seconds=float(mid))
    flux_scale = photometry.flux_w_m2(1.0, geo.irradiance_w_m2[p], geo.range_m[p])
    return FitData(
        t_s=t_mid - mid,
        mag=mag[ok],
        mag_err=err[ok],
        sun_dir=geo.sun_dir[p],
        obs_dir=geo.obs_dir[p],
        const_mag=photometry.magnitude(flux_scale),
        exposure_s=geo.exposure_s[p],
        epoch_utc=epoch,
        limit_mag=float(np.median(mag[ok]) + faint_clip_mag),
    )


# ---------------------------------------------------------------------------
# Cheap model: facets clustered by normal


def fibonacci_sphere(n: int) -> np.ndarray:
    """(n, 3) nearly uniform unit vectors."""
    k = np.arange(n) + 0.5
    z = 1 - 2 * k / n
    r = np.sqrt(1 - z**2)
    phi = np.pi * (1 + 5**0.5) * k
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def coarsen_facets(facets: Facets, directions: int = 64) -> Facets:
    """Merge the facets of each part whose normals fall in one of ``directions`` bins.

    A merged facet keeps the summed area, the area-weighted mean normal and
    centroid, and its triangles (so the shadow table of a merged facet is the
    area-weighted mean over all of them). Exact for facets with identical
    normals; otherwise an approximation whose error grows with the bin size
    relative to the sharpest lobe.
    """
    if facets.n_facets <= directions:
        return facets
    grid = fibonacci_sphere(directions)
    bin_id = np.argmax(facets.normals @ grid.T, axis=1)
    key = facets.part.astype(np.int64) * directions + bin_id
    uniq, inv = np.unique(key, return_inverse=True)
    a = facets.areas_m2
    n_sum = np.zeros((len(uniq), 3))
    np.add.at(n_sum, inv, facets.normals * a[:, None])
    area = np.bincount(inv, weights=a)
    c_sum = np.zeros((len(uniq), 3))
    np.add.at(c_sum, inv, facets.centroids_m * a[:, None])
    norm = np.linalg.norm(n_sum, axis=1, keepdims=True)
    normals = np.where(norm > 0, n_sum / np.maximum(norm, 1e-300), grid[uniq % directions])
    can_shadow = np.bincount(inv, weights=facets.can_shadow.astype(float)) > 0
    tri = facets.triangle_facet
    return dataclasses.replace(
        facets,
        normals=normals,
        areas_m2=area,
        centroids_m=c_sum / area[:, None],
        part=(uniq // directions).astype(facets.part.dtype),
        can_shadow=can_shadow,
        triangle_facet=np.where(tri >= 0, inv[np.maximum(tri, 0)], -1),
    )


# ---------------------------------------------------------------------------
# The model


class SpinModel(eqx.Module):
    """Shape, materials and sub-exposure layout of a spin fit (a pytree).

    Attributes:
        obj: the traced object (its attitude is replaced per θ).
        body_axis, body_ref: (3,) spin axis and reference direction in the body frame.
        sub_frac: (S,) sub-exposure offsets as fractions of the exposure, centred on 0.
        floor_m2_sr: intensity floor that keeps unlit samples finite in magnitude
            (10⁻¹⁰ × the total area: 25 mag below a fully lit face, far below the
            soft clip, so it changes no sample above the limit by > 10⁻⁵ mag; a
            floor of 10⁻⁷ biased a CubeSat's faint plateau by 6 mmag and its
            period by 2.5 σ in the calibration study).
    """

    obj: SpaceObject
    body_axis: jax.Array
    body_ref: jax.Array
    sub_frac: jax.Array
    floor_m2_sr: jax.Array
    limit_mag: jax.Array

    def attitude(self, pole_vec, ln_period, phase) -> Spin:
        u = pole_vec / jnp.linalg.norm(pole_vec)
        ra = jnp.arctan2(u[1], u[0])
        dec = jnp.arctan2(u[2], jnp.hypot(u[0], u[1]))
        return Spin(
            body_axis=self.body_axis,
            body_ref=self.body_ref,
            pole_ra_rad=ra,
            pole_dec_rad=dec,
            period_s=jnp.exp(ln_period),
            phase_rad=phase,
        )

    def magnitudes(self, theta_lm, t_s, exposure_s, sun_dir, obs_dir, const_mag, chunk=None):
        """(N,) model magnitudes for LM coordinates ``theta_lm`` (6,).

        ``chunk``: samples per block of the facet sum (static; default sized for
        one curve, see :func:`jaxlc.render.time_chunk`). Under ``vmap`` over W
        parameter vectors pass ``time_chunk(n_facets × W)`` so one block of all
        W still fits the cache.
        """
        spin = self.attitude(theta_lm[:3], theta_lm[3], theta_lm[4])
        obj = eqx.tree_at(lambda o: o.attitude, self.obj, spin)
        s = self.sub_frac.shape[0]
        t = (t_s[:, None] + exposure_s[:, None] * self.sub_frac[None, :]).reshape(-1)
        rep = lambda x: jnp.repeat(x, s, axis=0)  # noqa: E731
        i = light_curve_intensity(obj, t, rep(sun_dir), rep(obs_dir), chunk)
        i = i.reshape(-1, s).mean(axis=1)
        m = const_mag - 2.5 * jnp.log10(i + self.floor_m2_sr) + theta_lm[5]
        return soft_clip(m, self.limit_mag)


def spin_model(
    scene: Scene,
    limit_mag: float = float("inf"),
    exact: bool = True,
    subsamples: int = 1,
    directions: int = 512,
    shadows: bool = True,
    coarse_spacing: float = 0.02,
) -> SpinModel:
    """The fit model of a scene: exact (its facets, shadows if non-convex) or coarse.

    Args:
        scene: shape and materials; ``[attitude] body_axis`` gives the spin axis
            in the body frame (a fixed-attitude scene spins about body z).
        exact: False for the cheap model (:func:`coarsen_facets`).
        subsamples: sub-exposures per sample (motion blur).
        directions: normal bins of the coarse model.
        coarse_spacing: shadow sub-point spacing of the coarse model (fraction
            of the object's size; the exact model uses the scene's).
        shadows: self-shadowing in the exact model when the mesh is non-convex.
    """
    body_axis = scene.attitude.body_axis if scene.attitude.model == "spin" else (0.0, 0.0, 1.0)
    b = np.asarray(body_axis, np.float64)
    b = b / np.linalg.norm(b)
    facets = scene.facets
    use = shadows and scene.render.shadows == "auto"
    settings = scene.render.shadow
    if not exact:  # fewer sub-points: the shadow look-up dominates the cost otherwise
        settings = dataclasses.replace(settings, spacing=coarse_spacing)
    obj = space_object(
        scene,
        None,
        jnp.float32,
        settings if use else None,
        facets=None if exact else coarsen_facets(facets, directions),
    )
    frac = (np.arange(subsamples) + 0.5) / subsamples - 0.5
    return SpinModel(
        obj=obj,
        body_axis=jnp.asarray(b, jnp.float32),
        body_ref=jnp.asarray(reference_direction(b), jnp.float32),
        sub_frac=jnp.asarray(frac, jnp.float32),
        floor_m2_sr=jnp.asarray(1e-10 * float(facets.areas_m2.sum()), jnp.float32),
        limit_mag=jnp.asarray(limit_mag, jnp.float32),
    )


def data_arrays(data: FitData) -> tuple:
    f = lambda x: jnp.asarray(x, jnp.float32)  # noqa: E731
    return (
        f(data.t_s),
        f(data.exposure_s),
        f(data.sun_dir),
        f(data.obs_dir),
        f(data.const_mag),
    )


# ---------------------------------------------------------------------------
# Coordinates


def lm_to_mc(theta_lm: np.ndarray, noise_mag) -> np.ndarray:
    """(..., 6) LM coordinates (+ noise) → (..., 6) MCMC coordinates."""
    t = np.asarray(theta_lm, np.float64)
    u = t[..., :3] / np.linalg.norm(t[..., :3], axis=-1, keepdims=True)
    lam = np.mod(np.arctan2(u[..., 1], u[..., 0]), 2 * np.pi)
    return np.stack(
        [
            lam,
            u[..., 2],
            t[..., 3],
            np.mod(t[..., 4], 2 * np.pi),
            t[..., 5],
            np.log(np.broadcast_to(noise_mag, lam.shape)),
        ],
        axis=-1,
    )


def mc_to_lm(theta_mc):
    """(..., 6) MCMC → LM coordinates (works on numpy and JAX arrays)."""
    xp = jnp if isinstance(theta_mc, jax.Array) else np
    lam, z = theta_mc[..., 0], xp.clip(theta_mc[..., 1], -1.0, 1.0)
    r = xp.sqrt(1 - z**2)
    return xp.stack(
        [r * xp.cos(lam), r * xp.sin(lam), z, theta_mc[..., 2], theta_mc[..., 3], theta_mc[..., 4]],
        axis=-1,
    )


def pole_radec_deg(theta_lm) -> tuple[np.ndarray, np.ndarray]:
    t = np.asarray(theta_lm, np.float64)
    u = t[..., :3] / np.linalg.norm(t[..., :3], axis=-1, keepdims=True)
    return (
        np.degrees(np.mod(np.arctan2(u[..., 1], u[..., 0]), 2 * np.pi)),
        np.degrees(np.arcsin(np.clip(u[..., 2], -1, 1))),
    )


def angle_between_deg(a, b) -> np.ndarray:
    """Angle (deg) between unit vectors (..., 3)."""
    a = np.asarray(a) / np.linalg.norm(a, axis=-1, keepdims=True)
    b = np.asarray(b) / np.linalg.norm(b, axis=-1, keepdims=True)
    return np.degrees(np.arccos(np.clip(np.sum(a * b, axis=-1), -1, 1)))


# ---------------------------------------------------------------------------
# Multi-start MAP


@dataclasses.dataclass(frozen=True)
class Mode:
    """A distinct optimum: LM coordinates, χ² on the model it was refined with, members."""

    theta_lm: np.ndarray
    chi2: float
    starts: int
    noise_mag: float

    @property
    def period_s(self) -> float:
        return float(math.exp(self.theta_lm[3]))

    @property
    def pole_radec_deg(self) -> tuple[float, float]:
        ra, dec = pole_radec_deg(self.theta_lm)
        return float(ra), float(dec)

    def describe(self, best_chi2: float) -> dict:
        ra, dec = self.pole_radec_deg
        return {
            "period_s": self.period_s,
            "pole_ra_deg": ra,
            "pole_dec_deg": dec,
            "phase_deg": float(np.degrees(np.mod(self.theta_lm[4], 2 * np.pi))),
            "dmag": float(self.theta_lm[5]),
            "chi2": self.chi2,
            "delta_chi2": self.chi2 - best_chi2,
            "noise_mag": self.noise_mag,
            "starts": self.starts,
        }


def dense_jvp(fn):
    """``fn`` (P,) → (N,) with a JVP rule that forms the (N, P) Jacobian by ``jacfwd``.

    optimistix linearises the residuals (``jax.linearize``), which keeps every
    (samples × facets) intermediate of the facet sum for later tangents: an LM
    step then costs 4-5× one fused ``jacfwd`` (S4: 267 vs 48 ms). With this rule
    the linearisation holds only the Jacobian and its linear map is a matrix
    product; values are those of ``jax.jacfwd(fn)``.
    """

    @jax.custom_jvp
    def wrapped(theta):
        return fn(theta)

    @wrapped.defjvp
    def _jvp(primals, tangents):
        (theta,), (dt,) = primals, tangents

        def value_twice(x):  # one trace of fn: the Jacobian's output and the value
            y = fn(x)
            return y, y

        jac, value = jax.jacfwd(value_twice, has_aux=True)(theta)
        return value, jac @ dt

    return wrapped


@filter_jit
def _solve(model: SpinModel, arrays, mag, weight, starts, max_steps: int, batch: int):
    """Batched optimistix LM (``lax.map`` over vmapped blocks of ``batch`` starts).

    Compiled once per model layout, start count and batch size. The blocks
    bound memory: the shadow look-up under ``jacfwd`` holds (starts × samples
    × facets × tangents) values, ~29 GB for 1,024 starts of S4 in one vmap.
    """
    import optimistix as optx

    @dense_jvp
    def plain(theta):
        return (model.magnitudes(theta, *arrays) - mag) * weight

    def residuals(theta, _args):
        return plain(theta)

    solver = optx.LevenbergMarquardt(rtol=1e-5, atol=1e-6)

    def one(y0):
        sol = optx.least_squares(residuals, solver, y0, max_steps=max_steps, throw=False)
        r = residuals(sol.value, None)
        return sol.value, jnp.sum(r**2)

    return jax.lax.map(one, starts, batch_size=batch)


def least_squares(
    model: SpinModel, data: FitData, starts: np.ndarray, max_steps: int = 20
) -> tuple[np.ndarray, np.ndarray]:
    """Levenberg–Marquardt from every start at once (one vmapped optimistix solve).

    Args:
        starts: (K, 6) LM coordinates.
        max_steps: LM iterations (all starts run this many under ``vmap``).

    Returns:
        (K, 6) optima and (K,) their sums of squared residuals (weights 1/σ with
        σ the data errors, or 1 mag where unknown).
    """
    arrays = data_arrays(data)
    sigma = np.where(data.mag_err > 0, data.mag_err, 1.0)
    mag = jnp.asarray(soft_clip(data.mag, data.limit_mag), jnp.float32)
    weight = jnp.asarray(1.0 / sigma, jnp.float32)
    per_start = data.n * model.obj.n_facets
    batch = int(min(len(starts), max(1, 2**21 // per_start)))
    theta, cost = _solve(
        model, arrays, mag, weight, jnp.asarray(starts, jnp.float32), max_steps, batch
    )
    theta, cost = np.asarray(theta, np.float64), np.asarray(cost, np.float64)
    cost = np.where(np.isfinite(cost), cost, np.inf)
    return theta, cost


def start_points(
    seeds_period_s, n_starts: int, rng: np.random.Generator, period_jitter: float = 0.002
) -> np.ndarray:
    """(n_starts, 6) LM starts: isotropic poles, the seed periods in turn, uniform phases.

    Δm starts at 0 and is set by :func:`_match_offset` before solving.
    """
    seeds = np.asarray(seeds_period_s, np.float64)
    pole = rng.normal(size=(n_starts, 3))
    per = seeds[np.arange(n_starts) % len(seeds)] * np.exp(
        period_jitter * rng.standard_normal(n_starts)
    )
    phase = rng.uniform(0, 2 * np.pi, n_starts)
    return np.column_stack([pole, np.log(per), phase, np.zeros(n_starts)])


@filter_jit
def _batch_magnitudes(model: SpinModel, arrays, thetas):
    return jax.vmap(lambda th: model.magnitudes(th, *arrays))(thetas)


def reversed_starts(thetas, n_starts: int, rng: np.random.Generator) -> np.ndarray:
    """(n_starts, 6) starts at the reversed poles −u of ``thetas`` (LM coordinates):
    same period, phases spread uniformly, poles jittered by ~3°."""
    base = np.asarray(thetas, np.float64)[np.arange(n_starts) % len(thetas)]
    out = base.copy()
    u = -base[:, :3] / np.linalg.norm(base[:, :3], axis=1, keepdims=True)
    out[:, :3] = u + 0.05 * rng.standard_normal((n_starts, 3))
    out[:, 4] = rng.uniform(0, 2 * np.pi, n_starts)
    out[:, 5] = 0.0
    return out


def _match_offset(model: SpinModel, data: FitData, starts: np.ndarray) -> np.ndarray:
    """Set each start's Δm to the median offset between data and model."""
    thetas = jnp.asarray(starts, jnp.float32)
    m = np.asarray(_batch_magnitudes(model, data_arrays(data), thetas), np.float64)
    out = starts.copy()
    out[:, 5] = np.median(soft_clip(data.mag, data.limit_mag)[None, :] - m, axis=1)
    return out


def distinct_modes(
    theta: np.ndarray,
    cost: np.ndarray,
    n_data: int,
    pole_tol_deg: float = 10.0,
    period_tol: float = 0.01,
    max_modes: int = 8,
) -> list[tuple[np.ndarray, float, int]]:
    """Greedy clustering of optima: (theta, cost, members) per mode, best first.

    Two optima belong together when their poles are within ``pole_tol_deg`` and
    their periods within a fraction ``period_tol``.
    """
    order = np.argsort(cost)
    modes: list[list] = []
    for k in order:
        if not np.isfinite(cost[k]):
            break
        for m in modes:
            same_pole = angle_between_deg(theta[k, :3], m[0][:3]) < pole_tol_deg
            same_period = abs(theta[k, 3] - m[0][3]) < period_tol
            if same_pole and same_period:
                m[2] += 1
                break
        else:
            if len(modes) < max_modes:
                modes.append([theta[k], float(cost[k]), 1])
    return [tuple(m) for m in modes]


def multistart(
    scene: Scene,
    data: FitData,
    seeds_period_s,
    n_starts: int = 1024,
    search_samples: int = 64,
    search_steps: int = 10,
    refine_steps: int = 12,
    max_modes: int = 8,
    subsamples: int = 1,
    rng: np.random.Generator | None = None,
    log=None,
) -> list[Mode]:
    """Multi-start MAP: cheap-model search from ``n_starts``, exact-model refinement.

    The search model is the coarse one (:func:`coarsen_facets`, 128 normal
    bins) without shadows on ``search_samples`` evenly spread samples: it
    only has to put starts into the right basins. A second solve of the same
    size starts at the reversed poles of the four best optima
    (:func:`reversed_starts`); the ``max_modes`` best distinct optima of both
    are then refined on the exact model (shadows included).

    Returns:
        Distinct modes on the exact model, best (lowest χ²) first.
    """
    rng = rng or np.random.default_rng(0)
    log = log or (lambda msg: None)
    # Search on an evenly spread subset of the samples and the coarse model.
    sub = data.subset(np.unique(np.linspace(0, data.n - 1, search_samples).astype(int)))
    coarse = spin_model(
        scene, data.limit_mag, exact=False, subsamples=subsamples, directions=128, shadows=False
    )
    starts = _match_offset(coarse, sub, start_points(seeds_period_s, n_starts, rng))
    theta, cost = least_squares(coarse, sub, starts, max_steps=search_steps)
    first = distinct_modes(theta, cost, sub.n, max_modes=max_modes)
    # The reversed spin (pole −u) of a good optimum gives a nearly time-reversed
    # light curve: often as good, and often missed by random starts. A second
    # batched solve of the same size (no new compilation) starts there.
    rev = _match_offset(coarse, sub, reversed_starts([c[0] for c in first[:4]], n_starts, rng))
    theta2, cost2 = least_squares(coarse, sub, rev, max_steps=search_steps)
    candidates = distinct_modes(
        np.concatenate([theta, theta2]), np.concatenate([cost, cost2]), sub.n, max_modes=max_modes
    )
    log(
        f"search: {n_starts} starts on {sub.n} samples, then {n_starts} at reversed poles → "
        f"{len(candidates)} distinct optima (coarse model)"
    )
    exact = spin_model(scene, data.limit_mag, exact=True, subsamples=subsamples)
    init = np.stack([c[0] for c in candidates])
    refined, rcost = least_squares(exact, data, init, max_steps=refine_steps)
    modes = []
    for (th, c, members), r_th, r_c in zip(candidates, refined, rcost, strict=True):
        del th, c
        noise = math.sqrt(r_c / max(data.n - N_LM, 1)) if np.all(data.mag_err == 0) else 0.0
        modes.append(Mode(theta_lm=r_th, chi2=float(r_c), starts=members, noise_mag=noise))
    # Refinement can land two candidates on one optimum: merge again.
    merged = distinct_modes(
        np.stack([m.theta_lm for m in modes]), np.array([m.chi2 for m in modes]), data.n
    )
    by_theta = {m.theta_lm.tobytes(): m for m in modes}
    out = []
    for th, _c, _n in merged:
        out.append(by_theta[th.tobytes()])
    return sorted(out, key=lambda m: m.chi2)
