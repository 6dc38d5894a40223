"""The scene file's ``[attitude]`` table: parsed strictly, built into an attitude model.

Three models (:mod:`jaxlc.body.attitude`, :mod:`jaxlc.body.tumble`)::

    [attitude]
    model = "fixed"
    quaternion = [1.0, 0.0, 0.0, 0.0]          # [w, x, y, z], body → inertial

    [attitude]
    model = "spin"
    body_axis = [0, 0, 1]
    pole_ra_deg = 30.0
    pole_dec_deg = 60.0
    period_s = 82.6
    phase_deg = 0.0                           # optional, default 0
    epoch_utc = "2019-07-07T12:00:00Z"        # optional, default: first table row

    [attitude]
    model = "tumble"                          # torque-free rigid body
    inertia_kg_m2 = [1.0, 2.5, 3.0]           # principal moments along body x, y, z
    omega_body_rad_s = [0.05, 0.20, 0.01]     # body-frame angular velocity at the epoch
    quaternion = [1.0, 0.0, 0.0, 0.0]         # body → inertial at the epoch
    epoch_utc = "2024-03-20T20:00:00Z"        # optional, default: first table row

Values at ``epoch_utc`` are moved to the render's time origin in float64 on the
host (:meth:`AttitudeSpec.build`).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pandas as pd

from jaxlc.body import attitude as att
from jaxlc.body.tumble import Tumble
from jaxlc.errors import SceneError
from jaxlc.io.toml import Section, in_range, nonzero_vector, show
from jaxlc.io.utc import utc_timestamp

#: Spin periods a scene may give (s): 1 ms (1,000 turns per second) to ~30 years.
PERIOD_RANGE_S = (1e-3, 1e9)
#: Body rotation rates a tumble may give (rad/s): those of the spin periods.
RATE_RANGE_RAD_S = (2 * math.pi / PERIOD_RANGE_S[1], 2 * math.pi / PERIOD_RANGE_S[0])
MODELS = ("spin", "fixed", "tumble")
_PERIOD = "spin period in seconds, 0.001 … 1e9"


@dataclasses.dataclass(frozen=True)
class AttitudeSpec:
    """The ``[attitude]`` table in scene units (degrees, UTC; SI for a tumble)."""

    model: str
    quaternion: tuple[float, ...] | None = None
    body_axis: tuple[float, ...] | None = None
    pole_ra_deg: float | None = None
    pole_dec_deg: float | None = None
    period_s: float | None = None
    phase_deg: float = 0.0
    epoch_utc: pd.Timestamp | None = None
    inertia_kg_m2: tuple[float, ...] | None = None
    omega_body_rad_s: tuple[float, ...] | None = None

    def tumble(self) -> Tumble:
        """The tumble at its epoch (float64 leaves; ``model == "tumble"`` only)."""
        return Tumble.from_state(
            self.inertia_kg_m2, self.omega_body_rad_s, self.quaternion, np.float64
        )

    def rate_rad_s(self) -> float:
        """The largest rotation rate of the body (rad/s), which sets the motion blur:
        2π/period for a spin, max |ω(t)| for a tumble, 0 when fixed."""
        if self.model == "spin":
            return 2.0 * math.pi / self.period_s
        if self.model == "tumble":
            return self.tumble().max_rate_rad_s()
        return 0.0

    def exact_parameters(self) -> dict:
        """Float64 parameters to pass to ``attitude.times`` (keeps float32 models exact).

        A tumble's are its moments and ω at the epoch: the split of
        :meth:`~jaxlc.body.tumble.Tumble.times` needs only the motion's
        invariants (period and precession per period), the same at any epoch.
        """
        if self.model == "spin":
            return {"period_s": self.period_s}
        if self.model == "tumble":
            return {"inertia_kg_m2": self.inertia_kg_m2, "omega_body_rad_s": self.omega_body_rad_s}
        return {}

    def build(self, origin_utc: pd.Timestamp | None, dtype) -> att.AbstractAttitude:
        """The attitude model with its time origin at ``origin_utc`` (float64 phase
        or state transfer on the host; numpy leaves in ``dtype``)."""
        dtype = np.dtype(dtype)
        if self.model == "fixed":
            return att.Fixed(quaternion=np.asarray(self.quaternion, np.float64).astype(dtype))
        offset = 0.0
        if self.epoch_utc is not None and origin_utc is not None:
            offset = (origin_utc - self.epoch_utc).total_seconds()
        if self.model == "tumble":
            moved = self.tumble().at_offset(offset) if offset else self.tumble()
            return Tumble.from_state(
                moved.inertia_kg_m2, moved.omega_body_rad_s, moved.quaternion, dtype
            )
        phase = att.phase_at_offset_deg(self.phase_deg, self.period_s, offset)
        return att.Spin.from_degrees(
            self.body_axis, self.pole_ra_deg, self.pole_dec_deg, self.period_s, phase, dtype
        )

    def describe(self) -> str:
        """One line for ``jaxlc render --explain``: the model and its periods."""
        if self.model == "fixed":
            return "fixed"
        if self.model == "spin":
            return (
                f"spin, period {self.period_s:.6g} s about body "
                f"[{', '.join(f'{float(x):g}' for x in self.body_axis)}]"
                f", pole RA {self.pole_ra_deg:g}°, Dec {self.pole_dec_deg:g}°"
            )
        tumble = self.tumble()
        body, precession = tumble.periods_s()
        ra, dec = tumble.angular_momentum_radec_deg()
        return (
            f"tumble ({tumble.mode()}): ω repeats in the body every {body:.6g} s, precession "
            f"about L every {precession:.6g} s; L at RA {ra:.2f}°, Dec {dec:.2f}°; max rate "
            f"{math.degrees(tumble.max_rate_rad_s()):.3g}°/s"
        )


def parse_attitude(table, source) -> AttitudeSpec:
    """The ``[attitude]`` table of scene ``source``, checked (a :class:`SceneError`
    names the key of the first problem)."""
    where = f"{source}: [attitude]"
    sec = Section(table, where, SceneError)
    model = sec.get("model", str, what="'spin', 'fixed' or 'tumble'")
    if model == "fixed":
        spec = AttitudeSpec(model="fixed", quaternion=_unit_quaternion(sec, where))
    elif model == "spin":
        axis = sec.get(
            "body_axis", "vec3", check=nonzero_vector, what="spin axis in the body frame"
        )
        ra = sec.get("pole_ra_deg", float, check=in_range(-360.0, 360.0), what="degrees")
        dec = sec.get("pole_dec_deg", float, check=in_range(-90.0, 90.0), what="degrees")
        period = sec.get("period_s", float, check=in_range(*PERIOD_RANGE_S), what=_PERIOD)
        phase = sec.get("phase_deg", float, default=0.0, check=in_range(-1e6, 1e6), what="degrees")
        spec = AttitudeSpec(
            model="spin",
            body_axis=tuple(float(x) for x in axis / np.linalg.norm(axis)),
            pole_ra_deg=ra,
            pole_dec_deg=dec,
            period_s=period,
            phase_deg=phase,
            epoch_utc=_epoch(sec, where),
        )
    elif model == "tumble":
        inertia = sec.get(
            "inertia_kg_m2",
            "vec3",
            check=principal_moments_problem,
            what="principal moments along body x, y, z, kg m²",
        )
        omega = sec.get(
            "omega_body_rad_s",
            "vec3",
            check=_body_rate,
            what="body-frame angular velocity at the epoch, rad/s",
        )
        spec = AttitudeSpec(
            model="tumble",
            quaternion=_unit_quaternion(sec, where),
            epoch_utc=_epoch(sec, where),
            inertia_kg_m2=tuple(float(x) for x in inertia),
            omega_body_rad_s=tuple(float(x) for x in omega),
        )
    else:
        raise SceneError(
            f"{where}: model = {model!r} must be one of {', '.join(map(repr, MODELS))}"
        )
    sec.finish()
    return spec


def _unit_quaternion(sec: Section, where: str) -> tuple[float, ...]:
    q = sec.get("quaternion", "vec4", check=nonzero_vector, what="[w, x, y, z], body → inertial")
    norm = float(np.linalg.norm(q))
    if abs(norm - 1.0) > 1e-3:
        raise SceneError(
            f"{where}: quaternion = {show(q)} has norm {norm:.6g}; give a unit quaternion "
            f"[w, x, y, z] (e.g. {show(q / norm)})"
        )
    return tuple(float(x) for x in q / norm)


def _epoch(sec: Section, where: str) -> pd.Timestamp | None:
    epoch = sec.get("epoch_utc", str, default=None, what="ISO 8601 UTC")
    return None if epoch is None else utc_timestamp(epoch, f"{where}: epoch_utc", SceneError)


def principal_moments_problem(inertia) -> str | None:
    """What is wrong with (3,) principal moments of inertia, or None when they can be a
    rigid body's (all > 0, the triangle inequality)."""
    if not np.all(inertia > 0):
        return "must all be > 0 (principal moments of inertia)"
    for k in range(3):
        i, j = (k + 1) % 3, (k + 2) % 3
        # every rigid body has I_i + I_j ≥ I_k (equal for a flat plate); 1e-9 for rounding
        if inertia[i] + inertia[j] < inertia[k] * (1.0 - 1e-9):
            axes = "xyz"
            return (
                f"breaks the triangle inequality I_{axes[i]} + I_{axes[j]} ≥ I_{axes[k]} "
                f"({inertia[i]:g} + {inertia[j]:g} < {inertia[k]:g}) that every rigid body "
                "obeys; give the principal moments about the centre of mass"
            )
    return None


def _body_rate(omega) -> str | None:
    rate = float(np.linalg.norm(omega))
    lo, hi = RATE_RANGE_RAD_S
    if not lo <= rate <= hi:
        return (
            f"has |ω| = {rate:.3g} rad/s, outside [{lo:.3g}, {hi:.4g}] (rotation periods "
            f"{PERIOD_RANGE_S[0]:g} … {PERIOD_RANGE_S[1]:g} s); a body that does not turn "
            "is model = 'fixed'"
        )
    return None
