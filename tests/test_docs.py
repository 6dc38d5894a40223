"""Docs that run: the README's Python example and the docstring examples."""

from __future__ import annotations

import re
import subprocess
import sys

from helpers import MESHES, REPO


def _python_blocks(text: str) -> list[str]:
    return re.findall(r"```python\n(.*?)```", text, flags=re.S)


def test_readme_python_example_runs(tmp_path):
    blocks = _python_blocks((REPO / "README.md").read_text())
    assert blocks, "README has no python example"
    code = blocks[0]
    assert len(code.strip().splitlines()) <= 12
    # run in an empty folder: shipped scenes and meshes are package data
    r = subprocess.run(
        [sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=300
    )
    assert r.returncode == 0, r.stderr
    assert "float32 − float64" in r.stdout
    assert (tmp_path / "build" / "lightcurve.parquet").is_file()


def test_readme_cli_example_commands_exist():
    text = (REPO / "README.md").read_text()
    for cmd in re.findall(r"^jaxlc (\w+)", text, flags=re.M):
        assert cmd in (
            "geometry",
            "render",
            "info",
            "passes",
            "sites",
            "generate",
            "period",
            "fit",
            "calibrate",
            "frames",
            "extract",
        ), cmd
    assert "make demo" in text and "make test" in text


def test_readme_scene_example_loads(tmp_path):
    """The README's scene file, saved anywhere, loads: its mesh is a shipped one."""
    from jaxlc import load_scene

    blocks = re.findall(r"```toml\n(.*?)```", (REPO / "README.md").read_text(), flags=re.S)
    scene_block = next(b for b in blocks if "[object]" in b)
    (tmp_path / "my_scene.toml").write_text(scene_block)
    scene = load_scene(tmp_path / "my_scene.toml")
    assert scene.mesh_path.name == "falcon9_upper_stage.obj"
    assert (scene.attitude.model, scene.attitude.period_s) == ("spin", 82.6)
    assert [m.part for m in scene.materials] == ["*", "nozzle"]


def test_mesh_docstring_example():
    from jaxlc.body.mesh import facets_from_mesh, load_mesh

    f = facets_from_mesh(load_mesh(MESHES / "cubesat_3u.obj"))
    assert (f.n_triangles, f.n_facets, f.convex) == (12, 6, True)
