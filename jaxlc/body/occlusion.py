"""Which points see a direction: rays cast against a triangle mesh, binned in the plane.

For a direction d, a point x is occluded when the ray x + t d (t > 0) meets a
triangle deeper along d than x by more than ``eps``: its projection onto the
plane perpendicular to d lies inside the triangle's (2-D edge functions of
one sign) and the triangle's interpolated depth there exceeds x·d + eps.
That is the whole test; the rest only avoids testing pairs that cannot hit,
so that a direction costs O((P + M) log M) instead of P × M:

* triangles are binned on a uniform grid of the projection plane (cells about
  the size of a typical triangle; the few that span more than 2 × 2 cells
  are entered in every cell of their bounding box with a bound of their
  plane's depth over that cell);
* each cell's entries are sorted by that depth bound, highest first, so a
  point is tested only against the entries of its cell that reach above it —
  none at all on most of a lit surface.

Float32 throughout, like the rest of the shadow precomputation; the brute
force over every pair is the slow twin (``tests/test_shadow.py``).
"""

from __future__ import annotations

import numpy as np

#: Most (point, triangle) pairs tested at once (bounds the memory of a direction).
PAIR_BLOCK = 1 << 21


class Occluders:
    """Triangles ready to be cast against along many directions (float32 columns).

    Args:
        tris: (M, 3, 3) triangles (m), counter-clockwise seen from outside.
        cull_back: test only triangles facing against the ray (n·d < 0); right
            for a watertight mesh, where a ray leaving the surface can only
            hit the solid through such a triangle.
    """

    def __init__(self, tris: np.ndarray, cull_back: bool):
        t = np.asarray(tris, dtype=np.float64)
        self.triangles = t  # (M, 3, 3) as given, float64
        self.corners = [np.ascontiguousarray(t[:, k].T, dtype=np.float32) for k in range(3)]
        n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
        norm = np.linalg.norm(n, axis=1, keepdims=True)
        self.normals = (n / np.where(norm > 0, norm, 1.0)).astype(np.float32)
        self.cull_back = cull_back

    def occluded(
        self, points_t: np.ndarray, d: np.ndarray, eps: float, want: np.ndarray | None = None
    ) -> np.ndarray:
        """(P,) True where the ray from each point along ``d`` is blocked.

        Args:
            points_t: (3, P) float32 points (m), coordinates first.
            d: (3,) unit direction.
            eps: depth (m) a blocker must exceed the point by.
            want: (P,) which points to test (the others come back False).
        """
        n_p = points_t.shape[1]
        out = np.zeros(n_p, dtype=bool)
        want = np.ones(n_p, dtype=bool) if want is None else want
        basis = plane_basis(np.asarray(d, dtype=np.float64)).astype(np.float32)
        active = (
            np.flatnonzero(self.normals @ basis[2] < 0)
            if self.cull_back
            else np.arange(len(self.normals))
        )
        if active.size == 0 or not np.any(want):
            return out
        a, b, h = zip(*[basis @ c[:, active] for c in self.corners], strict=True)  # 3 × (M,)
        grid = _Grid(a, b, h)
        pa, pb, ph = basis @ points_t
        cell, ok = grid.cell_of(pa, pb)
        level = grid.level(ph + np.float32(eps))
        todo = np.flatnonzero(want & ok & (grid.top[cell] >= level))
        if todo.size == 0:
            return out
        first, count = grid.reaching(cell[todo], level[todo])
        ends = np.cumsum(count)
        splits = np.searchsorted(ends, np.arange(PAIR_BLOCK, ends[-1], PAIR_BLOCK))
        for sel in np.split(np.arange(len(todo)), splits):
            n = count[sel]
            p = np.repeat(todo[sel], n)
            t = grid.tri[np.repeat(first[sel] - (np.cumsum(n) - n), n) + np.arange(len(p))]
            hit = hits(pa[p], pb[p], ph[p] + np.float32(eps), a, b, h, t)
            out[p[hit]] = True
        return out


def hits(pa, pb, level, a, b, h, t=None, xp=np):
    """Whether point k (pa, pb) lies inside triangle t[k] (corner coordinates a, b,
    depths h: three (M,) arrays each) where its depth exceeds level[k].

    ``t`` None: every point against every triangle, by broadcasting (pa, pb, level
    (P, 1) against the (1, M) corners: (P, M)). ``xp``: numpy, or ``jax.numpy`` inside
    a traced function (:mod:`jaxlc.body.shadow_rays`)."""
    a0, a1, a2, b0, b1, b2 = (x if t is None else x[t] for x in (*a, *b))
    w0 = (b2 - b1) * (pa - a1) - (a2 - a1) * (pb - b1)  # edge functions: barycentric × 2·area
    w1 = (b0 - b2) * (pa - a2) - (a0 - a2) * (pb - b2)
    w2 = (b1 - b0) * (pa - a0) - (a1 - a0) * (pb - b0)
    total = w0 + w1 + w2
    inside = ((w0 >= 0) & (w1 >= 0) & (w2 >= 0)) | ((w0 <= 0) & (w1 <= 0) & (w2 <= 0))
    inside &= xp.abs(total) > 1e-30
    h0, h1, h2 = (x if t is None else x[t] for x in h)
    depth_x_total = w0 * h0 + w1 * h1 + w2 * h2
    return inside & xp.where(
        total > 0, depth_x_total > level * total, depth_x_total < level * total
    )


def plane_basis(d, xp=np):
    """(3, 3) rows e1, e2, d: two unit vectors spanning the plane perpendicular to d, and d
    (``xp``: numpy, or ``jax.numpy`` in a traced function)."""
    helper = xp.where(xp.abs(d[0]) < 0.9, xp.asarray([1.0, 0.0, 0.0]), xp.asarray([0.0, 1.0, 0.0]))
    e1 = xp.cross(d, helper)
    e1 = e1 / xp.linalg.norm(e1)
    return xp.stack([e1, xp.cross(d, e1), d])


class _Grid:
    """Projected triangles binned on a uniform grid, each cell's entries sorted by
    their depth bound (highest first), packed in one int64 key per entry:
    cell | (levels − quantised bound) | triangle."""

    def __init__(self, a, b, h):
        a_lo, a_hi = np.minimum(np.minimum(*a[:2]), a[2]), np.maximum(np.maximum(*a[:2]), a[2])
        b_lo, b_hi = np.minimum(np.minimum(*b[:2]), b[2]), np.maximum(np.maximum(*b[:2]), b[2])
        h_hi = np.maximum(np.maximum(*h[:2]), h[2])
        m = len(h_hi)
        self.lo = (float(a_lo.min()), float(b_lo.min()))
        span = (float(a_hi.max()) - self.lo[0], float(b_hi.max()) - self.lo[1])
        extent = np.maximum(a_hi - a_lo, b_hi - b_lo)
        self.size = max(
            np.sqrt(span[0] * span[1] / m), float(np.quantile(extent, 0.75)), max(span) / (m + 1)
        )
        self.size = max(self.size, 1e-30)
        while True:  # coarser cells while big triangles would fill too many
            self.side = (int(span[0] / self.size) + 1, int(span[1] / self.size) + 1)
            i0, j0 = self._index(a_lo, b_lo)
            i1, j1 = self._index(a_hi, b_hi)
            n_cells = (i1 - i0 + 1) * (j1 - j0 + 1)
            if n_cells.sum() <= 8 * m + 4096:
                break
            self.size *= 1.5
        cells, tris, bound = self._entries(a, b, h, h_hi, i0, j0, i1, j1, n_cells)

        n_grid = self.side[0] * self.side[1]
        self.bits_t = max(1, (m - 1).bit_length())
        self.bits_q = min(40, 63 - self.bits_t - max(1, (n_grid - 1).bit_length()))
        self.levels = (1 << self.bits_q) - 1
        if self.bits_q < 8:
            raise ValueError(f"occlusion grid: {m} triangles on {n_grid} cells do not fit a key")
        # float64 from here; the slack covers the float32 round-off of the hit test
        bound = bound.astype(np.float64)
        bound += 1e-6 * float(np.max(np.abs(bound)))
        self.h_lo = float(bound.min())
        self.step = max((float(bound.max()) - self.h_lo) / self.levels, 1e-300)
        q = self.levels - np.clip(np.ceil((bound - self.h_lo) / self.step), 0, self.levels)
        shift = self.bits_q + self.bits_t
        key = np.sort((cells << shift) | (q.astype(np.int64) << self.bits_t) | tris)
        self.key = key
        self.tri = key & ((1 << self.bits_t) - 1)
        counts = np.bincount(key >> (self.bits_q + self.bits_t), minlength=n_grid)
        self.start = np.cumsum(counts) - counts
        self.top = np.full(n_grid, -1, dtype=np.int64)  # highest level reached in each cell
        full = np.flatnonzero(counts)
        self.top[full] = self.levels - ((key[self.start[full]] >> self.bits_t) & self.levels)

    def _index(self, a, b):
        i = np.minimum(((a - self.lo[0]) / self.size).astype(np.int64), self.side[0] - 1)
        j = np.minimum(((b - self.lo[1]) / self.size).astype(np.int64), self.side[1] - 1)
        return i, j

    def _entries(self, a, b, h, h_hi, i0, j0, i1, j1, n_cells):
        """(cell, triangle, depth bound) of every entry."""
        wide, high = i1 - i0, j1 - j0
        small = (wide <= 1) & (high <= 1)  # 1, 2 or 4 cells: bounded by the highest corner
        base = i0 * self.side[1] + j0
        cells, tris, bound = [], [], []
        for di, dj, more in ((0, 0, True), (1, 0, wide == 1), (0, 1, high == 1), (1, 1, None)):
            sel = np.flatnonzero(small & ((wide == 1) & (high == 1) if more is None else more))
            cells.append(base[sel] + di * self.side[1] + dj)
            tris.append(sel)
            bound.append(h_hi[sel])
        big = np.flatnonzero(~small)
        if big.size:  # the cells it crosses, bounded by the plane's depth over each
            at, bt, ht = (np.stack([c[big] for c in x]).astype(np.float64) for x in (a, b, h))
            row, ci, cj = self._crossed(at, bt, i0[big], j0[big], i1[big], j1[big])
            area2 = (at[1] - at[0]) * (bt[2] - bt[0]) - (at[2] - at[0]) * (bt[1] - bt[0])
            flat = np.abs(area2) > 1e-12 * self.size**2  # not seen edge-on
            denom = np.where(flat, area2, 1.0)
            ga = ((ht[1] - ht[0]) * (bt[2] - bt[0]) - (ht[2] - ht[0]) * (bt[1] - bt[0])) / denom
            gb = ((at[1] - at[0]) * (ht[2] - ht[0]) - (at[2] - at[0]) * (ht[1] - ht[0])) / denom
            da = self.lo[0] + (ci + 0.5) * self.size - at[0][row]
            db = self.lo[1] + (cj + 0.5) * self.size - bt[0][row]
            slack = 0.5 * self.size * (np.abs(ga) + np.abs(gb))
            plane = ht[0][row] + ga[row] * da + gb[row] * db + slack[row]
            cells.append(ci * self.side[1] + cj)
            tris.append(big[row])
            bound.append(np.where(flat[row], np.minimum(plane, h_hi[big][row]), h_hi[big][row]))
        return np.concatenate(cells), np.concatenate(tris), np.concatenate(bound)

    def _crossed(self, a, b, i0, j0, i1, j1):
        """(triangle, cell column, cell row) of every cell that triangles (a, b: (3, N),
        float64) cross: per row of cells, the columns between the extremes of the
        triangle cut by that row's slab (its corners inside the slab and its
        edges' crossings of the slab's sides), widened by a rounding margin."""
        n = j1 - j0 + 1
        tri = np.repeat(np.arange(len(n)), n)
        cj = j0[tri] + np.arange(len(tri)) - np.repeat(np.cumsum(n) - n, n)
        margin = 1e-3 * self.size  # covers float32 rounding of the points' cells
        y0 = self.lo[1] + cj * self.size - margin
        y1 = y0 + self.size + 2 * margin
        lo, hi = np.full(len(tri), np.inf), np.full(len(tri), -np.inf)
        for k in range(3):
            ak, bk = a[k][tri], b[k][tri]
            inside = (bk >= y0) & (bk <= y1)
            lo, hi = (
                np.where(inside, np.minimum(lo, ak), lo),
                np.where(inside, np.maximum(hi, ak), hi),
            )
            aq, bq = a[(k + 1) % 3][tri], b[(k + 1) % 3][tri]
            step = np.where(bq != bk, bq - bk, 1.0)
            for y in (y0, y1):
                t = (y - bk) / step
                cut = (bq != bk) & (t >= 0) & (t <= 1)
                x = ak + t * (aq - ak)
                lo, hi = np.where(cut, np.minimum(lo, x), lo), np.where(cut, np.maximum(hi, x), hi)
        first = np.maximum(np.floor((lo - margin - self.lo[0]) / self.size), i0[tri])
        last = np.minimum(np.floor((hi + margin - self.lo[0]) / self.size), i1[tri])
        count = np.maximum(last - first + 1, 0).astype(np.int64)  # 0 where none is crossed
        first = np.where(count > 0, first, 0.0)
        entry = np.repeat(np.arange(len(tri)), count)
        ci = (
            first.astype(np.int64)[entry]
            + np.arange(len(entry))
            - np.repeat(np.cumsum(count) - count, count)
        )
        return tri[entry], ci, cj[entry]

    def cell_of(self, pa, pb):
        """(cell of each point, whether it lies on the grid)."""
        i = np.floor((pa - self.lo[0]) / self.size).astype(np.int64)
        j = np.floor((pb - self.lo[1]) / self.size).astype(np.int64)
        # a point a rounding error off the grid still meets the triangles of its edge
        ok = (i >= -1) & (i <= self.side[0]) & (j >= -1) & (j <= self.side[1])
        i, j = np.clip(i, 0, self.side[0] - 1), np.clip(j, 0, self.side[1] - 1)
        return i * self.side[1] + j, ok

    def level(self, depth):
        """Quantised depths, rounded down: an entry whose bound exceeds ``depth`` has a
        level at least this."""
        q = np.floor((depth.astype(np.float64) - self.h_lo) / self.step)
        return np.clip(q, -1, self.levels + 1).astype(np.int64)

    def reaching(self, cell, level):
        """(first entry, number of entries) of each cell whose bound reaches ``level``."""
        shift = self.bits_q + self.bits_t
        lowest = np.clip(self.levels - level, 0, self.levels)
        last = np.searchsorted(
            self.key, (cell << shift) | (lowest << self.bits_t) | ((1 << self.bits_t) - 1), "right"
        )
        first = self.start[cell]
        return first, last - first


def occluded(points: np.ndarray, tris: np.ndarray, d: np.ndarray, eps: float) -> np.ndarray:
    """(P,) True where the ray points + t·d (t > 0) hits one of tris (M, 3, 3), every
    triangle counted (no culling); see :class:`Occluders`."""
    return Occluders(tris, cull_back=False).occluded(
        np.ascontiguousarray(np.asarray(points).T, dtype=np.float32), d, eps
    )
