"""Self-shadowing of non-convex objects, with no ray tracing at render time.

Method (precomputed sub-point visibility on a direction grid):

* Each facet that *can* be shadowed (``Facets.can_shadow``: geometry lies in
  front of its plane) gets K = 32·W sub-points, spread over its triangles in
  proportion to area (stratified, deterministic).
* For every direction d of an octahedral grid (N² directions over the sphere)
  and every sub-point x, one bit says whether the ray x + t d escapes the mesh.
  Rays are cast once, in JAX, with 2-D edge functions and interpolated depth
  after projecting along d; only facets with n·d > 0 are traced, and for a
  watertight mesh only triangles with n_T·d < 0 (a ray leaving the surface can
  only hit the solid through a triangle facing it). The bits are packed into
  uint32 words and cached on disk, keyed by the mesh's content and the settings.
* At render time the lit *and* seen fraction of facet f is
  Σ_ab w_a(s) w_b(v) popcount(B_f[a] & B_f[b]) / K over the grid corners a of the
  Sun direction s and b of the observer direction v (bilinear weights): the
  joint visibility of the same sub-points from both directions, not a product of
  two marginal fractions, so partly shadowed facets are represented.

Facets that cannot be shadowed get no data and no work; a convex object has no
shadow table at all (identical to the unshadowed model).
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
import time
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, UInt32

from jaxlc.errors import JaxlcError
from jaxlc.files import atomic_output
from jaxlc.mesh import Facets, TriangleMesh

#: Bump when the precomputation changes: cached tables of older versions are ignored.
ALGORITHM_VERSION = 3


@dataclasses.dataclass(frozen=True)
class ShadowSettings:
    """Resolution of the shadow approximation.

    Attributes:
        grid: side N of the octahedral direction grid (N² directions; N = 32
            gives ~6° spacing, 64 ~3°).
        spacing: target distance between sub-points as a fraction of the mesh's
            bounding-box diagonal; a facet of area A gets 32·⌈A / (32 (spacing·diag)²)⌉
            sub-points (at least 32, at most ``max_subpoints``).
        max_subpoints: cap per facet, a multiple of 32.
        interpolation: ``"bilinear"`` over the 4 grid corners of each direction,
            or ``"nearest"`` (one corner: faster, coarser).
    """

    grid: int = 32
    spacing: float = 0.005
    max_subpoints: int = 512
    interpolation: str = "bilinear"

    def __post_init__(self):
        if not (isinstance(self.grid, int) and 4 <= self.grid <= 512):
            raise JaxlcError(f"shadow grid = {self.grid!r} must be an integer in [4, 512]")
        if not (isinstance(self.spacing, int | float) and 1e-4 <= self.spacing <= 1.0):
            raise JaxlcError(
                f"shadow spacing = {self.spacing!r} must be in [1e-4, 1] (× mesh size)"
            )
        ok = isinstance(self.max_subpoints, int) and self.max_subpoints % 32 == 0
        if not (ok and 32 <= self.max_subpoints <= 4096):
            raise JaxlcError(
                f"shadow max_subpoints = {self.max_subpoints!r} must be 32, 64, … 4096"
            )
        if self.interpolation not in ("bilinear", "nearest"):
            raise JaxlcError(
                f"shadow interpolation = {self.interpolation!r} must be 'bilinear' or 'nearest'"
            )

    def words_per_facet(self, areas_m2: np.ndarray, diag_m: float) -> np.ndarray:
        """(F,) number of 32-point words for facets of these areas."""
        per_point = (self.spacing * diag_m) ** 2
        words = np.ceil(np.asarray(areas_m2) / (32.0 * per_point)).astype(int)
        return np.clip(words, 1, self.max_subpoints // 32)


# ---------------------------------------------------------------------------
# Octahedral direction grid


def octahedral_encode(d, xp=np):
    """Unit vectors (…, 3) → square coordinates (u, v) in [−1, 1]² (octahedral map)."""
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    scale = xp.abs(x) + xp.abs(y) + xp.abs(z)
    x, y, z = x / scale, y / scale, z / scale
    sign = lambda a: xp.where(a >= 0, 1.0, -1.0)  # noqa: E731  (sign(0) = +1)
    u = xp.where(z >= 0, x, (1.0 - xp.abs(y)) * sign(x))
    v = xp.where(z >= 0, y, (1.0 - xp.abs(x)) * sign(y))
    return u, v


def octahedral_directions(n: int) -> np.ndarray:
    """(n², 3) unit directions at the cell centres of the n × n octahedral grid;
    node (i, j) has index i·n + j."""
    c = -1.0 + (np.arange(n) + 0.5) * 2.0 / n
    u, v = np.meshgrid(c, c, indexing="ij")
    z = 1.0 - np.abs(u) - np.abs(v)
    x = np.where(z >= 0, u, (1.0 - np.abs(v)) * np.where(u >= 0, 1.0, -1.0))
    y = np.where(z >= 0, v, (1.0 - np.abs(u)) * np.where(v >= 0, 1.0, -1.0))
    d = np.stack([x, y, z], -1).reshape(-1, 3)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def grid_corners(d, n: int, interpolation: str = "bilinear"):
    """Grid nodes and weights for directions d (T, 3): (idx (T, C), w (T, C)),
    C = 4 (bilinear) or 1 (nearest). Weights sum to 1."""
    u, v = octahedral_encode(d, xp=jnp)
    a = (u + 1.0) * (0.5 * n) - 0.5
    b = (v + 1.0) * (0.5 * n) - 0.5
    if interpolation == "nearest":
        i = jnp.clip(jnp.round(a), 0, n - 1).astype(jnp.int32)
        j = jnp.clip(jnp.round(b), 0, n - 1).astype(jnp.int32)
        return (i * n + j)[:, None], jnp.ones_like(a)[:, None]
    i0 = jnp.clip(jnp.floor(a), 0, n - 2)
    j0 = jnp.clip(jnp.floor(b), 0, n - 2)
    fa = jnp.clip(a - i0, 0.0, 1.0)
    fb = jnp.clip(b - j0, 0.0, 1.0)
    i0 = i0.astype(jnp.int32)
    j0 = j0.astype(jnp.int32)
    idx = jnp.stack([i0 * n + j0, (i0 + 1) * n + j0, i0 * n + j0 + 1, (i0 + 1) * n + j0 + 1], -1)
    w = jnp.stack([(1 - fa) * (1 - fb), fa * (1 - fb), (1 - fa) * fb, fa * fb], -1)
    return idx, w


# ---------------------------------------------------------------------------
# Sub-points


def sub_points(
    mesh: TriangleMesh, facets: Facets, facet_ids: np.ndarray, counts: np.ndarray
) -> list[np.ndarray]:
    """Per facet, ``counts[i]`` points (k, 3) spread over its triangles by area.

    Each triangle gets its share (largest remainder); inside a triangle the
    points follow a 2-D Halton sequence folded into the triangle, so the
    placement is stratified and reproducible.
    """
    tri = mesh.vertices_m[mesh.faces]
    out = []
    for f, k in zip(facet_ids, counts, strict=True):
        t = tri[facets.triangle_facet == f]
        area = 0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1)
        share = k * area / area.sum()
        count = np.floor(share).astype(int)
        rest = np.argsort(-(share - count))[: k - count.sum()]
        count[rest] += 1
        pts = []
        for tt, c in zip(t, count, strict=True):
            if c:
                r1, r2 = _halton(c, 2), _halton(c, 3)
                fold = r1 + r2 > 1  # fold the unit square onto the triangle
                r1, r2 = np.where(fold, 1 - r1, r1), np.where(fold, 1 - r2, r2)
                pts.append(tt[0] + r1[:, None] * (tt[1] - tt[0]) + r2[:, None] * (tt[2] - tt[0]))
        out.append(np.concatenate(pts))
    return out


def _halton(n: int, base: int) -> np.ndarray:
    i = np.arange(1, n + 1)
    f, r = np.ones(n), np.zeros(n)
    while np.any(i > 0):
        f = f / base
        r = r + f * (i % base)
        i = i // base
    return r


# ---------------------------------------------------------------------------
# Precomputation: ray casting on the grid


def _occluded(points, tris, d, eps):
    """(P,) True where the ray points + t·d (t > 0) hits one of tris (M, 3, 3)."""
    helper = jnp.where(jnp.abs(d[0]) < 0.9, jnp.array([1.0, 0.0, 0.0]), jnp.array([0.0, 1.0, 0.0]))
    e1 = jnp.cross(d, helper.astype(d.dtype))
    e1 = e1 / jnp.linalg.norm(e1)
    e2 = jnp.cross(d, e1)
    pa, pb, ph = points @ e1, points @ e2, points @ d
    ta, tb, th = tris @ e1, tris @ e2, tris @ d  # (M, 3)

    def edge(i, j):  # edge function of the edge i → j at every point, (P, M)
        return (tb[:, j] - tb[:, i])[None, :] * (pa[:, None] - ta[:, i][None, :]) - (
            ta[:, j] - ta[:, i]
        )[None, :] * (pb[:, None] - tb[:, i][None, :])

    w0, w1, w2 = edge(1, 2), edge(2, 0), edge(0, 1)  # barycentric weights × 2·area
    total = w0 + w1 + w2
    inside = ((w0 >= 0) & (w1 >= 0) & (w2 >= 0)) | ((w0 <= 0) & (w1 <= 0) & (w2 <= 0))
    inside = inside & (jnp.abs(total) > 1e-30)
    depth = (w0 * th[None, :, 0] + w1 * th[None, :, 1] + w2 * th[None, :, 2]) / jnp.where(
        inside, total, 1.0
    )
    return jnp.any(inside & (depth > ph[:, None] + eps), axis=1)


@jax.jit
def _occluded_batch(points, tris, dirs, eps):
    """(B, P) occlusion for a batch of directions with their own points and triangles."""
    return jax.lax.map(lambda a: _occluded(a[0], a[1], a[2], eps), (points, tris, dirs))


def _is_watertight(mesh: TriangleMesh) -> bool:
    import trimesh

    tm = trimesh.Trimesh(mesh.vertices_m, mesh.faces, process=False)
    tm.merge_vertices(digits_vertex=6)
    return bool(tm.is_watertight)


def nearest_node(d: np.ndarray, n: int) -> np.ndarray:
    """Index of the grid node nearest (in grid coordinates) to each direction (…, 3)."""
    u, v = octahedral_encode(d)
    i = np.clip(np.round((u + 1.0) * (0.5 * n) - 0.5), 0, n - 1).astype(np.int64)
    j = np.clip(np.round((v + 1.0) * (0.5 * n) - 0.5), 0, n - 1).astype(np.int64)
    return i * n + j


def trace_visibility(
    mesh: TriangleMesh,
    facets: Facets,
    facet_ids: np.ndarray,
    words: np.ndarray,
    settings: ShadowSettings,
    progress=None,
) -> np.ndarray:
    """Packed visibility (D, Σ words) uint32 of the sub-points of ``facet_ids``.

    Facet ``facet_ids[i]`` owns ``words[i]`` consecutive words (32 sub-points
    each). Directions below a facet's plane take the bits of their mirror image
    above it, so that interpolating near grazing does not mix in zeros (those
    directions never light or show the facet, so nothing else changes).
    """
    from jaxlc.render import compiler_options

    dirs = octahedral_directions(settings.grid)
    n_dir = len(dirs)
    valid = facets.triangle_facet >= 0
    tri = mesh.vertices_m[mesh.faces][valid]
    tri_normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    tri_normal /= np.linalg.norm(tri_normal, axis=1, keepdims=True)
    diag = float(np.linalg.norm(np.ptp(mesh.vertices_m, axis=0)))
    normals = facets.normals[facet_ids]
    counts = 32 * np.asarray(words)
    owner = np.repeat(np.arange(len(facet_ids)), counts)  # facet row of each sub-point
    pts = np.concatenate(sub_points(mesh, facets, facet_ids, counts))
    pts = pts + 1e-5 * diag * normals[owner]  # lift off the surface
    cull_back = _is_watertight(mesh)

    facing = dirs @ normals.T > 1e-9  # (D, F_s): directions above each facet
    p_pad = max(32, int((facing @ counts).max()))
    tri_ok = (dirs @ tri_normal.T < 0) if cull_back else np.ones((n_dir, len(tri)), bool)
    m_pad = max(1, int(tri_ok.sum(1).max()))

    packed = np.zeros((n_dir, int(np.sum(words))), np.uint32)
    batch = 16
    kernel = jax.jit(_occluded_batch.__wrapped__, compiler_options=compiler_options())
    eps = np.float32(1e-6 * diag)
    for start in range(0, n_dir, batch):
        ids = list(range(start, min(start + batch, n_dir)))
        p_blk = np.zeros((batch, p_pad, 3), np.float32)
        t_blk = np.zeros((batch, m_pad, 3, 3), np.float32)  # zero triangles: never hit
        d_blk = np.tile(np.array([0.0, 0.0, 1.0], np.float32), (batch, 1))
        chosen = []
        for b, j in enumerate(ids):
            sel = np.flatnonzero(facing[j][owner])
            t = tri[tri_ok[j]]
            p_blk[b, : len(sel)] = pts[sel]
            t_blk[b, : len(t)] = t
            d_blk[b] = dirs[j]
            chosen.append(sel)
        occ = np.asarray(kernel(jnp.asarray(p_blk), jnp.asarray(t_blk), jnp.asarray(d_blk), eps))
        for b, (j, sel) in enumerate(zip(ids, chosen, strict=True)):
            seen = np.zeros(len(pts), bool)
            seen[sel] = ~occ[b, : len(sel)]
            packed[j] = pack_bits(seen.reshape(-1, 32)).ravel()
        if progress is not None:
            progress(ids[-1] + 1, n_dir)

    # Below each facet's horizon: the bits of the mirror direction above it.
    first_word = np.concatenate([[0], np.cumsum(words)[:-1]])
    for row, nrm in enumerate(normals):
        below = ~facing[:, row]
        if not below.any():
            continue
        d = dirs[below]
        mirror = nearest_node(d - 2.0 * (d @ nrm)[:, None] * nrm, settings.grid)
        cols = slice(first_word[row], first_word[row] + words[row])
        packed[below, cols] = packed[mirror, cols]
    return packed


def pack_bits(visible: np.ndarray) -> np.ndarray:
    """(…, 32) bool → (…, 1) uint32; element b is bit b."""
    bits = visible.astype(np.uint64) << np.arange(32, dtype=np.uint64)
    return bits.sum(-1, keepdims=True).astype(np.uint32)


# ---------------------------------------------------------------------------
# Cache


def cache_dir() -> Path:
    """``$JAXLC_CACHE_DIR`` or ``~/.cache/jaxlc``."""
    return Path(os.environ.get("JAXLC_CACHE_DIR", Path.home() / ".cache" / "jaxlc"))


def cache_key(
    mesh: TriangleMesh,
    facets: Facets,
    facet_ids: np.ndarray,
    words: np.ndarray,
    settings: ShadowSettings,
) -> str:
    """Content hash of everything the table depends on."""
    h = hashlib.sha256()
    for arr in (mesh.vertices_m, mesh.faces, facets.triangle_facet, facet_ids, words):
        a = np.ascontiguousarray(arr)
        h.update(str(a.dtype).encode() + str(a.shape).encode() + a.tobytes())
    h.update(repr((ALGORITHM_VERSION, settings.grid)).encode())
    return h.hexdigest()[:24]


@dataclasses.dataclass(frozen=True)
class ShadowData:
    """Packed visibility with its layout and provenance (host side).

    Attributes:
        bits: (D, Σ words) uint32; facets are sorted by their number of words
            and each owns its words consecutively (32 sub-points per word).
        facet_ids: (F_s,) the facets that can be shadowed, in that order.
        words: (F_s,) words per facet.
        settings: the resolution used.
        seconds: time spent tracing (0 when loaded from the cache).
        from_cache: whether the table came from disk.
        path: the cache file, if any.
    """

    bits: np.ndarray
    facet_ids: np.ndarray
    words: np.ndarray
    settings: ShadowSettings
    seconds: float
    from_cache: bool
    path: Path | None

    @property
    def nbytes(self) -> int:
        return int(self.bits.nbytes)

    @property
    def subpoints(self) -> int:
        return int(32 * np.sum(self.words))

    @property
    def groups(self) -> tuple[tuple[int, int], ...]:
        """((facets, words per facet), …): runs of facets with equal word counts."""
        values, counts = np.unique(self.words, return_counts=True)
        return tuple((int(c), int(v)) for v, c in zip(values, counts, strict=True))


def shadow_data(
    mesh: TriangleMesh,
    facets: Facets,
    settings: ShadowSettings | None = None,
    use_cache: bool = True,
    progress=None,
) -> ShadowData | None:
    """The visibility table of the facets that can be shadowed (None if there are none).

    Loaded from the cache when the mesh, facets and settings are unchanged;
    traced (and cached, atomically) otherwise.
    """
    settings = settings or ShadowSettings()
    facet_ids = np.flatnonzero(facets.can_shadow)
    if facet_ids.size == 0:
        return None
    diag = float(np.linalg.norm(np.ptp(mesh.vertices_m, axis=0)))
    words = settings.words_per_facet(facets.areas_m2[facet_ids], diag)
    order = np.argsort(words, kind="stable")  # runs of equal word counts
    facet_ids, words = facet_ids[order], words[order]
    key = cache_key(mesh, facets, facet_ids, words, settings)
    path = cache_dir() / "shadow" / f"{key}.npz"
    if use_cache and path.is_file():
        try:
            with np.load(path) as z:
                bits = z["bits"]
            if bits.shape == (settings.grid**2, int(words.sum())):
                return ShadowData(bits, facet_ids, words, settings, 0.0, True, path)
        except (OSError, ValueError, KeyError):
            pass  # unreadable cache entry: recompute and replace it
    t0 = time.perf_counter()
    bits = trace_visibility(mesh, facets, facet_ids, words, settings, progress)
    seconds = time.perf_counter() - t0
    if use_cache:
        try:
            with atomic_output(path) as tmp:
                np.savez_compressed(tmp, bits=bits)
        except OSError:
            path = None  # read-only home: work without a cache
    return ShadowData(bits, facet_ids, words, settings, seconds, False, path if use_cache else None)


# ---------------------------------------------------------------------------
# Render time


class ShadowTable(eqx.Module):
    """Packed visibility bits of the facets that can be shadowed (traced input).

    Attributes:
        bits: (D, Σ words) uint32 (see :class:`ShadowData`); bit b of a word says
            whether that sub-point sees the grid direction of the row.
        subpoints: (F_s,) sub-points per facet.
        groups: ((facets, words per facet), …) runs of the word layout.
        grid: octahedral grid side N (D = N²).
        interpolation: ``"bilinear"`` or ``"nearest"``.
    """

    bits: UInt32[Array, "D W"]
    subpoints: Float[Array, " F"]
    groups: tuple[tuple[int, int], ...] = eqx.field(static=True)
    grid: int = eqx.field(static=True)
    interpolation: str = eqx.field(static=True)


def lit_seen_fraction(
    table: ShadowTable, sun_b: Float[Array, "T 3"], obs_b: Float[Array, "T 3"]
) -> Float[Array, "T F"]:
    """Fraction of each shadowable facet both lit and seen, (T, F_s) in [0, 1]."""
    idx_s, w_s = grid_corners(sun_b, table.grid, table.interpolation)
    idx_v, w_v = grid_corners(obs_b, table.grid, table.interpolation)
    dtype = sun_b.dtype
    c = idx_s.shape[1]
    rows = table.bits[jnp.concatenate([idx_s, idx_v], axis=1)]  # one gather: (T, 2C, W)
    count = 0.0
    for a in range(c):
        for b in range(c):
            both = jax.lax.population_count(rows[:, a] & rows[:, c + b]).astype(dtype)
            count = count + (w_s[:, a] * w_v[:, b])[:, None] * both
    parts, start = [], 0
    for n_facets, words in table.groups:  # sum each facet's words: a static reshape
        block = count[:, start : start + n_facets * words]
        parts.append(block if words == 1 else block.reshape(-1, n_facets, words).sum(-1))
        start += n_facets * words
    per_facet = parts[0] if len(parts) == 1 else jnp.concatenate(parts, axis=1)
    return per_facet / table.subpoints.astype(dtype)[None, :]


def shadow_table(data: ShadowData, dtype=jnp.float32) -> ShadowTable:
    return ShadowTable(
        bits=jnp.asarray(data.bits),
        subpoints=jnp.asarray(32.0 * data.words, dtype=dtype),
        groups=data.groups,
        grid=data.settings.grid,
        interpolation=data.settings.interpolation,
    )
