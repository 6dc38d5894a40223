"""The octahedral direction grid: unit vectors ↔ an N × N square, and its nodes.

Directions over the whole sphere map onto [−1, 1]² by the octahedral map
(Praun & Hoppe 2003); the grid's nodes are the N × N cell centres. Shadow
tables (:mod:`jaxlc.body.shadow`) store one visibility bit per node and
interpolate between the nodes around a direction, across the map's seams too.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np


def octahedral_encode(d, xp=np):
    """Unit vectors (…, 3) → square coordinates (u, v) in [−1, 1]² (octahedral map)."""
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    scale = xp.abs(x) + xp.abs(y) + xp.abs(z)
    x, y, z = x / scale, y / scale, z / scale
    sign = lambda a: xp.where(a >= 0, 1.0, -1.0)  # noqa: E731  (sign(0) = +1)
    u = xp.where(z >= 0, x, (1.0 - xp.abs(y)) * sign(x))
    v = xp.where(z >= 0, y, (1.0 - xp.abs(x)) * sign(y))
    return u, v


def octahedral_decode(u, v) -> np.ndarray:
    """Square coordinates (u, v) in [−1, 1]² (arrays of one shape) → unit vectors (…, 3):
    the inverse of :func:`octahedral_encode`."""
    z = 1.0 - np.abs(u) - np.abs(v)
    x = np.where(z >= 0, u, (1.0 - np.abs(v)) * np.where(u >= 0, 1.0, -1.0))
    y = np.where(z >= 0, v, (1.0 - np.abs(u)) * np.where(v >= 0, 1.0, -1.0))
    d = np.stack([x, y, z], -1)
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def octahedral_directions(n: int) -> np.ndarray:
    """(n², 3) unit directions at the cell centres of the n × n octahedral grid;
    node (i, j) has index i·n + j."""
    c = -1.0 + (np.arange(n) + 0.5) * 2.0 / n
    u, v = np.meshgrid(c, c, indexing="ij")
    return octahedral_decode(u, v).reshape(-1, 3)


def wrap_nodes(i, j, n: int):
    """Node indices one step beyond the square's edges → the nodes they are on the sphere.

    The octahedral map folds the lower hemisphere onto the square's corners, so its
    edges are seams: the point (u, 1 + ε) is the direction at (−u, 1 − ε), and
    likewise at the other three edges. In grid indices a virtual node (i, n) is node
    (n − 1 − i, n − 1), (i, −1) is (n − 1 − i, 0), (n, j) is (n − 1, n − 1 − j) and
    (−1, j) is (0, n − 1 − j); applied in turn, a corner beyond both edges lands on the
    opposite corner (all four are next to the −z pole). Works for numpy and jax arrays.
    """
    flip_i = (i < 0) | (i > n - 1)
    i, j = (i.clip(0, n - 1), (n - 1 - j) * flip_i + j * ~flip_i)
    flip_j = (j < 0) | (j > n - 1)
    return (n - 1 - i) * flip_j + i * ~flip_j, j.clip(0, n - 1)


def grid_corners(d, n: int, interpolation: str):
    """Grid nodes and weights for directions d (T, 3): (idx (T, C), w (T, C)),
    C = 4 (bilinear), 3 (triangle: barycentric in the half of the grid cell that holds
    the direction) or 1 (nearest). Weights sum to 1.

    Cells that straddle the square's edges take their outer corners across the seam
    (:func:`wrap_nodes`), so the interpolation is continuous over the whole sphere: a
    direction crossing a seam of the lower hemisphere (z < 0, x = 0 or y = 0) moves
    smoothly between the nodes on either side, not in a jump of one grid cell.
    """
    u, v = octahedral_encode(d, xp=jnp)
    a = (u + 1.0) * (0.5 * n) - 0.5
    b = (v + 1.0) * (0.5 * n) - 0.5
    if interpolation == "nearest":
        i = jnp.clip(jnp.round(a), 0, n - 1).astype(jnp.int32)
        j = jnp.clip(jnp.round(b), 0, n - 1).astype(jnp.int32)
        return (i * n + j)[:, None], jnp.ones_like(a)[:, None]
    # a, b lie in [−½, n − ½]: the cell's corners in [−1, n], wrapped onto nodes.
    i0 = jnp.clip(jnp.floor(a), -1, n - 1)
    j0 = jnp.clip(jnp.floor(b), -1, n - 1)
    fa = jnp.clip(a - i0, 0.0, 1.0)
    fb = jnp.clip(b - j0, 0.0, 1.0)
    i0 = i0.astype(jnp.int32)
    j0 = j0.astype(jnp.int32)

    def node(di, dj):
        i, j = wrap_nodes(i0 + di, j0 + dj, n)
        return i * n + j

    if interpolation == "triangle":
        # Cell corners 00, 10, 01 and 11; the diagonal 10–01 splits it in two.
        upper = fa + fb > 1.0
        first = jnp.where(upper, node(1, 1), node(0, 0))
        idx = jnp.stack([first, node(1, 0), node(0, 1)], -1)
        w_first = jnp.where(upper, fa + fb - 1.0, 1.0 - fa - fb)
        w = jnp.stack([w_first, jnp.where(upper, 1.0 - fb, fa), jnp.where(upper, 1.0 - fa, fb)], -1)
        return idx, w
    idx = jnp.stack([node(0, 0), node(1, 0), node(0, 1), node(1, 1)], -1)
    w = jnp.stack([(1 - fa) * (1 - fb), fa * (1 - fb), (1 - fa) * fb, fa * fb], -1)
    return idx, w


def nearest_node(d, n: int, xp=np):
    """Index of the grid node nearest (in grid coordinates) to each direction (…, 3): the
    node of the grid cell that holds it (on a cell's edge, either neighbour's). Works for
    numpy (int64) and jax (int32) arrays."""
    u, v = octahedral_encode(d, xp=xp)
    index = xp.int64 if xp is np else xp.int32
    i = xp.clip(xp.round((u + 1.0) * (0.5 * n) - 0.5), 0, n - 1).astype(index)
    j = xp.clip(xp.round((v + 1.0) * (0.5 * n) - 0.5), 0, n - 1).astype(index)
    return i * n + j


def node_spacing_rad(n: int) -> float:
    """Largest angle (rad) between a node of the n × n grid and one of its 8 neighbours:
    how far the corners of an interpolated look-up can lie from its direction."""
    d = octahedral_directions(n).reshape(n, n, 3)
    cos = 1.0
    for (i, j), (k, m) in (((1, 0), (0, 0)), ((0, 1), (0, 0)), ((1, 1), (0, 0)), ((1, 0), (0, 1))):
        x = d[i : n - 1 + i, j : n - 1 + j]
        y = d[k : n - 1 + k, m : n - 1 + m]
        cos = min(cos, float(np.min(np.sum(x * y, axis=-1))))
    return float(np.arccos(np.clip(cos, -1.0, 1.0)))
