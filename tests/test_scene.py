"""Strict scene parsing: every error names the key."""

from __future__ import annotations

import pytest
from helpers import SCENES

import jaxlc
from jaxlc.body.brdf import AshikhminShirley, Lambert
from jaxlc.errors import SceneError

BASE = """
[object]
mesh = "@MESHES@/falcon9_upper_stage.obj"

[[material]]
part = "*"
brdf = "ashikhmin-shirley"
rd = 0.5
rs = 0.1
nu = 100

[attitude]
model = "spin"
body_axis = [1, 0, 0]
pole_ra_deg = 30.0
pole_dec_deg = 60.0
period_s = 82.6
"""


#: BASE as a dict (scene_from_dict), the mesh by its shipped name.
SCENE_DICT = {
    "object": {"mesh": "falcon9_upper_stage.obj"},
    "attitude": {"model": "spin", "body_axis": [1, 0, 0], "pole_ra_deg": 30.0,
                 "pole_dec_deg": 60.0, "period_s": 82.6},
}  # fmt: skip


@pytest.mark.parametrize("path", sorted(SCENES.glob("*.toml")), ids=lambda p: p.stem)
def test_shipped_scenes_parse(path):
    scene = jaxlc.load_scene(path)
    assert scene.mesh_path.is_file()
    assert len(scene.materials_for(scene.facets.part_names)) == len(scene.facets.part_names)


def test_render_table(write_scene):
    text = BASE + '\n[render]\nshadows = "off"\nshadow_grid = 64\nsubsamples = 8\n'
    r = jaxlc.load_scene(write_scene(text)).render
    assert (r.shadows, r.shadow.grid, r.subsamples, r.blur) == ("off", 64, 8, "auto")


def test_base_scene_defaults(write_scene):
    scene = jaxlc.load_scene(write_scene(BASE))
    brdf = scene.materials[0].brdf
    assert isinstance(brdf, AshikhminShirley) and brdf.nv == brdf.nu == 100.0
    assert not brdf.anisotropic
    assert scene.exposure_s == 1.0 and scene.attitude.phase_deg == 0.0
    assert scene.attitude.epoch_utc is None


def test_part_override(write_scene):
    text = BASE + '\n[[material]]\npart = "nozzle"\nbrdf = "lambert"\nrd = 0.2\n'
    scene = jaxlc.load_scene(write_scene(text))
    mats = scene.materials_for(scene.facets.part_names)
    by_name = dict(zip(scene.facets.part_names, mats, strict=True))
    assert isinstance(by_name["nozzle"], Lambert)
    assert isinstance(by_name["body"], AshikhminShirley)


BAD = [
    (BASE.replace("rd = 0.5", "rd = 1.5"), r"rd = 1\.5 is outside \[0, 1\]"),
    (BASE.replace("rs = 0.1", "rs = -0.1"), r"rs = -0\.1 is outside \[0, 1\]"),
    (
        BASE.replace("period_s = 82.6", "period_s = 0.0"),
        r"period_s = 0\.0 is outside \[0\.001, 1e\+09\]",
    ),
    (BASE.replace("period_s = 82.6", "period_s = -3"), r"period_s = -3\.0 is outside \[0\.001"),
    (
        BASE.replace("body_axis = [1, 0, 0]", "body_axis = [0, 0, 0]"),
        "body_axis .* must not be the zero vector",
    ),
    (
        BASE.replace("body_axis = [1, 0, 0]", "body_axis = [1, 0]"),
        "body_axis .* must be a list of 3",
    ),
    (
        BASE.replace("pole_dec_deg = 60.0", "pole_dec_deg = 95.0"),
        r"pole_dec_deg = 95\.0 is outside",
    ),
    (
        BASE.replace("period_s = 82.6", "period_s = 82.6\nperiod = 3"),
        "unknown key 'period'; did you mean 'period_s'",
    ),
    (BASE.replace("period_s = 82.6\n", ""), "missing required key 'period_s'"),
    (BASE.replace("rd = 0.5\n", ""), "missing required key 'rd'"),
    (BASE.replace('brdf = "ashikhmin-shirley"', 'brdf = "phong"'), "brdf = 'phong' is not one of"),
    (BASE.replace('brdf = "ashikhmin-shirley"', 'brdf = "lambert"'), "unknown key 'nu'"),
    (BASE.replace("nu = 100", 'nu = "high"'), "nu = 'high' must be a number"),
    (BASE.replace("nu = 100", "nu = nan"), "must be finite"),
    (
        BASE.replace('model = "spin"', 'model = "wobble"'),
        "model = 'wobble' must be one of 'spin', 'fixed', 'tumble'",
    ),
    (BASE.replace('model = "spin"', 'model = "tumble"'), "missing required key 'inertia_kg_m2'"),
    (BASE + "\n[sensor]\nexposure_s = 0\n", r"exposure_s = 0\.0 is outside \[1e-06, 3600\]"),
    (BASE + "\n[sensor]\nexposure = 1\n", "unknown key 'exposure'"),
    (BASE + "\n[rendering]\nfast = true\n", "unknown key 'rendering'; did you mean 'render'"),
    (BASE + "\n[render]\nfast = true\n", r"\[render\]: unknown key 'fast'"),
    (BASE + '\n[render]\nshadows = "on"\n', "shadows = 'on' must be one of 'auto', 'off'"),
    (
        BASE + "\n[render]\nshadow_grid = 3\n",
        r"shadow_grid = 3\.0 must be a whole number in \[4, 512\]",
    ),
    (BASE + "\n[render]\nsubsamples = 2.5\n", "subsamples = 2.5 must be a whole number"),
    (BASE.replace("[object]", "[objects]"), "missing required key 'object'"),
    (BASE.replace("falcon9_upper_stage.obj", "nope.obj"), "mesh = .*nope.obj.* not found"),
    (
        BASE.replace("pole_ra_deg = 30.0", 'pole_ra_deg = 30.0\nepoch_utc = "yesterday"'),
        "epoch_utc = 'yesterday' is not an ISO 8601",
    ),
    (
        BASE + '\n[[material]]\npart = "*"\nbrdf = "lambert"\nrd = 0.1\n',
        "part '\\*' is given twice",
    ),
    ("[object\nmesh=1", "not valid TOML"),
]


@pytest.mark.parametrize(("text", "message"), BAD)
def test_bad_scene_errors_name_the_key(write_scene, text, message):
    with pytest.raises(SceneError, match=message):
        jaxlc.load_scene(write_scene(text))


def test_unknown_part_and_missing_material(write_scene):
    text = BASE + '\n[[material]]\npart = "solar_panel"\nbrdf = "lambert"\nrd = 0.2\n'
    scene = jaxlc.load_scene(write_scene(text))
    with pytest.raises(SceneError, match=r"part = 'solar_panel' is not a part of .*parts: nozzle"):
        scene.materials_for(scene.facets.part_names)
    no_default = BASE.replace('part = "*"', 'part = "body"')
    scene = jaxlc.load_scene(write_scene(no_default))
    with pytest.raises(SceneError, match=r"part 'nozzle' .* has no material"):
        scene.materials_for(scene.facets.part_names)


def test_fixed_quaternion_checks(write_scene):
    fixed = BASE.split("[attitude]")[0] + '[attitude]\nmodel = "fixed"\nquaternion = [2, 0, 0, 0]\n'
    with pytest.raises(SceneError, match="has norm 2; give a unit quaternion"):
        jaxlc.load_scene(write_scene(fixed))
    ok = fixed.replace("[2, 0, 0, 0]", "[0.5, 0.5, 0.5, 0.5]")
    assert jaxlc.load_scene(write_scene(ok)).attitude.quaternion == (0.5, 0.5, 0.5, 0.5)


def test_missing_scene_file(tmp_path):
    with pytest.raises(SceneError, match="does not exist"):
        jaxlc.load_scene(tmp_path / "none.toml")


def test_mesh_relative_to_scene_file(tmp_path):
    import shutil

    from helpers import MESHES

    shutil.copy(MESHES / "cubesat_3u.obj", tmp_path / "sat.obj")
    text = BASE.replace('"@MESHES@/falcon9_upper_stage.obj"', '"sat.obj"')
    (tmp_path / "s.toml").write_text(text)
    assert jaxlc.load_scene(tmp_path / "s.toml").mesh_path == (tmp_path / "sat.obj").resolve()


def test_files_are_never_looked_up_in_the_working_directory(tmp_path, monkeypatch):
    """A mesh next to the working directory but not next to the scene file is not
    found; a bare shipped mesh name and a shipped scene name are (package data)."""
    import shutil

    from helpers import MESHES

    work, scenes = tmp_path / "work", tmp_path / "scenes"
    (work / "meshes").mkdir(parents=True)
    scenes.mkdir()
    shutil.copy(MESHES / "cubesat_3u.obj", work / "meshes" / "mine.obj")
    monkeypatch.chdir(work)
    (scenes / "a.toml").write_text(
        BASE.replace('"@MESHES@/falcon9_upper_stage.obj"', '"meshes/mine.obj"')
    )
    with pytest.raises(SceneError, match=r"mine\.obj' not found"):
        jaxlc.load_scene(scenes / "a.toml")
    (scenes / "b.toml").write_text(
        BASE.replace('"@MESHES@/falcon9_upper_stage.obj"', '"cubesat_3u.obj"')
    )
    assert jaxlc.load_scene(scenes / "b.toml").mesh_path == (MESHES / "cubesat_3u.obj").resolve()
    for name in ("S4", "s4_falcon9", "s4_falcon9.toml"):
        assert jaxlc.load_scene(name).mesh_path.name == "falcon9_upper_stage.obj"
    with pytest.raises(SceneError, match="shipped scenes: S1"):
        jaxlc.load_scene("s9_nothing")


def test_a_remembered_material_never_lets_a_bad_one_through():
    """Valid [[material]] tables are parsed once per content (dataset curves repeat them):
    a table that differs only in a value's type, or in a bad value, still gets its error,
    and the remembered one comes back equal."""
    good = {"part": "*", "brdf": "lambert", "rd": 1.0}
    first = jaxlc.scene_from_dict({**SCENE_DICT, "material": [good]}, source="one")
    again = jaxlc.scene_from_dict({**SCENE_DICT, "material": [dict(good)]}, source="two")
    assert again.materials == first.materials
    for bad, message in [
        ({**good, "rd": True}, "rd"),
        ({**good, "rd": 1.5}, "rd = 1.5"),
        ({**good, "extra": 1.0}, "unknown key 'extra'"),
    ]:
        with pytest.raises(SceneError, match=message):
            jaxlc.scene_from_dict({**SCENE_DICT, "material": [bad]}, source="three")
