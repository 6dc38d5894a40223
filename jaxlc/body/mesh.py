"""Shape models: mesh files → named parts → facets.

A *facet* is a flat piece of surface with one normal, one area and one
material. Facets are derived once per mesh on the host in float64:

1. :func:`load_mesh` reads any trimesh-readable file (OBJ, STL, PLY, GLB, …)
   into a :class:`TriangleMesh` whose triangles carry a *part* index. Parts are
   the file's objects/groups (OBJ ``o``/``g``, glTF meshes); materials are
   assigned per part name.
2. :func:`facets_from_mesh` masks degenerate and non-finite triangles (with a
   warning naming how many), merges coplanar triangles of the same part into
   one facet (exact for the unshadowed facet sum, which is linear in area for a
   given normal), and records, per facet, whether any other geometry lies in
   front of its plane (``can_shadow``). A mesh with no such facet is convex and
   never shadows itself.

Size limit: at most :data:`MAX_TRIANGLES` (2,000,000) triangles; :func:`load_mesh`
refuses more with a :class:`MeshError` naming the file, its count and the limit
(an OBJ file before it is parsed). Every step is O(F log F) in time and O(F) in
memory (``experiments/big_mesh.py``); a large non-convex mesh's shadow table is
sized by budgets (:mod:`jaxlc.body.shadow`).
"""

from __future__ import annotations

import dataclasses
import functools
import warnings
from pathlib import Path

import numpy as np

from jaxlc.body.hull import support_heights
from jaxlc.body.planes import coplanar_groups
from jaxlc.errors import MeshError


class MeshWarning(UserWarning):
    """A mesh was usable but something in it was dropped or repaired."""


@dataclasses.dataclass(frozen=True)
class TriangleMesh:
    """Triangles with a part label each (host-side, float64).

    Attributes:
        vertices_m: (V, 3) vertex positions in metres, body frame.
        faces: (M, 3) vertex indices of each triangle (counter-clockwise seen
            from outside, so the right-hand normal points out).
        face_part: (M,) index into ``part_names`` for each triangle.
        part_names: names of the parts, e.g. ``("body", "nozzle")``.
        source: where the mesh came from (a path or a description).
    """

    vertices_m: np.ndarray
    faces: np.ndarray
    face_part: np.ndarray
    part_names: tuple[str, ...]
    source: str = "<memory>"

    @property
    def n_triangles(self) -> int:
        return int(self.faces.shape[0])

    @property
    def diagonal_m(self) -> float:
        """Length of the bounding box's diagonal (m): the mesh's size, which the shadow
        precomputation's spacings and margins are fractions of."""
        return float(np.linalg.norm(np.ptp(self.vertices_m, axis=0)))

    def scaled(self, scale: float) -> TriangleMesh:
        """The mesh with every coordinate multiplied by ``scale``."""
        if scale == 1.0:
            return self
        return dataclasses.replace(self, vertices_m=self.vertices_m * float(scale))


@dataclasses.dataclass(frozen=True)
class Facets:
    """Flat facets of a shape model (host-side, float64).

    Attributes:
        normals: (F, 3) outward unit normals, body frame.
        areas_m2: (F,) facet areas in m².
        centroids_m: (F, 3) area-weighted centroids in metres.
        part: (F,) part index of each facet (into ``part_names``).
        can_shadow: (F,) True where some geometry lies in front of the facet's
            plane, i.e. where the facet could be shadowed or hidden.
        triangle_facet: (M,) facet index of each input triangle, −1 where the
            triangle was masked out as degenerate.
        part_names: names of the parts.
        n_triangles: number of triangles in the input mesh.
        n_masked: number of triangles dropped as degenerate or non-finite.
        source: where the mesh came from.
    """

    normals: np.ndarray
    areas_m2: np.ndarray
    centroids_m: np.ndarray
    part: np.ndarray
    can_shadow: np.ndarray
    triangle_facet: np.ndarray
    part_names: tuple[str, ...]
    n_triangles: int
    n_masked: int
    source: str = "<memory>"

    @property
    def n_facets(self) -> int:
        return int(self.areas_m2.shape[0])

    @property
    def convex(self) -> bool:
        """True when no facet can be shadowed: the object never shadows itself."""
        return not bool(np.any(self.can_shadow))

    def scaled(self, scale: float) -> Facets:
        """The facets of the mesh scaled by ``scale`` (areas × scale², centroids × scale)."""
        if scale == 1.0:
            return self
        s = float(scale)
        return dataclasses.replace(
            self, areas_m2=self.areas_m2 * s * s, centroids_m=self.centroids_m * s
        )

    def subset(self, ids: np.ndarray) -> Facets:
        """These facets only (in this order), e.g. to give them their own material model."""
        ids = np.asarray(ids, dtype=np.int64)
        remap = np.full(self.n_facets, -1, dtype=np.int64)
        remap[ids] = np.arange(len(ids))
        tri = np.where(self.triangle_facet >= 0, remap[np.maximum(self.triangle_facet, 0)], -1)
        return dataclasses.replace(
            self,
            normals=self.normals[ids],
            areas_m2=self.areas_m2[ids],
            centroids_m=self.centroids_m[ids],
            part=self.part[ids],
            can_shadow=self.can_shadow[ids],
            triangle_facet=tri,
        )


# ---------------------------------------------------------------------------
# Reading


#: Most triangles a mesh may have (the documented limit; see the module docstring).
MAX_TRIANGLES = 2_000_000
#: Text-only formats (binary data in one is refused) and what load_mesh reads.
TEXT_FORMATS, ACCEPTED = {".obj": "OBJ", ".off": "OFF"}, "OBJ or OFF (text), STL, PLY, GLB/glTF"
#: Bytes of text files (tab, newlines, form feed, printable and any UTF-8 byte).
_TEXT_BYTES = bytes([9, 10, 11, 12, 13, *range(32, 127), *range(128, 256)])


def load_mesh(
    path: str | Path, scale: float = 1.0, max_triangles: int = MAX_TRIANGLES
) -> TriangleMesh:
    """Read a mesh file into named parts.

    Args:
        path: any file trimesh reads (OBJ, STL, PLY, GLB/glTF, OFF, …).
        scale: multiply coordinates by this (e.g. 0.001 for a file in mm).
        max_triangles: refuse meshes with more triangles than this.

    Returns:
        A :class:`TriangleMesh` with one part per object/group of the file; a
        file without names (STL, PLY) gives a single part called ``"body"``.

    Raises:
        MeshError: the file is missing, unreadable (binary data in a text format, a
            missing optional module), has no triangles or more than ``max_triangles``.
    """
    import trimesh

    path = Path(path)
    if not path.is_file():
        raise MeshError(f"mesh file {str(path)!r} does not exist (check [object] mesh)")
    if not (np.isfinite(scale) and scale > 0):
        raise MeshError(f"mesh scale {scale!r} must be a positive number")
    _check_text(path, max_triangles)
    try:
        loaded = trimesh.load(
            str(path),
            force="scene",
            process=False,
            split_objects=True,
            group_material=False,
            maintain_order=True,
        )
    except ImportError as exc:  # an optional module trimesh needs for this file
        name = getattr(exc, "name", None) or str(exc)
        raise MeshError(
            f"cannot read mesh {str(path)!r}: missing dependency, the Python module {name!r}"
            f" (install it with: pip install {name.replace('_', '-')})"
        ) from exc
    except Exception as exc:  # trimesh raises many types; report them as one
        raise MeshError(f"cannot read mesh {str(path)!r}: {exc}") from exc
    mesh = mesh_from_trimesh(loaded, source=str(path))
    if mesh.n_triangles > max_triangles:
        raise _too_many(path, f"{mesh.n_triangles:,} triangles", max_triangles)
    if scale != 1.0:
        mesh = dataclasses.replace(mesh, vertices_m=mesh.vertices_m * float(scale))
    return mesh


def _too_many(path, count: str, limit: int) -> MeshError:  # one message for both checks
    return MeshError(
        f"mesh {str(path)!r} has {count}, more than the limit of {limit:,} "
        "(simplify it, e.g. by quadric decimation in Blender or MeshLab)"
    )


def _check_text(path: Path, max_triangles: int) -> None:
    """Refuse binary data in a text format, and an OBJ with too many faces before parsing."""
    kind = TEXT_FORMATS.get(path.suffix.lower())
    if kind is None:
        return
    with open(path, "rb") as fh:
        head = fh.read(1 << 16)
    if b"\0" in head or len(head.translate(None, _TEXT_BYTES)) > 0.01 * len(head):
        raise MeshError(
            f"mesh file {str(path)!r} is not a text {kind} mesh (it holds binary data); "
            f"jaxlc reads {ACCEPTED} files: check the file and its extension"
        )
    if kind == "OBJ":  # a scan of the bytes: far cheaper than parsing a file too big
        faces = 0
        with open(path, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 24), b""):
                faces += block.count(b"\nf ")
        if faces > max_triangles:
            raise _too_many(path, f"at least {faces:,} faces", max_triangles)


def mesh_from_trimesh(obj, source: str = "<memory>") -> TriangleMesh:
    """Convert a ``trimesh.Trimesh`` or ``trimesh.Scene`` to a :class:`TriangleMesh`.

    Scene node transforms are applied; geometries with the same name form one
    part.
    """
    import trimesh

    if isinstance(obj, trimesh.Trimesh):
        scene = trimesh.Scene()
        scene.add_geometry(obj, geom_name="body", node_name="body")
        obj = scene
    if not isinstance(obj, trimesh.Scene):
        raise MeshError(f"{source}: expected a triangle mesh, got {type(obj).__name__}")

    stem = Path(source).name
    names: list[str] = []
    chunks_v, chunks_f, chunks_p = [], [], []
    offset = 0
    for node in obj.graph.nodes_geometry:
        transform, geom_name = obj.graph[node]
        geom = obj.geometry[geom_name]
        if not isinstance(geom, trimesh.Trimesh) or len(geom.faces) == 0:
            continue  # point clouds, paths: no surface
        name = str(geom_name)
        if name not in names:
            names.append(name)
        v = np.asarray(geom.vertices, dtype=np.float64)
        v = v @ np.asarray(transform, dtype=np.float64)[:3, :3].T + transform[:3, 3]
        chunks_v.append(v)
        chunks_f.append(np.asarray(geom.faces, dtype=np.int64) + offset)
        chunks_p.append(np.full(len(geom.faces), names.index(name), dtype=np.int32))
        offset += len(v)
    if not chunks_f:
        raise MeshError(f"mesh {source!r} has no triangles")
    nameless = Path(source).suffix.lower() in (".stl", ".ply", ".off")
    if len(names) == 1 and (nameless or names[0] in (stem, "geometry_0")):
        names = ["body"]  # formats without object names: one part
    return TriangleMesh(
        vertices_m=np.concatenate(chunks_v),
        faces=np.concatenate(chunks_f),
        face_part=np.concatenate(chunks_p),
        part_names=tuple(names),
        source=source,
    )


def load_body(path: str | Path) -> tuple[TriangleMesh, Facets]:
    """The mesh of a file and its facets, in the file's units, derived once per process.

    Cached by the file's path, size and modification time: render, dataset
    generation, the spin fit and the Blender job share one copy. A scene's
    ``scale`` is applied by its users (:meth:`TriangleMesh.scaled`,
    :meth:`Facets.scaled`; the facet model multiplies areas), so every size
    of one shape shares the mesh, its facets and its shadow table.
    """
    path = Path(path)  # a relative one depends on the working folder: not memoized
    path = _resolved(str(path)) if path.is_absolute() else path.resolve()
    try:
        st = path.stat()
    except OSError:
        raise MeshError(f"mesh file {str(path)!r} does not exist (check [object] mesh)") from None
    return _load_body(str(path), st.st_size, st.st_mtime_ns)


@functools.lru_cache(maxsize=64)
def _resolved(path: str) -> Path:
    """An absolute path resolved (once per name: a scene's body is asked for several
    times a curve, and resolving walks every folder of the path)."""
    return Path(path).resolve()


@functools.lru_cache(maxsize=16)
def _load_body(path: str, size: int, mtime_ns: int) -> tuple[TriangleMesh, Facets]:
    del size, mtime_ns  # part of the cache key only
    mesh = load_mesh(path)
    return mesh, facets_from_mesh(mesh)


# ---------------------------------------------------------------------------
# Facets

#: Triangles with area below this fraction of (bounding-box diagonal)² are degenerate.
DEGENERATE_AREA_FRACTION = 1e-12
#: Geometry further in front of a facet's plane than this (relative to the
#: bounding-box diagonal) can shadow it.
SHADOW_TOLERANCE = 1e-7


def facets_from_mesh(mesh: TriangleMesh, merge: bool = True) -> Facets:
    """Derive facets: mask degenerate triangles, merge coplanar ones, test convexity.

    Args:
        mesh: triangles with parts.
        merge: merge coplanar triangles of the same part into one facet. The
            unshadowed facet sum is unchanged (it is linear in area for a
            given normal and material); turn off to keep raw triangles.

    Returns:
        :class:`Facets`.

    Raises:
        MeshError: no triangle has a finite, non-zero area.

    Example:
        >>> from jaxlc.body.mesh import load_mesh, facets_from_mesh
        >>> f = facets_from_mesh(load_mesh("meshes/cubesat_3u.obj"))
        >>> f.n_triangles, f.n_facets, f.convex
        (12, 6, True)
    """
    v = mesh.vertices_m
    tri = v[mesh.faces]  # (M, 3, 3)
    finite = np.all(np.isfinite(tri), axis=(1, 2))
    tri = np.where(finite[:, None, None], tri, 0.0)
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    double_area = np.linalg.norm(cross, axis=1)
    good_v = v[np.all(np.isfinite(v), axis=1)]
    diag = float(np.linalg.norm(np.ptp(good_v, axis=0))) if len(good_v) else 0.0
    valid = finite & (0.5 * double_area > DEGENERATE_AREA_FRACTION * diag**2) & (diag > 0)
    n_masked = int(np.count_nonzero(~valid))
    if not np.any(valid):
        raise MeshError(
            f"mesh {mesh.source!r}: all {mesh.n_triangles} triangles are degenerate "
            "or non-finite; nothing to render"
        )
    if n_masked:
        warnings.warn(
            f"mesh {mesh.source!r}: masked out {n_masked} of {mesh.n_triangles} triangles "
            "that are degenerate (zero area) or have non-finite vertices",
            MeshWarning,
            stacklevel=2,
        )

    idx = np.flatnonzero(valid)
    normals = cross[idx] / double_area[idx, None]
    areas = 0.5 * double_area[idx]
    centroids = tri[idx].mean(axis=1)
    part = mesh.face_part[idx].astype(np.int32)

    if merge:
        group = coplanar_groups(normals, centroids, part, diag)
    else:
        group = np.arange(len(idx))
    n_f = int(group.max()) + 1
    f_area = np.bincount(group, weights=areas, minlength=n_f)
    f_normal = np.stack(
        [np.bincount(group, weights=areas * normals[:, k], minlength=n_f) for k in range(3)], 1
    )
    f_normal /= np.linalg.norm(f_normal, axis=1, keepdims=True)
    f_centroid = (
        np.stack(
            [np.bincount(group, weights=areas * centroids[:, k], minlength=n_f) for k in range(3)],
            1,
        )
        / f_area[:, None]
    )
    f_part = np.zeros(n_f, dtype=np.int32)
    f_part[group] = part

    used = np.zeros(len(v), dtype=bool)
    used[mesh.faces[idx]] = True
    can_shadow = _can_be_shadowed(f_normal, f_centroid, v[used], diag)

    triangle_facet = np.full(mesh.n_triangles, -1, dtype=np.int64)
    triangle_facet[idx] = group
    return Facets(
        normals=f_normal,
        areas_m2=f_area,
        centroids_m=f_centroid,
        part=f_part,
        can_shadow=can_shadow,
        triangle_facet=triangle_facet,
        part_names=mesh.part_names,
        n_triangles=mesh.n_triangles,
        n_masked=n_masked,
        source=mesh.source,
    )


def _can_be_shadowed(normals, centroids, vertices, diag) -> np.ndarray:
    """(F,) True where some vertex lies in front of the facet's plane
    (:func:`jaxlc.body.hull.support_heights`: O(F log V), not F × V)."""
    height = support_heights(vertices, normals) - np.einsum("ij,ij->i", normals, centroids)
    return height > SHADOW_TOLERANCE * diag
