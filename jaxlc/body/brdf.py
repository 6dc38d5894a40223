"""Reflectance models (``PHYSICS.md`` §1): the materials of a scene.

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

Every material maps onto the per-facet form of :mod:`jaxlc.body.facet_model`
(:meth:`AbstractBRDF.coefficients`), so one kernel serves mixed materials.
"""

from __future__ import annotations

import abc
import math
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array


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

    @property
    def _lobe_norm(self):
        """√((nu + 1)(nv + 1)) / 8π (a property: an eqx method is handed out wrapped in a
        pytree made on each access, ~20 µs)."""
        xp = jnp if isinstance(self.nu, jax.Array) or isinstance(self.nv, jax.Array) else np
        return xp.sqrt((self.nu + 1.0) * (self.nv + 1.0)) / (8.0 * math.pi)


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
            ks=self._lobe_norm,
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
            ks=self._lobe_norm,
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
