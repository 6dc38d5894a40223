"""Build the standard scenes' shape models S1–S6 (BENCHMARKS.md), and two further
non-convex test shapes, as OBJ files.

Run from anywhere: ``python experiments/make_meshes.py`` (``make meshes``).
Dimensions are in metres; each OBJ object (``o`` line) is a named part so
materials can differ per part. Outward normals follow the right-hand rule of
each triangle. The output goes to the package data, ``jaxlc/data/meshes/``, and
is committed; its ``README.md`` lists the files with their triangle and facet
counts.

Sources of the dimensions: Falcon 9 second stage 3.66 m diameter and about
13.8 m long with its Merlin Vacuum nozzle (SpaceX Falcon user's guide, 2021);
3U CubeSat 0.1 × 0.1 × 0.34 m (CubeSat design specification rev. 14).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import trimesh

HERE = Path(__file__).resolve().parent
OUT = HERE.parent / "jaxlc" / "data" / "meshes"

# Falcon 9 second stage (metres): tank, nose (payload adapter), engine, MVac nozzle.
F9_RADIUS = 1.83
F9_TANK_TOP = 9.0
F9_NOSE_TOP = 10.3
F9_NOSE_TOP_RADIUS = 0.6
F9_ENGINE_RADIUS = 0.5
F9_ENGINE_BOTTOM = -0.5
F9_THROAT_RADIUS = 0.3
F9_EXIT_RADIUS = 1.6
F9_NOZZLE_BOTTOM = -3.6
F9_NOZZLE_WALL = 0.02
SECTIONS = 48


def _clean(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    mesh.merge_vertices()
    mesh.update_faces(mesh.nondegenerate_faces())
    mesh.remove_unreferenced_vertices()
    return mesh


def _revolve(profile_rz, sections=SECTIONS) -> trimesh.Trimesh:
    """Surface of revolution about z of an (r, z) polyline; a profile traversed
    counter-clockwise around the solid's cross-section gives outward normals."""
    return _clean(trimesh.creation.revolve(np.asarray(profile_rz, float), sections=sections))


def _scene(parts: dict[str, trimesh.Trimesh]) -> trimesh.Scene:
    scene = trimesh.Scene()
    for name, mesh in parts.items():
        scene.add_geometry(mesh, geom_name=name, node_name=name)
    return scene


def plate() -> trimesh.Scene:
    """S1: 1 × 1 m plate in the body x-y plane, front face +z and back face −z
    (zero thickness; each side is one facet)."""
    v = np.array([[-0.5, -0.5, 0], [0.5, -0.5, 0], [0.5, 0.5, 0], [-0.5, 0.5, 0]], float)
    front = [[0, 1, 2], [0, 2, 3]]
    back = [[0, 2, 1], [0, 3, 2]]
    return _scene({"plate": trimesh.Trimesh(v, front + back, process=False)})


def sphere(level: int) -> trimesh.Scene:
    """S2: unit-radius icosphere (vertices on the sphere), 20·4^level triangles."""
    return _scene({"body": trimesh.creation.icosphere(subdivisions=level, radius=1.0)})


def falcon9_cylinder() -> trimesh.Scene:
    """S3: closed cylinder with the Falcon 9 second stage's outer dimensions,
    axis +z, from the nozzle exit plane to the nose top (convex)."""
    length = F9_NOSE_TOP - F9_NOZZLE_BOTTOM
    profile = [
        (0.0, F9_NOZZLE_BOTTOM),
        (F9_RADIUS, F9_NOZZLE_BOTTOM),
        (F9_RADIUS, F9_NOZZLE_BOTTOM + length),
        (0.0, F9_NOZZLE_BOTTOM + length),
    ]
    return _scene({"body": _revolve(profile, sections=64)})


def _bell(u, offset=0.0):
    """(r, z) of the nozzle bell at fraction u from throat (0) to exit (1)."""
    r = F9_THROAT_RADIUS + (F9_EXIT_RADIUS - F9_THROAT_RADIUS) * u**0.7 + offset
    z = F9_ENGINE_BOTTOM + (F9_NOZZLE_BOTTOM - F9_ENGINE_BOTTOM) * u
    return r, z


def falcon9_upper_stage() -> trimesh.Scene:
    """S4: tank cylinder + nose cone + engine housing + thin-walled bell nozzle
    (inside and outside surfaces), axis +z towards the nose (non-convex)."""
    u = np.linspace(0.0, 1.0, 12)
    inner = [_bell(x) for x in u]  # throat → exit
    outer = [_bell(x, F9_NOZZLE_WALL) for x in u[::-1]]  # exit → throat
    chamber_z = inner[0][1]
    nozzle = [(0.0, chamber_z), *inner, *outer]
    outer_top = outer[-1]
    engine = [outer_top, (F9_ENGINE_RADIUS, F9_ENGINE_BOTTOM), (F9_ENGINE_RADIUS, 0.0)]
    body = [(F9_ENGINE_RADIUS, 0.0), (F9_RADIUS, 0.0), (F9_RADIUS, F9_TANK_TOP)]
    nose = [(F9_RADIUS, F9_TANK_TOP), (F9_NOSE_TOP_RADIUS, F9_NOSE_TOP), (0.0, F9_NOSE_TOP)]
    return _scene(
        {
            "body": _revolve(body),
            "nose": _revolve(nose),
            "engine": _revolve(engine),
            "nozzle": _revolve(nozzle),
        }
    )


def cubesat_3u() -> trimesh.Scene:
    """S5: 3U CubeSat, 0.1 × 0.1 × 0.34 m, long axis z."""
    return _scene({"body": trimesh.creation.box((0.1, 0.1, 0.34))})


def boxwing() -> trimesh.Scene:
    """S6: box-wing satellite: 1.2 × 1.2 × 1.8 m bus, two 5 × 1.6 m solar panels
    on 0.3 m booms along ±y, panel faces ±x (strong self-shadowing)."""

    def box(extents, center):
        return trimesh.creation.box(extents, trimesh.transformations.translation_matrix(center))

    panels = trimesh.util.concatenate([box((0.04, 5.0, 1.6), (0.0, s * 3.4, 0.0)) for s in (1, -1)])
    booms = trimesh.util.concatenate([box((0.1, 0.3, 0.1), (0.0, s * 0.75, 0.0)) for s in (1, -1)])
    # Boom end caps would lie inside the bus and the panels: keep the tube only.
    booms.update_faces(np.abs(booms.face_normals[:, 1]) < 0.5)
    booms.remove_unreferenced_vertices()
    return _scene({"bus": box((1.2, 1.2, 1.8), (0, 0, 0)), "boom": booms, "panels": panels})


def _box(extents, center):
    return trimesh.creation.box(extents, trimesh.transformations.translation_matrix(center))


def antenna_box() -> trimesh.Scene:
    """A 1 m cube bus with a 0.3 × 0.3 × 0.06 m antenna block held 4 cm above its
    +z face by a 2 cm mast: a shadow caster close to the surface it shadows."""
    mast = _box((0.02, 0.02, 0.04), (0.1, 0.1, 0.52))
    mast.update_faces(np.abs(mast.face_normals[:, 2]) < 0.5)  # its end caps would be hidden
    mast.remove_unreferenced_vertices()
    return _scene(
        {
            "bus": _box((1.0, 1.0, 1.0), (0.0, 0.0, 0.0)),
            "mast": mast,
            "antenna": _box((0.3, 0.3, 0.06), (0.1, 0.1, 0.57)),
        }
    )


def boom_panel() -> trimesh.Scene:
    """A 1 × 1 × 1.5 m bus with one 1.5 × 1.2 m panel (faces ±x) on a 1.5 m boom along
    +y: a caster and a receiver a few metres apart."""
    boom = _box((0.05, 1.5, 0.05), (0.0, 1.25, 0.0))
    boom.update_faces(np.abs(boom.face_normals[:, 1]) < 0.5)
    boom.remove_unreferenced_vertices()
    return _scene(
        {
            "bus": _box((1.0, 1.0, 1.5), (0.0, 0.0, 0.0)),
            "boom": boom,
            "panel": _box((0.03, 1.5, 1.2), (0.0, 2.75, 0.0)),
        }
    )


MESHES = {
    "plate.obj": (plate, "S1"),
    **{f"sphere_L{k}.obj": ((lambda k=k: sphere(k)), "S2") for k in range(1, 6)},
    "falcon9_cylinder.obj": (falcon9_cylinder, "S3"),
    "falcon9_upper_stage.obj": (falcon9_upper_stage, "S4"),
    "cubesat_3u.obj": (cubesat_3u, "S5"),
    "boxwing.obj": (boxwing, "S6"),
    "antenna_box.obj": (antenna_box, "test"),
    "boom_panel.obj": (boom_panel, "test"),
}


def main(out_dir: Path = OUT) -> None:
    sys.path.insert(0, str(HERE.parent))
    from jaxlc.body.mesh import facets_from_mesh, load_mesh

    rows = []
    for name, (make, scene_id) in MESHES.items():
        scene = make()
        text = trimesh.exchange.obj.export_obj(
            scene, include_normals=False, include_texture=False, include_color=False, digits=10
        )
        (out_dir / name).write_text(
            f"# {scene_id} — made by experiments/make_meshes.py (trimesh {trimesh.__version__})\n"
            + text
        )
        f = facets_from_mesh(load_mesh(out_dir / name))
        ext = np.ptp(load_mesh(out_dir / name).vertices_m, axis=0)
        rows.append(
            f"| {scene_id} | `{name}` | {', '.join(f.part_names)} | {f.n_triangles} | "
            f"{f.n_facets} | {'yes' if f.convex else 'no'} | "
            f"{ext[0]:.2f} × {ext[1]:.2f} × {ext[2]:.2f} |"
        )
    readme = [
        "# Shape models",
        "",
        "Made by `python experiments/make_meshes.py` (the standard scenes of",
        "`BENCHMARKS.md`). Metres; body frame; OBJ objects are parts. Facets are",
        "coplanar triangles of one part merged (`jaxlc.body.mesh.facets_from_mesh`).",
        "",
        "| scene | file | parts | triangles | facets | convex | extent x × y × z (m) |",
        "|---|---|---|---|---|---|---|",
        *rows,
        "",
    ]
    (out_dir / "README.md").write_text("\n".join(readme))
    print("\n".join(rows))


if __name__ == "__main__":
    main()
