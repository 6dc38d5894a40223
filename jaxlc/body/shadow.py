"""Self-shadowing of non-convex objects, with no ray tracing at render time.

Method (precomputed sub-point visibility on a direction grid):

* Each facet that *can* be shadowed (``Facets.can_shadow``: geometry lies in
  front of its plane) gets sub-points, and for every direction of an
  octahedral grid one bit per sub-point says whether it sees that direction
  (:mod:`jaxlc.body.raycast`, traced once on the host). The bits are cached on disk
  (:func:`jaxlc.io.cache.cache_dir` ``("shadow")``), keyed by the mesh's
  content and the settings, and kept in memory for the rest of the process.
* At render time (:mod:`jaxlc.body.shadow_lookup`) the lit *and* seen fraction of facet f is
  Σ_ab w_a(s) w_b(v) popcount(B_f[a] & B_f[b]) / K over the grid corners a of the
  Sun direction s and b of the observer direction v (interpolation weights): the
  joint visibility of the same sub-points from both directions, not a product of
  two marginal fractions, so partly shadowed facets are represented.

Facets that cannot be shadowed get no data and no work; a convex object has none.

Size: a table holds grid² × sub-points bits, and tracing it costs about
grid² × (sub-points + 2 × triangles). Both are bounded (512 MB of bits,
:func:`subpoint_budget`; :data:`TRACE_BUDGET`). A large non-convex mesh first
gets a grid coarser than the default 64 × 64, down to 32 × 32; if that is not
enough (every facet gets 32 sub-points or more), fewer sub-points: small
facets get 1, 2, 4, 8 or 16 as their area asks (facets then share words), then
the spacing grows in steps of 2^¼; if that is not enough, a coarser grid. Each facet's
lit-and-seen fraction is then coarser (a facet with one sub-point is lit or
not, blended only by the grid interpolation) and shadow edges move in larger
angular steps; the plan line says so (:func:`reduced_resolution`). Meshes of
a few thousand triangles, the shipped ones included, are far below both.
"""

from __future__ import annotations

import dataclasses
import hashlib
import time
from pathlib import Path

import numpy as np

from jaxlc.body.mesh import Facets, TriangleMesh
from jaxlc.body.raycast import trace_visibility, word_layout
from jaxlc.errors import JaxlcError
from jaxlc.io.cache import cache_dir
from jaxlc.io.files import atomic_output
from jaxlc.memo import identity_memo, remember

#: Bump when the precomputation changes: cached tables of older versions are ignored.
ALGORITHM_VERSION = 5
#: Most sub-points of one table at a 32 × 32 grid (see the module docstring).
SUBPOINT_BUDGET = 1 << 22
#: Grid side that a finer grid asked for gives way to, before sub-points do.
COARSE_GRID = 32
#: Most directions × (sub-points + 2 × triangles) of one trace (its cost, measured:
#: ~0.5 µs each on the 2-core reference machine, so a few minutes at most;
#: ``experiments/big_mesh.py``).
TRACE_BUDGET = 1 << 29
#: Direction-grid interpolations (:func:`jaxlc.body.octahedral.grid_corners`).
INTERPOLATIONS = ("bilinear", "triangle", "nearest")
#: Sub-point counts below one word: facets with these share uint32 words.
SHARED_COUNTS = (1, 2, 4, 8, 16)


@dataclasses.dataclass(frozen=True)
class ShadowSettings:
    """Resolution of the shadow approximation.

    Attributes:
        grid: side N of the octahedral direction grid (N² directions; N = 32
            gives ~6° spacing, 64 ~3°). 64 bounds the tail: the 99th percentile
            of |Δm| against the exact twin at phase ≤ 160° is ≤ 0.05 on S4, S6, S7
            and S8 (``experiments/shadow_tail.py``; 0.053 on S4 at 32), at a look-up
            cost 4 % (S4) to ~19 % (S6) higher and a 4× longer trace (S4: 30 s
            once, then cached).
        spacing: target distance between sub-points as a fraction of the mesh's
            bounding-box diagonal; a facet of area A gets 32·⌈A / (32 (spacing·diag)²)⌉
            sub-points (at least 32, at most ``max_subpoints``).
        max_subpoints: cap per facet, a multiple of 32.
        interpolation: ``"triangle"`` (barycentric over 3 grid corners per direction:
            9 corner pairs per look-up), ``"bilinear"`` (4 corners, 16 pairs: as accurate,
            ~10 % slower on S4; ``experiments/shadow_tail.py``) or ``"nearest"`` (1, coarser).
    """

    grid: int = 64
    spacing: float = 0.005
    max_subpoints: int = 512
    interpolation: str = "triangle"

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
        if self.interpolation not in INTERPOLATIONS:
            raise JaxlcError(
                f"shadow interpolation = {self.interpolation!r} must be one of {INTERPOLATIONS}"
            )

    def words_per_facet(self, areas_m2: np.ndarray, diag_m: float) -> np.ndarray:
        """(F,) number of 32-point words for facets of these areas."""
        per_point = (self.spacing * diag_m) ** 2
        words = np.ceil(np.asarray(areas_m2) / (32.0 * per_point)).astype(int)
        return np.clip(words, 1, self.max_subpoints // 32)

    def subpoints_per_facet(
        self, areas_m2: np.ndarray, diag_m: float, budget: int = SUBPOINT_BUDGET
    ) -> tuple[np.ndarray, float]:
        """(F,) sub-points for facets of these areas, and the spacing used (× object size).

        32 × :meth:`words_per_facet` while the total is within ``budget``;
        otherwise counts by area are rounded up to 1, 2, 4, 8, 16 or a multiple of
        32 (no longer at least 32 a facet), at the spacing asked for and then at
        spacings larger by steps of 2^¼ until the total fits.
        """
        areas_m2 = np.asarray(areas_m2, dtype=np.float64)
        counts = 32 * self.words_per_facet(areas_m2, diag_m)
        if counts.sum() <= budget:
            return counts, self.spacing
        if len(areas_m2) > budget:
            raise JaxlcError(
                f"shadow table: {len(areas_m2):,} facets can be shadowed, more than the "
                f"budget of {budget:,} sub-points (render with shadows = 'off')"
            )
        shared = np.asarray(SHARED_COUNTS)
        spacing = self.spacing / 2.0**0.25  # first the spacing asked for, without the floor
        while True:
            spacing *= 2.0**0.25
            need = np.maximum(areas_m2 / (spacing * diag_m) ** 2, 1.0)
            small = shared[np.minimum(np.searchsorted(shared, need), len(shared) - 1)]
            counts = np.where(need <= shared[-1], small, 32 * np.ceil(need / 32.0))
            counts = np.minimum(counts, self.max_subpoints).astype(np.int64)
            if counts.sum() <= budget:
                return counts, float(spacing)


# ---------------------------------------------------------------------------
# Cache


def cache_key(
    mesh: TriangleMesh,
    facets: Facets,
    facet_ids: np.ndarray,
    counts: np.ndarray,
    settings: ShadowSettings,
) -> str:
    """Content hash of everything the table depends on."""
    h = hashlib.sha256()
    for arr in (mesh.vertices_m, mesh.faces, facets.triangle_facet, facet_ids, counts):
        a = np.ascontiguousarray(arr)
        h.update(str(a.dtype).encode() + str(a.shape).encode() + a.tobytes())
    h.update(repr((ALGORITHM_VERSION, settings.grid)).encode())
    return h.hexdigest()[:24]


@dataclasses.dataclass(frozen=True)
class ShadowData:
    """Packed visibility with its layout and provenance (host side).

    Attributes:
        bits: (D, words) uint32; facets are sorted by their number of
            sub-points and laid out by :func:`jaxlc.body.raycast.word_layout`
            (32 sub-points per word; counts below 32 share words).
        facet_ids: (F_s,) the facets that can be shadowed, in that order.
        counts: (F_s,) sub-points per facet.
        settings: the resolution used: the one asked for unless the budgets
            made the grid coarser (:func:`reduced_resolution`).
        seconds: time spent tracing (0 when loaded from the cache).
        from_cache: whether the table came from disk.
        path: the cache file, if any.
        key: content hash of everything the table depends on (:func:`cache_key`).
        spacing: the sub-point spacing used (× object size): ``settings.spacing``
            unless the budget made it coarser.
    """

    bits: np.ndarray
    facet_ids: np.ndarray
    counts: np.ndarray
    settings: ShadowSettings
    seconds: float
    from_cache: bool
    path: Path | None
    key: str = ""
    spacing: float = 0.0

    @property
    def nbytes(self) -> int:
        return int(self.bits.nbytes)

    @property
    def subpoints(self) -> int:
        return int(np.sum(self.counts))

    @property
    def groups(self) -> tuple[tuple[int, int], ...]:
        """((facets, sub-points per facet), …): runs of facets with equal counts."""
        first = np.flatnonzero(np.diff(self.counts, prepend=-1))
        size = np.diff(np.append(first, len(self.counts)))
        return tuple((int(n), int(self.counts[f])) for f, n in zip(first, size, strict=True))


#: Tables loaded or traced in this process, by (cache key, cache file, its stamp), and
#: how many a process keeps (of these and of their device copies,
#: :func:`jaxlc.body.shadow_lookup.shadow_table`).
_LOADED: dict[tuple, ShadowData] = {}
KEEP_TABLES = 8


def subpoint_budget(grid: int, total: int | None = None) -> int:
    """Most sub-points of a table at this grid side: ``total`` (default
    :data:`SUBPOINT_BUDGET`) at 32 × 32, the same number of bits (512 MB) at any grid."""
    return max(1, (SUBPOINT_BUDGET if total is None else total) * COARSE_GRID**2 // grid**2)


def _layout(mesh: TriangleMesh, facets: Facets, settings: ShadowSettings):
    """(facet ids sorted by count, sub-points per facet, settings used, spacing used, the
    table's :func:`cache_key`).

    The settings asked for, unless the table would pass its bit budget
    (:func:`subpoint_budget`) or its trace :data:`TRACE_BUDGET`: then first a
    grid coarser than asked, down to :data:`COARSE_GRID`, then fewer sub-points
    (not below one a facet, nor below the triangle count, under which the trace
    hardly gets cheaper), then a coarser grid still (not below 8 × 8).
    """
    return _budgeted_layout(mesh, facets, settings, SUBPOINT_BUDGET, TRACE_BUDGET)


@identity_memo()
def _budgeted_layout(mesh, facets, settings, subpoints: int, trace: int):
    """:func:`_layout` under these budgets (memoized: once per mesh, settings and budgets,
    the mesh hashed for the key once too)."""
    facet_ids = np.flatnonzero(facets.can_shadow)
    diag = mesh.diagonal_m
    areas = facets.areas_m2[facet_ids]
    n_tri = int(np.count_nonzero(facets.triangle_facet >= 0))
    full = 32 * int(settings.words_per_facet(areas, diag).sum())  # at the spacing asked for
    grid = settings.grid
    while grid > COARSE_GRID and (
        full > subpoint_budget(grid, subpoints) or grid**2 * (full + 2 * n_tri) > trace
    ):
        grid -= 1
    per_direction = trace // grid**2  # sub-points + 2 × triangles
    budget = subpoint_budget(grid, subpoints)
    if full + 2 * n_tri > per_direction:
        budget = min(budget, max(per_direction - 2 * n_tri, n_tri, len(facet_ids)))
    counts, spacing = settings.subpoints_per_facet(areas, diag, budget)
    while grid > 8 and grid**2 * (int(counts.sum()) + 2 * n_tri) > trace:
        grid -= 1
    order = np.argsort(counts, kind="stable")  # runs of equal counts
    facet_ids, counts = facet_ids[order], counts[order]
    used = dataclasses.replace(settings, grid=grid)
    return facet_ids, counts, used, spacing, cache_key(mesh, facets, facet_ids, counts, used)


@identity_memo()
def table_order(facets: Facets, facet_ids: np.ndarray) -> Facets:
    """The facets that a table covers (``facet_ids``, in its order), then the others: the
    order of a shadowed object's facet model (once per table and process, not per curve)."""
    return facets.subset(np.concatenate([facet_ids, np.flatnonzero(~facets.can_shadow)]))


def reduced_resolution(mesh: TriangleMesh, facets: Facets, settings: ShadowSettings) -> str:
    """The plan line's note on a table: empty when it gets the resolution asked for,
    else how much coarser the budgets made it."""
    _, counts, used, spacing, _ = _layout(mesh, facets, settings)
    if counts.min() >= 32 and spacing == settings.spacing and used.grid == settings.grid:
        return ""
    lo, hi = int(counts.min()), int(counts.max())
    return (
        f"; REDUCED for a mesh this large: {used.grid}×{used.grid} grid, "
        f"{int(counts.sum()):,} sub-points ({lo if lo == hi else f'{lo}–{hi}'} per "
        f"facet, every {spacing:.3g} × object size), so coarser shadow edges"
    )


def shadow_data(
    mesh: TriangleMesh,
    facets: Facets,
    settings: ShadowSettings | None = None,
    use_cache: bool = True,
    progress=None,
) -> ShadowData | None:
    """The visibility table of the facets that can be shadowed (None if there are none).

    Kept in memory for the process, loaded from the disk cache when the mesh,
    facets and settings are unchanged, traced (and cached, atomically) otherwise.
    ``use_cache=False`` always traces and stores nothing.
    """
    settings = settings or ShadowSettings()
    if not np.any(facets.can_shadow):
        return None
    facet_ids, counts, settings, spacing, key = _layout(mesh, facets, settings)
    path = cache_dir("shadow") / f"{key}.npz"
    memo = (key, str(path), _stamp(path))
    if use_cache and memo in _LOADED:
        # the bits do not depend on the interpolation: it is this call's
        return dataclasses.replace(_LOADED[memo], from_cache=True, seconds=0.0, settings=settings)
    data = _load(path, key, facet_ids, counts, settings, spacing) if use_cache else None
    if data is None:
        t0 = time.perf_counter()
        bits = trace_visibility(mesh, facets, facet_ids, counts, settings.grid, progress)
        seconds = time.perf_counter() - t0
        stored = None
        if use_cache:
            try:
                with atomic_output(path) as tmp:
                    np.savez_compressed(tmp, bits=bits)
                stored = path
            except OSError:
                pass  # read-only home: work without a disk cache
        data = ShadowData(bits, facet_ids, counts, settings, seconds, False, stored, key, spacing)
    if use_cache:
        remember(_LOADED, (key, str(path), _stamp(path)), data, KEEP_TABLES)
    return data


def _stamp(path: Path):
    """The cache file's size and modification time (None if absent): a memory copy
    is used only while the file it came from is unchanged."""
    try:
        st = path.stat()
    except OSError:
        return None
    return st.st_size, st.st_mtime_ns


def _load(path: Path, key: str, facet_ids, counts, settings, spacing) -> ShadowData | None:
    """The cached table at ``path``, or None if it is missing, unreadable or stale."""
    if not path.is_file():
        return None
    try:
        with np.load(path) as z:
            bits = z["bits"]
    except (OSError, ValueError, KeyError):
        return None  # unreadable cache entry: recompute and replace it
    if bits.shape != (settings.grid**2, word_layout(counts)[1]):
        return None
    return ShadowData(bits, facet_ids, counts, settings, 0.0, True, path, key, spacing)
