"""Large meshes: set-up, shadow table and render time, and peak memory (issue 15).

Meshes are generated (under ``--workdir``, a temporary folder by default; never
committed):

* ``sphere``: trimesh icospheres, 2·10⁴ … 1.3·10⁶ faces (convex: no shadow work);
* ``bumpy``: the same spheres with radial bumps r = 1 + 0.15 sin 6θ cos 5φ
  (non-convex, every triangle its own facet, nearly all of them shadowable:
  the worst case for the shadow table);
* ``falcon``: the S4 Falcon 9 stage subdivided 2–4 times (non-convex; the
  triangles merge back into ~1,200–1,500 facets: many triangles, few facets).

Each case runs in a child process, as ``jaxlc render`` would with an empty
shadow cache: S4's scene with the mesh swapped and one Ashikhmin–Shirley
material, over a 120-row synthetic geometry (phase 20° → 120°). The child
times reading + facets (``load_body``), the shadow table (``shadow_data``) and
the render (``jaxlc.render``: plan, kernel compilation, adaptive blur) and
reports its own peak resident memory (``getrusage``). Writes
``experiments/results/big_mesh.csv``.

    python experiments/big_mesh.py [--quick] [--max-faces N] [--out PATH] [--workdir DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

import jaxlc  # noqa: E402
from jaxlc.io.tables import write_table  # noqa: E402

S4 = HERE.parent / "jaxlc" / "data" / "scenes" / "s4_falcon9.toml"
S4_MESH = HERE.parent / "jaxlc" / "data" / "meshes" / "falcon9_upper_stage.obj"
#: (kind, subdivisions): icosphere levels 5–8 (20,480 … 1,310,720 faces), S4 subdivided 2–4×.
CASES = [(k, s) for s in (5, 6, 7, 8) for k in ("sphere", "bumpy")] + [
    ("falcon", s) for s in (2, 3, 4)
]
QUICK = [("sphere", 4), ("bumpy", 4), ("falcon", 1)]
MATERIAL = 'part = "*"\nbrdf = "ashikhmin-shirley"\nrd = 0.6\nrs = 0.1\nnu = 20\nnv = 20\n'


def make_mesh(kind: str, level: int, folder: Path) -> Path:
    """Write one generated mesh as OBJ (see the module docstring); its path."""
    import trimesh

    if kind == "falcon":
        mesh = trimesh.load(S4_MESH, force="mesh", process=False)
        v, f = mesh.vertices, mesh.faces
        for _ in range(level):
            v, f = trimesh.remesh.subdivide(v, f)
        mesh = trimesh.Trimesh(v, f, process=False)
    else:
        mesh = trimesh.creation.icosphere(subdivisions=level, radius=1.0)
        if kind == "bumpy":
            v = mesh.vertices
            theta, phi = np.arccos(np.clip(v[:, 2], -1, 1)), np.arctan2(v[:, 1], v[:, 0])
            r = 1.0 + 0.15 * np.sin(6 * theta) * np.cos(5 * phi)
            mesh = trimesh.Trimesh(v * r[:, None], mesh.faces, process=False)
    path = folder / f"{kind}_{len(mesh.faces)}.obj"
    if not path.exists():
        mesh.export(path)
    return path


def make_scene(mesh: Path) -> Path:
    """S4's scene with ``mesh`` and one material for every part."""
    text = S4.read_text()
    text = (
        text[: text.index("[[material]]")]
        + "[[material]]\n"
        + MATERIAL
        + "\n"
        + (text[text.index("[attitude]") :])
    )
    text = text.replace('mesh = "../meshes/falcon9_upper_stage.obj"', f'mesh = "{mesh}"')
    path = mesh.with_suffix(".toml")
    path.write_text(text)
    return path


def run_case(scene: Path, geometry: Path) -> dict:
    """In the child: time the stages of one render and report the peak memory."""
    import resource

    from jaxlc.body.mesh import load_body
    from jaxlc.body.shadow import reduced_resolution, shadow_data

    t0 = time.perf_counter()
    sc = jaxlc.load_scene(scene)
    mesh, facets = load_body(sc.mesh_path)
    t1 = time.perf_counter()
    options = sc.render
    data = None
    if not facets.convex:
        data = shadow_data(mesh, facets, options.shadow)
    t2 = time.perf_counter()
    lc = jaxlc.render(sc, geometry)
    t3 = time.perf_counter()
    return dict(
        faces=mesh.n_triangles,
        facets=facets.n_facets,
        shadowable=int(facets.can_shadow.sum()),
        grid=data.settings.grid if data else 0,
        subpoints=data.subpoints if data else 0,
        table_mb=data.nbytes / 1e6 if data else 0.0,
        setup_s=t1 - t0,
        shadow_s=t2 - t1,
        render_s=t3 - t2,
        total_s=t3 - t0,
        peak_rss_gb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6,
        finite=bool(np.all(np.isfinite(lc["flux_w_m2"]))),
        reduced=reduced_resolution(mesh, facets, options.shadow).removeprefix("; ") if data else "",
    )


def print_table(df: pd.DataFrame) -> None:
    cols = ["case", "faces", "facets", "shadowable", "grid", "subpoints", "setup_s"]
    cols += ["shadow_s", "render_s", "total_s", "peak_rss_gb"]
    print(df[cols].to_string(index=False, float_format=lambda x: f"{x:.2f}"))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="three small meshes (smoke test)")
    parser.add_argument("--max-faces", type=int, default=2_000_000, help="skip larger cases")
    parser.add_argument("--out", type=Path, default=HERE / "results" / "big_mesh.csv")
    parser.add_argument("--workdir", type=Path, default=None, help="where meshes are written")
    parser.add_argument("--case", nargs=2, type=Path, help=argparse.SUPPRESS)  # child mode
    args = parser.parse_args(argv)
    if args.case:
        print(json.dumps(run_case(*args.case)))
        return 0

    work = args.workdir or Path(tempfile.mkdtemp(prefix="jaxlc_big_mesh_"))
    work.mkdir(parents=True, exist_ok=True)
    geometry = work / "geometry.csv"
    jaxlc.write_table(jaxlc.synthetic_geometry(duration_s=120.0), geometry)
    rows = []
    for kind, level in QUICK if args.quick else CASES:
        faces = 20 * 4**level if kind != "falcon" else 2784 * 4**level
        if faces > args.max_faces:
            continue
        scene = make_scene(make_mesh(kind, level, work))
        with tempfile.TemporaryDirectory() as cache:  # an empty shadow cache
            env = dict(os.environ, JAXLC_CACHE_DIR=cache)
            child = subprocess.run(
                [sys.executable, __file__, "--case", str(scene), str(geometry)],
                capture_output=True,
                text=True,
                env=env,
            )
        if child.returncode != 0:
            print(child.stderr, file=sys.stderr)
            return 1
        rows.append(dict(case=f"{kind}-{faces}", kind=kind, **json.loads(child.stdout)))
        print(f"{rows[-1]['case']}: {rows[-1]['total_s']:.1f} s, {rows[-1]['peak_rss_gb']:.2f} GB")
    df = pd.DataFrame(rows)
    df.attrs.update(
        {
            "generator": "experiments/big_mesh.py",
            "jaxlc": jaxlc.__version__,
            "cpu_count": str(os.cpu_count()),
            "machine": f"{platform.machine()} {platform.processor() or ''}".strip(),
            "date_utc": pd.Timestamp.now(tz="UTC").strftime("%Y-%m-%dT%H:%M:%SZ"),
            "quick": str(args.quick),
        }
    )
    print_table(df)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    write_table(df, args.out)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
