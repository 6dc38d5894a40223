"""The facet model: facets with per-facet material coefficients, and the fused facet sum.

Every material of :mod:`jaxlc.body.brdf` maps onto one per-facet form, so one
kernel serves mixed materials::

    I/E = Σ_f  μ0 μ [kl + kd D(μ0) D(μ)]  +  ks (fa/hs + fb (1−hs)⁵/hs) (n·h)^z min(μ0, μ)

with μ0 = n·s, μ = n·v, hs = h·s, D(μ) = 1 − (1 − μ/2)⁵, the sum over facets
with μ0 > 0 and μ > 0 and the facet area folded into kl, kd, ks. The
``μ0 μ / max(μ0, μ) = min(μ0, μ)`` identity removes the division of the lobe.
Terms no material uses are removed at trace time (static flags).
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from jaxlc.body.brdf import AbstractBRDF
from jaxlc.body.mesh import Facets
from jaxlc.memo import identity_memo

#: The static flags of a :class:`FacetModel`: which terms are traced.
FLAGS = ("use_lambert", "use_as_diffuse", "use_specular", "anisotropic")
COEFFICIENTS = ("kl", "kd", "ks", "fa", "fb", "nu", "nv")


class FacetModel(eqx.Module):
    """Facets with their material coefficients: the traced input of the kernel.

    Array fields are (F,) or (F, 3); ``kl, kd, ks`` include the facet area, so
    their unit is m² sr⁻¹. They may be numpy arrays (made on the host; JAX
    moves them at the jit boundary) or JAX arrays (traced, differentiable).
    The boolean flags are static: terms that no facet uses are not traced at all.
    """

    normals: Float[Array, "F 3"]
    tangent_u: Float[Array, "F 3"]
    tangent_w: Float[Array, "F 3"]
    kl: Float[Array, " F"]
    kd: Float[Array, " F"]
    ks: Float[Array, " F"]
    fa: Float[Array, " F"]
    fb: Float[Array, " F"]
    nu: Float[Array, " F"]
    nv: Float[Array, " F"]
    use_lambert: bool = eqx.field(static=True)
    use_as_diffuse: bool = eqx.field(static=True)
    use_specular: bool = eqx.field(static=True)
    anisotropic: bool = eqx.field(static=True)

    @property
    def n_facets(self) -> int:
        return int(self.normals.shape[-2])

    def astype(self, dtype) -> FacetModel:
        """The same model with every array in ``dtype`` (float32 or float64)."""
        return jax.tree_util.tree_map(lambda x: jnp.asarray(x, dtype=dtype), self)


def _plain_values(coef: list[dict]) -> tuple | None:
    """Each part's :data:`COEFFICIENTS` as plain floats (one tuple a part), or None where
    any is a JAX tracer (a model differentiated in its materials)."""
    try:
        return tuple(tuple(float(np.asarray(c[k], np.float64)) for k in COEFFICIENTS) for c in coef)
    except (TypeError, jax.errors.TracerArrayConversionError, jax.errors.ConcretizationTypeError):
        return None


def facet_model(
    facets: Facets,
    materials: list[AbstractBRDF],
    dtype=jnp.float32,
    area_scale: float = 1.0,
    n_facets: int | None = None,
) -> FacetModel:
    """Attach one material per part to the facets.

    Args:
        facets: geometry from :func:`jaxlc.body.mesh.facets_from_mesh`.
        materials: one material per entry of ``facets.part_names``.
        dtype: float dtype of the model's arrays.
        area_scale: multiplies every facet area (a scene's ``scale`` squared).
        n_facets: pad with inert facets up to this many (:func:`pad_facets`; default none).

    Returns:
        :class:`FacetModel`: numpy arrays when the materials hold plain numbers
        (fast, no device work; what does not depend on ``area_scale`` made once per
        facets and materials, :func:`_unit_model`), JAX arrays (differentiable in the
        materials' parameters) when they hold traced values.
    """
    if len(materials) != len(facets.part_names):
        raise ValueError(
            f"facet_model: got {len(materials)} materials for "
            f"{len(facets.part_names)} parts {facets.part_names}"
        )
    dtype = np.dtype(dtype)
    coef = [type(m).coefficients(m) for m in materials]  # not eqx's bound method (~20 µs)
    flags = dict(
        use_lambert=any(m.has_lambert for m in materials),
        use_as_diffuse=any(m.has_as_diffuse for m in materials),
        use_specular=any(m.has_specular for m in materials),
        anisotropic=any(m.anisotropic for m in materials),
    )
    axes = tuple(tuple(m.tangent_axis) for m in materials)
    values = _plain_values(coef)
    if values is not None:  # the same shape and materials at every size: made once
        unit = _unit_model(facets, values, axes, dtype.str, n_facets or len(facets.part))
        scale = np.asarray(area_scale, dtype)
        arrays = dict(zip(UNIT_FIELDS, unit, strict=True))
        arrays.update({k: arrays[k] * scale for k in AREA_FIELDS})
        return FacetModel(**arrays, **flags)
    part = np.asarray(facets.part)
    area = jnp.asarray(facets.areas_m2 * area_scale, dtype=dtype)
    per_part = {k: jnp.stack([jnp.asarray(c[k], dtype=dtype) for c in coef]) for k in COEFFICIENTS}
    per_facet = {k: v[part] for k, v in per_part.items()}
    u, w = _part_frames(facets, axes)
    model = FacetModel(
        normals=jnp.asarray(facets.normals, dtype=dtype),
        tangent_u=jnp.asarray(u, dtype=dtype),
        tangent_w=jnp.asarray(w, dtype=dtype),
        **{k: per_facet[k] * area if k in AREA_FIELDS else per_facet[k] for k in COEFFICIENTS},
        **flags,
    )
    return model if n_facets is None else pad_facets(model, n_facets)


#: The coefficients that hold the facet area (m² sr⁻¹).
AREA_FIELDS = ("kl", "kd", "ks")
#: The array fields of a :class:`FacetModel`, in :func:`_unit_model`'s order.
UNIT_FIELDS = ("normals", "tangent_u", "tangent_w", *COEFFICIENTS)


@identity_memo(maxsize=16)
def _unit_model(facets: Facets, values: tuple, axes: tuple, dtype: str, n_facets: int) -> tuple:
    """A :class:`FacetModel`'s arrays (:data:`UNIT_FIELDS`) at area scale 1 (numpy,
    ``dtype``, read-only: shared by every model made from them) for per-part
    coefficient ``values`` (one tuple of :data:`COEFFICIENTS` a part), padded with inert
    facets to ``n_facets``: once per facets and materials, not per curve."""
    part = np.asarray(facets.part)
    per_part = np.asarray(values, np.float64)  # (parts, coefficients)
    area = np.asarray(facets.areas_m2, np.float64)
    u, w = _part_frames(facets, axes)
    out = {"normals": facets.normals, "tangent_u": u, "tangent_w": w}
    for i, k in enumerate(COEFFICIENTS):
        out[k] = per_part[part, i] * (area if k in AREA_FIELDS else 1.0)
    extra = n_facets - len(part)
    if extra > 0:
        out = {k: np.concatenate([x, _inert(k, x, extra)]) for k, x in out.items()}
    return tuple(np.array(out[k], dtype) for k in UNIT_FIELDS)


@identity_memo(maxsize=16)
def _part_frames(facets: Facets, axes: tuple) -> tuple[np.ndarray, np.ndarray]:
    """(F, 3) tangents u and w of every facet, those of part i from reference axis
    ``axes[i]`` (:func:`tangent_frame`; once per facets and axes, not per curve)."""
    part = np.asarray(facets.part)
    u = np.zeros_like(facets.normals)
    w = np.zeros_like(facets.normals)
    for i, axis in enumerate(axes):
        sel = part == i
        if np.any(sel):
            u[sel], w[sel] = tangent_frame(facets.normals[sel], axis)
    return u, w


def tangent_frame(normals: np.ndarray, reference_axis=(0.0, 0.0, 1.0)):
    """Per-facet tangents ``u`` (projection of ``reference_axis`` onto the facet)
    and ``w = n × u``; where the reference is parallel to the normal, the body
    x axis (or y) is projected instead.

    Args:
        normals: (F, 3) unit normals.
        reference_axis: (3,) body-frame direction of the first tangent, e.g. the
            brushing direction of an anisotropic material.

    Returns:
        (u, w), each (F, 3) unit vectors, orthonormal with the normals.
    """
    normals = np.asarray(normals, dtype=np.float64)
    u = np.zeros_like(normals)
    todo = np.ones(len(normals), dtype=bool)
    for axis in (reference_axis, (1.0, 0.0, 0.0), (0.0, 1.0, 0.0)):
        a = np.asarray(axis, dtype=np.float64)
        a = a / np.linalg.norm(a)
        proj = a[None, :] - (normals @ a)[:, None] * normals
        norm = np.linalg.norm(proj, axis=1)
        take = todo & (norm > 1e-3)
        u[take] = proj[take] / norm[take, None]
        todo &= ~take
    w = np.cross(normals, u)
    return u, w


def pad_facets(model: FacetModel, n_facets: int, flags: dict | None = None) -> FacetModel:
    """The model with inert facets (zero coefficients) up to ``n_facets`` and, if
    given, other static flags (a flag set needlessly only adds zeros)."""
    extra = n_facets - model.n_facets
    if extra <= 0 and (flags is None or all(getattr(model, f) == v for f, v in flags.items())):
        return model  # nothing to add (a class's curves share one facet count)
    arrays = {}
    for field in dataclasses.fields(model):
        if field.name in FLAGS:
            continue
        x = getattr(model, field.name)
        if extra > 0:
            xp = np if isinstance(x, np.ndarray) else jnp
            x = xp.concatenate([x, _inert(field.name, x, extra)])
        arrays[field.name] = x
    flags = flags or {f: getattr(model, f) for f in FLAGS}
    return FacetModel(**arrays, **flags)


def _inert(name: str, x, extra: int):
    """``extra`` rows of field ``name`` (like ``x``, numpy or JAX) for inert facets: zero
    coefficients, exponents 1, normals and tangents +z."""
    xp = np if isinstance(x, np.ndarray) else jnp
    if x.ndim == 2:
        return xp.broadcast_to(xp.asarray([0.0, 0.0, 1.0], x.dtype), (extra, 3))
    return xp.full((extra,), 1.0 if name in ("nu", "nv") else 0.0, x.dtype)


def facet_slice(model: FacetModel, start: int, stop: int) -> FacetModel:
    """Facets ``start … stop − 1`` of one model (arrays (F,) or (F, 3); static bounds)."""
    return jax.tree_util.tree_map(lambda x: x[start:stop], model)


def pad_models(models: list[FacetModel], flags: dict | None = None) -> list[FacetModel]:
    """Models padded with inert facets to one facet count and one set of flags
    (the union of theirs, or ``flags``), ready to be stacked."""
    n_max = max(m.n_facets for m in models)
    if flags is None:
        flags = {f: any(getattr(m, f) for m in models) for f in FLAGS}
    return [pad_facets(m, n_max, flags) for m in models]


# ---------------------------------------------------------------------------
# The facet sum


def dot_parts(a, parts):
    """(T, 3) · facet vectors given as their components (x, y, z), each broadcastable to
    (T, X) — all facets as (1, F) rows or a few gathered per sample as (T, K) — → (T, X),
    written out so XLA fuses it into the facet loop."""
    return a[:, None, 0] * parts[0] + a[:, None, 1] * parts[1] + a[:, None, 2] * parts[2]


def _dot(a, b):
    """(T, 3) · (F, 3) → (T, F) (:func:`dot_parts` of b's rows)."""
    return dot_parts(a, tuple(b[None, :, c] for c in range(3)))


def _as_diffuse_shape(mu):
    """D(μ) = 1 − (1 − μ/2)⁵, expanded so small μ loses no precision."""
    x = 0.5 * mu
    return x * (5.0 + x * (-10.0 + x * (10.0 + x * (-5.0 + x))))


def facet_contributions(
    model: FacetModel,
    sun_b: Float[Array, "T 3"],
    obs_b: Float[Array, "T 3"],
    specular: bool = True,
) -> Float[Array, "T F"]:
    """Per-facet terms A ρ (n·s)(n·v) (m² sr⁻¹), zero unless lit and seen.

    Args:
        model: facets and materials.
        sun_b: (T, 3) unit vectors object→Sun in the body frame.
        obs_b: (T, 3) unit vectors object→observer in the body frame.
        specular: include the specular lobes (False: the diffuse terms alone, for a
            caller that sums the lobes of a few candidate facets itself,
            :mod:`jaxlc.body.lobe_cells`).

    Returns:
        (T, F) contributions; their sum over facets is :func:`facet_intensity`.
    """
    s, v = sun_b, obs_b
    n = model.normals
    # Clamping both cosines at 0 masks every term: μ0 μ, min(μ0, μ) and D(0) all
    # vanish unless the facet is both lit and seen; no joint mask is needed.
    mu0 = jnp.maximum(_dot(s, n), 0.0)
    mu = jnp.maximum(_dot(v, n), 0.0)
    k = 0.0
    if model.use_lambert:
        k = model.kl[None, :]
    if model.use_as_diffuse:
        k = k + model.kd[None, :] * _as_diffuse_shape(mu0) * _as_diffuse_shape(mu)
    total = mu0 * mu * k if model.use_lambert or model.use_as_diffuse else 0.0
    if model.use_specular and specular:
        total = total + _specular(model, s, v, mu0, mu)
    if isinstance(total, float):  # no term traced: zeros of the right shape
        total = jnp.zeros_like(mu0)
    return total


#: From this many facets, :func:`facet_intensity` sums the (T, F) terms as a product with a
#: vector of ones: XLA:CPU's matrix-vector product reduces them faster than the row
#: reduction fused into the loop that makes them (S4's 1,104-facet run: its bulk kernel calls
#: 0.88–0.95× their time, A/B on one pinned core); below it, the fused
#: reduction is faster (S6's 24 facets: 2.5× slower as a product).
DOT_SUM_FACETS = 256


def facet_intensity(
    model: FacetModel,
    sun_b: Float[Array, "T 3"],
    obs_b: Float[Array, "T 3"],
    weights: Float[Array, "T F"] | None = None,
    specular: bool = True,
) -> Float[Array, " T"]:
    """Radiant intensity per unit irradiance, I/E = Σ_f w_f A ρ (n·s)(n·v), in m² sr⁻¹.

    Args:
        model: facets and materials.
        sun_b: (T, 3) unit vectors object→Sun in the body frame.
        obs_b: (T, 3) unit vectors object→observer in the body frame.
        weights: optional (T, F) factors per facet and sample, e.g. the lit and
            seen fraction of facets that can be shadowed.
        specular: include the specular lobes (:func:`facet_contributions`).

    Returns:
        (T,) I/E. Multiply by the irradiance and divide by range² for the flux.

    Finite, with finite gradients, at grazing angles, at phase angles of 0°
    and 180° and for exponents up to 10⁵ in float32.
    """
    terms = facet_contributions(model, sun_b, obs_b, specular)
    if weights is not None:
        terms = terms * weights
    if terms.shape[-1] >= DOT_SUM_FACETS:  # the sum as a matrix-vector product
        return terms @ jnp.ones(terms.shape[-1], terms.dtype)
    return jnp.sum(terms, axis=-1)


_LN2 = 0.6931471805599453
#: Bits of float32 √½ (0x3F3504F3): mantissas are reduced into [√½, √2).
_SQRT_HALF_BITS = 0x3F3504F3


def log1m(delta):
    """ln(1 − δ) for δ in [0, 1), float32 or float64, relative error ≲ 3·10⁻⁷.

    The lobe's logarithm is most of the facet sum's cost: XLA's ``log1p`` is a
    slow path on the CPU (the AS kernel ran 1.4× faster without it, S4). Here
    u = 1 − δ = 2ᵉ m with m in [√½, √2) from the float's bits, and
    ln m = 2 atanh(s), s = (m − 1)/(m + 1), |s| ≤ 0.172, by its odd series to
    s¹¹; where e = 0 the numerator m − 1 is taken as −δ exactly, so small δ
    keeps its full relative precision (ln(1 − δ) ≈ −δ), which exponents of
    10⁵ need. Only arithmetic and bit operations: one fused, vectorised loop.
    """
    dtype = delta.dtype
    if dtype != jnp.float32:  # float64: the library function (references, tests)
        return jnp.log1p(-delta)
    u = 1.0 - delta
    bits = jax.lax.bitcast_convert_type(u, jnp.int32)
    # e such that u / 2ᵉ lies in [√½, √2): the exponent field of u / √½
    e = jax.lax.shift_right_arithmetic(bits - _SQRT_HALF_BITS, 23)
    # m = u · 2⁻ᵉ: a product (not a bit copy) so that derivatives flow through it
    m = u * jax.lax.bitcast_convert_type(jax.lax.shift_left(127 - e, 23), jnp.float32)
    top = e == 0
    s = jnp.where(top, -delta, m - 1.0) / jnp.where(top, 2.0 - delta, m + 1.0)
    s2 = s * s
    series = 2.0 + s2 * (
        2.0 / 3 + s2 * (2.0 / 5 + s2 * (2.0 / 7 + s2 * (2.0 / 9 + s2 * (2.0 / 11))))
    )
    return e.astype(dtype) * _LN2 + s * series


def half_vectors(s, v):
    """Half vectors h (T, 3) of unit vectors s, v (T, 3), with 1/(h·s) (T,) and the
    Schlick factor (1 − h·s)⁵ (T,); at α → 180° (s + v → 0) h is s + v itself (no facet
    is both lit and seen there) and 1/(h·s) is 0."""
    sv = s + v
    sq = jnp.sum(sv * sv, axis=-1)
    ok = sq > 1e-12  # α → 180°: no facet is both lit and seen
    norm_safe = jnp.sqrt(jnp.where(ok, sq, 1.0))  # |s + v| = 2 h·s = 2 cos(α/2)
    h = sv / norm_safe[:, None]
    inv_hs = jnp.where(ok, 2.0 / norm_safe, 0.0)
    schlick = (1.0 - 0.5 * norm_safe) ** 5
    return h, inv_hs, schlick


def lobe_terms(half, normal, coef: dict, mu0, mu, tangents=None):
    """ks (fa + fb (1−hs)⁵)/hs · (n·h)^z · min(μ0, μ) for facets laid out as (T, X) or
    (1, X) arrays: all facets (:func:`facet_contributions`) or a few gathered per sample
    (:mod:`jaxlc.body.lobe_cells`).

    Args:
        half: :func:`half_vectors` of the samples.
        normal: the facets' normal components (x, y, z), each broadcastable to (T, X).
        coef: ``ks, fa, fb, nu, nv`` of the facets, each broadcastable to (T, X).
        mu0, mu: (T, X) clamped cosines n·s and n·v.
        tangents: for anisotropic lobes, the components of the tangents u and w
            (two triples like ``normal``); None for isotropic ones (z = nu).
    """
    h, inv_hs, schlick = half
    fresnel_over_hs = coef["fa"] * inv_hs[:, None] + coef["fb"] * (schlick * inv_hs)[:, None]
    # δ = 1 − n·h = |h − n|²/2 is exact near the lobe's peak (no cancellation),
    # so log(n·h) = log1p(−δ) keeps exponents of 10⁵ accurate in float32.
    diff2 = (
        (h[:, None, 0] - normal[0]) ** 2
        + (h[:, None, 1] - normal[1]) ** 2
        + (h[:, None, 2] - normal[2]) ** 2
    )
    delta = jnp.minimum(0.5 * diff2, 0.999999)  # lit facets have n·h > 0, δ < 1
    log_nh = log1m(delta)
    if tangents is not None:
        # z log(n·h) = (nu hu² + nv hw²) · log(n·h) / (1 − (n·h)²), and
        # 1 − (n·h)² = δ (2 − δ); the ratio tends to −½ as δ → 0.
        hu, hw = (dot_parts(h, t) for t in tangents)
        sin2 = delta * (2.0 - delta)
        small = sin2 < 1e-12
        ratio = jnp.where(small, -0.5, log_nh / jnp.where(small, 1.0, sin2))
        z_log = (coef["nu"] * hu * hu + coef["nv"] * hw * hw) * ratio
    else:
        z_log = coef["nu"] * log_nh
    lobe = jnp.exp(z_log)
    return coef["ks"] * fresnel_over_hs * lobe * jnp.minimum(mu0, mu)


def _specular(model: FacetModel, s, v, mu0, mu):
    """The lobes of every facet, (T, F) (:func:`lobe_terms`)."""

    def row(x):  # (F, 3) → its components as (1, F) rows
        return tuple(x[None, :, c] for c in range(3))

    coef = {k: getattr(model, k)[None, :] for k in ("ks", "fa", "fb", "nu", "nv")}
    tangents = (row(model.tangent_u), row(model.tangent_w)) if model.anisotropic else None
    return lobe_terms(half_vectors(s, v), row(model.normals), coef, mu0, mu, tangents)
