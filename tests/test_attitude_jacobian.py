"""The fit models' Jacobian through body turns equals forward mode through the plain kernel."""

from __future__ import annotations

from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_tumble_fit import CYLINDER_TUMBLE

import jaxlc
import jaxlc.inference.tumble_model as tm
from jaxlc.inference.data import fit_data
from jaxlc.inference.model import spin_model, truth_theta
from jaxlc.rendering.attitude_jacobian import attitude_intensity
from jaxlc.rendering.kernel import exposure_intensity

# Both Jacobians are taken op by op (no jit): compiled separately, the two programs round
# the facet directions differently, and a sample whose facet sits on a kink (a horizon,
# a shadow-table cell edge) then takes the other one-sided derivative (S7 tumbling: 4
# of 120 rows, up to 4 % of a column; the same happens between two compilations of
# the plain path).


def plain_jacobian(model, attitude_of, theta):
    """(N, P) ∂I/∂θ by ``jax.jacfwd`` through the kernel as the renderer calls it."""

    def intensity(th):
        obj = eqx.tree_at(lambda o: o.attitude, model.obj, attitude_of(th))
        return exposure_intensity(obj, model.inputs)

    return np.asarray(jax.jacfwd(intensity)(theta))


def turned_jacobian(model, attitude_of, theta):
    f = lambda th: attitude_intensity(model.obj, model.inputs, attitude_of, th)  # noqa: E731
    return np.asarray(f(theta)), np.asarray(jax.jacfwd(f)(theta))


def assert_same_jacobian(model, attitude_of, theta):
    value, got = turned_jacobian(model, attitude_of, theta)
    want = plain_jacobian(model, attitude_of, theta)
    obj = eqx.tree_at(lambda o: o.attitude, model.obj, attitude_of(theta))
    np.testing.assert_allclose(value, exposure_intensity(obj, model.inputs), rtol=1e-5)
    scale = np.abs(want).max(axis=0)
    assert np.all(scale[:-1] > 0)  # every attitude coordinate moves the light curve
    # float32 rounding only: the same chain rule, summed in another order
    np.testing.assert_array_less(np.abs(got - want).max(axis=0), 1e-4 * scale + 1e-30)


@pytest.mark.parametrize("adapted", [False, True])
def test_spin_jacobian_with_shadows(adapted):
    """S4 (shadow look-up, AS lobes) spinning, 1 s exposures with blur: the fixed
    sub-exposure count (a reshape mean) and instants chosen at the spin (a segment sum)."""
    scene = jaxlc.load_scene("s4_falcon9")
    geo = jaxlc.synthetic_geometry(duration_s=120, phase_start_deg=30, phase_end_deg=70)
    data = fit_data(jaxlc.render(scene, geo), geo, default_exposure_s=scene.exposure_s)
    truth = truth_theta(scene, data)
    model = spin_model(scene, data, scene.attitude.period_s, theta=truth if adapted else None)
    assert (model.inputs.subsamples is None) == adapted
    theta = model.to_device(truth) + jnp.array([0.02, -0.03, 0.01, 1e-3, 0.3, 0.0])
    assert_same_jacobian(model, lambda t: model.attitude(t[:3], t[3], t[4]), theta)


def test_tumble_jacobian(write_scene, meshes_dir):
    """S7 (a box with an antenna block: shadows, no symmetry axis) tumbling: nine
    attitude coordinates through three body turns.

    A body of revolution would not do: turned about its axis its light curve does not
    change, and the Jacobian's entries there are float32 cancellation noise of the
    facet sum (a cylinder's: up to 6 % of a column's largest entry, jit vs eager)."""
    text = Path(jaxlc.load_scene("s7_antenna_box").source).read_text()
    text = text[: text.index("[attitude]")].replace("../meshes/", f"{meshes_dir}/")
    tumble = CYLINDER_TUMBLE[CYLINDER_TUMBLE.index("[attitude]") :]
    scene = jaxlc.load_scene(write_scene(text + tumble))
    assert scene.attitude.model == "tumble" and scene.render.shadows != "off"
    geo = jaxlc.synthetic_geometry(duration_s=120, phase_start_deg=30, phase_end_deg=90)
    data = fit_data(jaxlc.render(scene, geo), geo, default_exposure_s=scene.exposure_s)
    theta = tm.truth_theta(scene, data, 0.1)
    model = tm.tumble_model(scene, data, theta, 0.1)
    assert model.obj.shadow is not None
    t = model.to_device(theta) + 0.01 * jnp.arange(10, dtype=jnp.float32) % 0.03
    assert_same_jacobian(model, model.attitude, t)
