"""Reflectance models and the fused facet sum (``PHYSICS.md`` §1).

Three materials, each an ``equinox.Module`` so albedos and exponents can be
traced and differentiated:

``Lambert(rd)``
    ρ = rd/π.
``AshikhminShirley(rd, rs, nu, nv)``
    the Linares/Furfaro space-object form: the AS diffuse term
    (28 rd/23π)(1−rs)[1−(1−n·s/2)⁵][1−(1−n·v/2)⁵] plus the specular lobe
    √((nu+1)(nv+1))/8π · (n·h)^z / [(h·s) max(n·s, n·v)] · F with Schlick
    Fresnel F = rs + (1−rs)(1−h·s)⁵; anisotropic when nu ≠ nv, with a per-facet
    tangent.
``ASGlossy(rd, rs, nu, nv)``
    Lambert rd/π plus rs times the AS lobe without Fresnel — what Cycles
    renders for a Diffuse BSDF added to a Glossy BSDF with the
    Ashikhmin–Shirley distribution (roughness (2/(n+2))^¼).

Every material maps onto one per-facet form, so one kernel serves mixed
materials::

    I/E = Σ_f  μ0 μ [kl + kd D(μ0) D(μ)]  +  ks (fa/hs + fb (1−hs)⁵/hs) (n·h)^z min(μ0, μ)

with μ0 = n·s, μ = n·v, hs = h·s, D(μ) = 1 − (1 − μ/2)⁵, the sum over facets
with μ0 > 0 and μ > 0 and the facet area folded into kl, kd, ks. The
``μ0 μ / max(μ0, μ) = min(μ0, μ)`` identity removes the division of the lobe.
Terms no material uses are removed at trace time.
"""

from __future__ import annotations

import abc
import math
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from jaxlc.mesh import Facets, tangent_frame


class AbstractBRDF(eqx.Module):
    """A material. Subclasses give per-material coefficients of the facet form."""

    @abc.abstractmethod
    def coefficients(self) -> dict:
        """Scalars ``kl, kd, ks, fa, fb, nu, nv`` (sr⁻¹ or dimensionless)."""

    has_lambert: eqx.AbstractClassVar[bool]
    has_as_diffuse: eqx.AbstractClassVar[bool]
    has_specular: eqx.AbstractClassVar[bool]

    @property
    def anisotropic(self) -> bool:
        return False

    @property
    def tangent_axis(self) -> tuple[float, float, float]:
        return (0.0, 0.0, 1.0)


class Lambert(AbstractBRDF):
    """Lambertian surface, ρ = rd/π.

    Attributes:
        rd: diffuse albedo in [0, 1].
    """

    rd: float | Array
    has_lambert: ClassVar[bool] = True
    has_as_diffuse: ClassVar[bool] = False
    has_specular: ClassVar[bool] = False

    def coefficients(self) -> dict:
        return dict(kl=self.rd / math.pi, kd=0.0, ks=0.0, fa=0.0, fb=0.0, nu=1.0, nv=1.0)


def _is_anisotropic(nu, nv) -> bool:
    """False only when nu and nv are concrete and equal (decided at trace time)."""
    if nu is nv:
        return False
    try:
        return bool(np.asarray(nu) != np.asarray(nv))
    except (TypeError, jax.errors.TracerBoolConversionError, jax.errors.ConcretizationTypeError):
        return True


class _ASLobe(AbstractBRDF):
    rd: float | Array
    rs: float | Array
    nu: float | Array
    nv: float | Array
    tangent: tuple[float, float, float] = eqx.field(static=True, default=(0.0, 0.0, 1.0))

    @property
    def anisotropic(self) -> bool:
        return _is_anisotropic(self.nu, self.nv)

    @property
    def tangent_axis(self) -> tuple[float, float, float]:
        return self.tangent

    def _lobe_norm(self):
        return jnp.sqrt((self.nu + 1.0) * (self.nv + 1.0)) / (8.0 * math.pi)


class AshikhminShirley(_ASLobe):
    """Ashikhmin–Shirley BRDF in the Linares/Furfaro facet form.

    Attributes:
        rd: diffuse reflectance R_d in [0, 1].
        rs: specular reflectance at normal incidence R_s in [0, 1] (Schlick).
        nu, nv: Phong-like exponents along the tangent u and along w = n × u
            (equal: isotropic). Typical 1 … 10⁵.
        tangent: body-frame direction projected onto each facet to give u.
    """

    has_lambert: ClassVar[bool] = False
    has_as_diffuse: ClassVar[bool] = True
    has_specular: ClassVar[bool] = True

    def coefficients(self) -> dict:
        return dict(
            kl=0.0,
            kd=28.0 * self.rd / (23.0 * math.pi) * (1.0 - self.rs),
            ks=self._lobe_norm(),
            fa=self.rs,
            fb=1.0 - self.rs,
            nu=self.nu,
            nv=self.nv,
        )


class ASGlossy(_ASLobe):
    """Lambert plus the AS lobe without Fresnel: the Cycles-matched material.

    Cycles: Diffuse BSDF (colour rd, roughness 0) + Glossy BSDF
    (distribution Ashikhmin–Shirley, colour rs, roughness (2/(n+2))^¼).

    Attributes:
        rd: Lambert albedo in [0, 1].
        rs: colour (weight) of the specular lobe in [0, 1].
        nu, nv: lobe exponents, as for :class:`AshikhminShirley`.
    """

    has_lambert: ClassVar[bool] = True
    has_as_diffuse: ClassVar[bool] = False
    has_specular: ClassVar[bool] = True

    def coefficients(self) -> dict:
        return dict(
            kl=self.rd / math.pi,
            kd=0.0,
            ks=self._lobe_norm(),
            fa=self.rs,
            fb=0.0,
            nu=self.nu,
            nv=self.nv,
        )


#: Scene-file names of the materials.
BRDFS: dict[str, type[AbstractBRDF]] = {
    "lambert": Lambert,
    "ashikhmin-shirley": AshikhminShirley,
    "as-glossy": ASGlossy,
}


class FacetModel(eqx.Module):
    """Facets with their material coefficients: the traced input of the kernel.

    Array fields are (F,) or (F, 3); ``kl, kd, ks`` include the facet area, so
    their unit is m² sr⁻¹. The boolean flags are static: terms that no facet
    uses are not traced at all.
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


def facet_model(facets: Facets, materials: list[AbstractBRDF], dtype=jnp.float32) -> FacetModel:
    """Attach one material per part to the facets.

    Args:
        facets: geometry from :func:`jaxlc.mesh.facets_from_mesh`.
        materials: one material per entry of ``facets.part_names``.
        dtype: float dtype of the model's arrays.

    Returns:
        :class:`FacetModel`, differentiable in the materials' parameters.
    """
    if len(materials) != len(facets.part_names):
        raise ValueError(
            f"facet_model: got {len(materials)} materials for "
            f"{len(facets.part_names)} parts {facets.part_names}"
        )
    part = np.asarray(facets.part)
    area = jnp.asarray(facets.areas_m2, dtype=dtype)
    coef = [m.coefficients() for m in materials]
    per_part = {k: jnp.stack([jnp.asarray(c[k], dtype=dtype) for c in coef]) for k in coef[0]}
    per_facet = {k: v[part] for k, v in per_part.items()}

    u = np.zeros_like(facets.normals)
    w = np.zeros_like(facets.normals)
    for i, m in enumerate(materials):
        sel = part == i
        if np.any(sel):
            u[sel], w[sel] = tangent_frame(facets.normals[sel], m.tangent_axis)

    return FacetModel(
        normals=jnp.asarray(facets.normals, dtype=dtype),
        tangent_u=jnp.asarray(u, dtype=dtype),
        tangent_w=jnp.asarray(w, dtype=dtype),
        kl=per_facet["kl"] * area,
        kd=per_facet["kd"] * area,
        ks=per_facet["ks"] * area,
        fa=per_facet["fa"],
        fb=per_facet["fb"],
        nu=per_facet["nu"],
        nv=per_facet["nv"],
        use_lambert=any(m.has_lambert for m in materials),
        use_as_diffuse=any(m.has_as_diffuse for m in materials),
        use_specular=any(m.has_specular for m in materials),
        anisotropic=any(m.anisotropic for m in materials),
    )


def _dot(a, b):
    """(T, 3) · (F, 3) → (T, F), written out so XLA fuses it into the facet loop."""
    return (
        a[:, None, 0] * b[None, :, 0]
        + a[:, None, 1] * b[None, :, 1]
        + a[:, None, 2] * b[None, :, 2]
    )


def _as_diffuse_shape(mu):
    """D(μ) = 1 − (1 − μ/2)⁵, expanded so small μ loses no precision."""
    x = 0.5 * mu
    return x * (5.0 + x * (-10.0 + x * (10.0 + x * (-5.0 + x))))


def facet_contributions(
    model: FacetModel, sun_b: Float[Array, "T 3"], obs_b: Float[Array, "T 3"]
) -> Float[Array, "T F"]:
    """Per-facet terms A ρ (n·s)(n·v) (m² sr⁻¹), zero unless lit and seen.

    Args:
        model: facets and materials.
        sun_b: (T, 3) unit vectors object→Sun in the body frame.
        obs_b: (T, 3) unit vectors object→observer in the body frame.

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
    if model.use_specular:
        total = total + _specular(model, s, v, mu0, mu)
    return total


def facet_intensity(
    model: FacetModel,
    sun_b: Float[Array, "T 3"],
    obs_b: Float[Array, "T 3"],
    weights: Float[Array, "T F"] | None = None,
) -> Float[Array, " T"]:
    """Radiant intensity per unit irradiance, I/E = Σ_f w_f A ρ (n·s)(n·v), in m² sr⁻¹.

    Args:
        model: facets and materials.
        sun_b: (T, 3) unit vectors object→Sun in the body frame.
        obs_b: (T, 3) unit vectors object→observer in the body frame.
        weights: optional (T, F) factors per facet and sample, e.g. the lit and
            seen fraction of facets that can be shadowed.

    Returns:
        (T,) I/E. Multiply by the irradiance and divide by range² for the flux.

    Finite, with finite gradients, at grazing angles, at phase angles of 0°
    and 180° and for exponents up to 10⁵ in float32.
    """
    terms = facet_contributions(model, sun_b, obs_b)
    if weights is not None:
        terms = terms * weights
    return jnp.sum(terms, axis=-1)


def _specular(model: FacetModel, s, v, mu0, mu):
    """ks (fa + fb (1−hs)⁵)/hs · (n·h)^z · min(μ0, μ), per (sample, facet)."""
    sv = s + v
    sq = jnp.sum(sv * sv, axis=-1)
    ok = sq > 1e-12  # α → 180°: no facet is both lit and seen
    norm_safe = jnp.sqrt(jnp.where(ok, sq, 1.0))  # |s + v| = 2 h·s = 2 cos(α/2)
    h = sv / norm_safe[:, None]
    inv_hs = jnp.where(ok, 2.0 / norm_safe, 0.0)
    schlick = (1.0 - 0.5 * norm_safe) ** 5
    fresnel_over_hs = (
        model.fa[None, :] * inv_hs[:, None] + model.fb[None, :] * (schlick * inv_hs)[:, None]
    )

    # δ = 1 − n·h = |h − n|²/2 is exact near the lobe's peak (no cancellation),
    # so log(n·h) = log1p(−δ) keeps exponents of 10⁵ accurate in float32.
    n = model.normals
    diff2 = (
        (h[:, None, 0] - n[None, :, 0]) ** 2
        + (h[:, None, 1] - n[None, :, 1]) ** 2
        + (h[:, None, 2] - n[None, :, 2]) ** 2
    )
    delta = jnp.minimum(0.5 * diff2, 0.999999)  # lit facets have n·h > 0, δ < 1
    log_nh = jnp.log1p(-delta)
    if model.anisotropic:
        # z log(n·h) = (nu hu² + nv hw²) · log(n·h) / (1 − (n·h)²), and
        # 1 − (n·h)² = δ (2 − δ); the ratio tends to −½ as δ → 0.
        hu = _dot(h, model.tangent_u)
        hw = _dot(h, model.tangent_w)
        sin2 = delta * (2.0 - delta)
        small = sin2 < 1e-12
        ratio = jnp.where(small, -0.5, log_nh / jnp.where(small, 1.0, sin2))
        z_log = (model.nu[None, :] * hu * hu + model.nv[None, :] * hw * hw) * ratio
    else:
        z_log = model.nu[None, :] * log_nh
    lobe = jnp.exp(z_log)
    return model.ks[None, :] * fresnel_over_hs * lobe * jnp.minimum(mu0, mu)
