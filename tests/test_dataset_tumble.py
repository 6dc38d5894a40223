"""Tumbling classes in datasets: priors, labels, the stored curves re-rendered.

A ``[class.tumble]`` class draws torque-free states from priors on the
moments and the excitation; its labels (mode, excitation, both periods, L's
direction) are checked against the stored scene's state by formulas that share
nothing with the drawing (2E/L² and R I ω from the stored ω and quaternion),
and its stored curves against :func:`jaxlc.render` of that scene.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from helpers import radec_unit, rotation_matrix_from_quaternion

import jaxlc
import jaxlc.dataset as dataset
from jaxlc.dataset.config import DatasetError

pytest.importorskip("zarr")

CONFIG = """
[dataset]
count = 8
samples = 120
cadence_s = 2.0
shard_size = 8
seed = 11

[[class]]
name = "tumbling"
scene = "s3_cylinder"
period_s = [40.0, 200.0]
[class.tumble]
inertia_kg_m2 = [[0.15, 0.25], [0.9, 1.0], 1.0]
mode = "any"
excitation = [0.1, 0.8]

[[class]]
name = "spinning"
scene = "s3_cylinder"
period_s = [40.0, 200.0]

[geometry]
source = "synthetic"
phase_start_deg = [20.0, 60.0]
phase_end_deg = [60.0, 120.0]
range_start_m = [1.0e6, 2.0e6]
"""


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    path = tmp_path_factory.mktemp("tumble") / "bulk.toml"
    path.write_text(CONFIG)
    return dataset.generate(path, path.with_suffix(".zarr"), workers=0, progress=False)


def test_tumbling_labels_describe_the_stored_state(store):
    labels = store.labels
    tumbling = labels[labels["class"] == "tumbling"]
    assert len(tumbling) >= 2 and set(tumbling["tumble_mode"]) <= {"SAM", "LAM"}
    for _, row in tumbling.iterrows():
        att = json.loads(row["attitude"])
        assert att["model"] == "tumble"
        inertia = np.asarray(att["inertia_kg_m2"])
        w, q = np.asarray(att["omega_body_rad_s"]), np.asarray(att["quaternion"])
        i1, i2, i3 = np.sort(inertia)
        assert 0.15 <= i1 <= 0.25 and 0.9 <= i2 <= 1.0 and i3 == 1.0
        e = np.sum(inertia * w**2) / np.sum((inertia * w) ** 2)  # 2E / L²
        sam = e < 1 / i2
        assert row["tumble_mode"] == ("SAM" if sam else "LAM")
        x = (e - 1 / i3) / (1 / i2 - 1 / i3) if sam else (1 / i1 - e) / (1 / i1 - 1 / i2)
        assert row["excitation"] == pytest.approx(x, abs=1e-9) and 0.1 <= x <= 0.8
        ell = rotation_matrix_from_quaternion(q) @ (inertia * w)
        np.testing.assert_allclose(
            ell / np.linalg.norm(ell),
            radec_unit(row["pole_ra_deg"], row["pole_dec_deg"]),
            atol=1e-9,
        )
        assert row["period_s"] == pytest.approx(row["precession_period_s"], rel=1e-9)
        assert 40.0 <= row["period_s"] <= 200.0 and row["body_period_s"] > 0
        assert math.isnan(row["body_axis_x"])
    spinning = labels[labels["class"] == "spinning"]
    assert (spinning["tumble_mode"] == "").all() and spinning["excitation"].isna().all()
    assert all(json.loads(a)["model"] == "spin" for a in spinning["attitude"])


def test_tumbling_curves_re_render_from_their_labels(store):
    labels = store.labels
    for i in labels.index[labels["class"] == "tumbling"][:3]:
        scene = jaxlc.scene_from_dict(store.scene(int(i)))
        assert scene.attitude.model == "tumble"
        lc = jaxlc.render(scene, store.geometry(int(i)))
        stored = store["mag"][int(i)].astype(np.float64)
        lit = np.isfinite(stored)
        assert lit.sum() > 100 and np.ptp(stored[lit]) > 0.05  # it varies
        np.testing.assert_allclose(stored[lit], lc["mag"].to_numpy()[lit], atol=1e-4, rtol=0)


def test_a_format_2_store_still_reads(store, tmp_path):
    """A store written before tumbles (no attitude labels) reads with a warning, its
    spinning scenes rebuilt from the spin labels."""
    import shutil

    import zarr

    old = tmp_path / "old.zarr"
    shutil.copytree(store.path, old)
    root = zarr.open_group(str(old), mode="r+")
    spin = int(store.labels.index[store.labels["class"] == "spinning"][0])
    for name in ("attitude", "tumble_mode", "excitation"):
        del root["labels"][name]
    root.attrs["format"] = "jaxlc-dataset/2"
    with pytest.warns(UserWarning, match="no attitude or tumble labels"):
        ds = dataset.open_dataset(old)
    assert ds.labels.loc[spin, "attitude"] == ""
    assert ds.scene(spin)["attitude"] == json.loads(store.labels.loc[spin, "attitude"])


BASE = {
    "dataset": {"count": 2, "samples": 8, "seed": 1},
    "class": [
        {
            "name": "t",
            "scene": "s3_cylinder",
            "period_s": 60.0,
            "tumble": {"inertia_kg_m2": [0.2, 1.0, 1.0]},
        }
    ],
    "geometry": {
        "source": "synthetic",
        "phase_start_deg": 30.0,
        "phase_end_deg": 60.0,
        "range_start_m": 1e6,
    },
}


@pytest.mark.parametrize(
    ("tumble", "needles"),
    [
        ({"inertia_kg_m2": [0.2, 1.0]}, ["inertia_kg_m2 = [0.2, 1.0]", "must have 3 entries"]),
        ({"inertia_kg_m2": [0.2, -1.0, 1.0]}, ["entry -1.0", "> 0"]),
        ({"inertia_kg_m2": [0.2, "a", 1.0]}, ["entry 'a'", "a number or [low, high]"]),
        ({"inertia_kg_m2": [[0.1, 0.3], 0.5, 0.7]}, ["the draw [0.1, 0.5, 0.7]", "triangle"]),
        ({"inertia_kg_m2": [0.2, 1.0, 1.0], "mode": "wobble"}, ["mode = 'wobble'", "'SAM'"]),
        ({"inertia_kg_m2": [0.2, 1.0, 1.0], "excitation": 1.0}, ["excitation = 1.0"]),
        ({"inertia_kg_m2": [0.2, 1.0, 1.0], "spin": 1}, ["unknown key 'spin'"]),
        ({}, ["[class.tumble]", "inertia_kg_m2"]),
    ],
)
def test_bad_tumble_priors_are_named(tumble, needles):
    data = json.loads(json.dumps(BASE))
    data["class"][0]["tumble"] = tumble
    with pytest.raises(DatasetError) as info:
        dataset.config_from_dict(data, source="cfg.toml")
    text = str(info.value)
    assert "\n" not in text and "[class.tumble]" in text
    for needle in needles:
        assert needle in text, text


def test_tumble_moments_default_to_a_tumbling_scene():
    data = json.loads(json.dumps(BASE))
    data["class"][0] |= {"scene": "falcon9_tumble", "tumble": {"mode": "LAM"}}
    config = dataset.config_from_dict(data, source="cfg.toml")
    scene = jaxlc.load_scene("falcon9_tumble")
    assert config.classes[0].tumble.inertia_kg_m2 == tuple(
        (x, x) for x in scene.attitude.inertia_kg_m2
    )
