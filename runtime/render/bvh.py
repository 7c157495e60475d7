"""A binned-SAH bounding volume hierarchy over the scene's primitives, built in numpy, for
the ray traversal written in rdsl (stdlib/render/bvh.rdsl; ``--accel bvh``).

The build is top-down and level-synchronous: every node of one depth is split at once with
array operations, so a 100k-triangle mesh builds in about a second without a Python loop
per node.  Each node of ``count > leaf_size`` primitives is split along the axis and at the
bin boundary (``bins`` equal bins of its centroids' extent per axis) of least surface area
heuristic cost; a node whose centroids coincide is split at its middle primitive.  Every
leaf therefore holds at most ``leaf_size`` primitives.

The tree is laid out in depth-first order with an escape index per node, the layout of a
stackless "threaded" traversal: after a node whose box the ray meets comes the next node in
order (its first child, or for a leaf the next subtree), after one it misses comes its
escape (the node after its subtree).  Traversal is then one plain loop with no stack, which
every backend can express.  :func:`scene_bvh` flattens it into the two buffers the kernels
read, ``BV`` (floats) and ``BI`` (ints), documented in stdlib/render/bvh.rdsl.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from ...compiler.diagnostics import CompileError

NODE_FLOATS = 8  # BV: lower corner, upper corner, 2 unused
NODE_INTS = 4  # BI: escape, first primitive slot, primitive count (0: inner), unused
PRIM_INTS = 2  # BI: global triangle index (-1 for an analytic shape), shape (geometry id)
TRI_FLOATS = 9  # BV: v0, v1 - v0, v2 - v0 of a triangle slot (zeros for an analytic one)
HEADER = 4  # BI[0]: node count, BI[1]: first prim slot's offset, BI[2]: BV's triangle offset
# a uniform cubic B-spline segment's control points to the Bezier ones of the same curve
BSPLINE_TO_BEZIER = np.array([[1, 4, 1, 0], [0, 4, 2, 0], [0, 2, 4, 0], [0, 1, 4, 1]]) / 6


@dataclass
class Bvh:
    """A BVH in depth-first order: node ``i``'s box ``lo[i]..hi[i]``, its escape
    ``skip[i]``, and for a leaf (``count[i] > 0``) the primitives
    ``prims[first[i]:first[i] + count[i]]`` (indices into the builder's input)."""

    lo: np.ndarray
    hi: np.ndarray
    skip: np.ndarray
    first: np.ndarray
    count: np.ndarray
    prims: np.ndarray
    build_seconds: float = 0.0

    @property
    def nodes(self) -> int:
        return len(self.skip)


def _areas(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Half the surface area of boxes (the SAH only compares them); 0 for empty ones."""
    e = np.maximum(hi - lo, 0.0)
    return e[..., 0] * e[..., 1] + e[..., 1] * e[..., 2] + e[..., 2] * e[..., 0]


def _bin_bounds(key: np.ndarray, lo: np.ndarray, hi: np.ndarray, n: int
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Count and box of each of ``n`` groups of primitives, by group ``key``."""
    counts = np.bincount(key, minlength=n)
    blo = np.full((n, 3), np.inf)
    bhi = np.full((n, 3), -np.inf)
    order = np.argsort(key, kind="stable")
    groups = np.flatnonzero(counts)
    starts = np.concatenate([[0], np.cumsum(counts[groups])[:-1]])
    blo[groups] = np.minimum.reduceat(lo[order], starts)
    bhi[groups] = np.maximum.reduceat(hi[order], starts)
    return counts, blo, bhi


def _best_splits(c: np.ndarray, lo: np.ndarray, hi: np.ndarray, seg: np.ndarray,
                 starts: np.ndarray, nn: int, bins: int
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """For each of ``nn`` nodes (primitives grouped by ``seg``): the best axis, the last bin
    on its left, the split's SAH cost, and each primitive's bin along the best axis."""
    cmin = np.minimum.reduceat(c, starts)
    cmax = np.maximum.reduceat(c, starts)
    ext = cmax - cmin
    scale = np.where(ext > 0, bins / np.where(ext > 0, ext, 1.0), 0.0)
    prim_bins = np.clip(((c - cmin[seg]) * scale[seg]).astype(np.int64), 0, bins - 1)
    best_cost = np.full(nn, np.inf)
    best_axis = np.zeros(nn, np.int64)
    best_bin = np.zeros(nn, np.int64)
    for axis in range(3):
        counts, blo, bhi = _bin_bounds(seg * bins + prim_bins[:, axis], lo, hi, nn * bins)
        counts, blo, bhi = counts.reshape(nn, bins), blo.reshape(nn, bins, 3), \
            bhi.reshape(nn, bins, 3)
        nl = np.cumsum(counts, axis=1)[:, :-1]
        nr = np.cumsum(counts[:, ::-1], axis=1)[:, ::-1][:, 1:]
        al = _areas(np.minimum.accumulate(blo, axis=1), np.maximum.accumulate(bhi, axis=1))
        ar = _areas(np.minimum.accumulate(blo[:, ::-1], axis=1)[:, ::-1],
                    np.maximum.accumulate(bhi[:, ::-1], axis=1)[:, ::-1])
        cost = np.where((nl > 0) & (nr > 0), nl * al[:, :-1] + nr * ar[:, 1:], np.inf)
        k = np.argmin(cost, axis=1)
        ck = cost[np.arange(nn), k]
        better = ck < best_cost
        best_cost[better], best_axis[better], best_bin[better] = ck[better], axis, k[better]
    return best_axis, best_bin, best_cost, prim_bins


def _layout(left: np.ndarray, right: np.ndarray, parent_levels: list[np.ndarray]
            ) -> tuple[np.ndarray, np.ndarray]:
    """Depth-first index and subtree size of each node (built breadth first)."""
    n = len(left)
    size = np.ones(n, np.int64)
    for nodes in reversed(parent_levels):  # children's sizes are final before parents'
        inner = nodes[left[nodes] >= 0]
        size[inner] = 1 + size[left[inner]] + size[right[inner]]
    pre = np.zeros(n, np.int64)
    for nodes in parent_levels:
        inner = nodes[left[nodes] >= 0]
        pre[left[inner]] = pre[inner] + 1
        pre[right[inner]] = pre[inner] + 1 + size[left[inner]]
    return pre, size


# long: one level-synchronous loop; splitting it would pass a dozen arrays around
def build_bvh(lo: Any, hi: Any, leaf_size: int = 4, bins: int = 16) -> Bvh:
    """The binned-SAH BVH over primitives with boxes ``lo[i]..hi[i]`` (arrays (N, 3))."""
    if leaf_size < 1 or bins < 2:
        raise ValueError(f"BVH: leaf_size must be >= 1 and bins >= 2, got {leaf_size}, {bins}")
    t0 = time.perf_counter()
    lo, hi = np.asarray(lo, np.float64).reshape(-1, 3), np.asarray(hi, np.float64).reshape(-1, 3)
    n = len(lo)
    if n == 0:
        z = np.zeros(0, np.int32)
        return Bvh(np.zeros((0, 3), np.float32), np.zeros((0, 3), np.float32), z, z, z, z)
    cen = 0.5 * (lo + hi)
    order = np.arange(n)
    # nodes (breadth first): range start and count in `order`, children (-1: a leaf)
    m = 2 * n - 1
    start, count = np.zeros(m, np.int64), np.zeros(m, np.int64)
    left, right = np.full(m, -1), np.full(m, -1)
    box_lo, box_hi = np.empty((m, 3)), np.empty((m, 3))
    count[0], box_lo[0], box_hi[0] = n, lo.min(axis=0), hi.max(axis=0)
    nn = 1
    active = np.array([0]) if n > leaf_size else np.zeros(0, np.int64)  # nodes to split
    levels: list[np.ndarray] = []
    while len(active):
        levels.append(active)
        st, ct = start[active], count[active]
        seg = np.repeat(np.arange(len(active)), ct)
        starts = np.r_[0, np.cumsum(ct)[:-1]]
        pos = (st - starts)[seg] + np.arange(len(seg))  # the active nodes' slots in `order`
        prims = order[pos]
        axis, split, _, pbins = _best_splits(cen[prims], lo[prims], hi[prims], seg, starts,
                                             len(active), bins)
        right_side = pbins[np.arange(len(pos)), axis[seg]] > split[seg]
        nright = np.bincount(seg, weights=right_side, minlength=len(active)).astype(np.int64)
        degenerate = (nright == 0) | (nright == ct)  # coinciding centroids: split the middle
        rank = np.arange(len(pos)) - starts[seg]
        right_side = np.where(degenerate[seg], rank >= ct[seg] // 2, right_side)
        nright = np.where(degenerate, ct - ct // 2, nright)
        prims = prims[np.argsort(seg * 2 + right_side, kind="stable")]
        order[pos] = prims
        nleft = ct - nright
        bounds = np.c_[starts, starts + nleft].reshape(-1)
        kids = np.arange(nn, nn + 2 * len(active))
        left[active], right[active] = kids[0::2], kids[1::2]
        start[kids] = np.c_[st, st + nleft].reshape(-1)
        count[kids] = np.c_[nleft, nright].reshape(-1)
        box_lo[kids] = np.minimum.reduceat(lo[prims], bounds)
        box_hi[kids] = np.maximum.reduceat(hi[prims], bounds)
        nn += len(kids)
        active = kids[count[kids] > leaf_size]
    start, count, left, right = start[:nn], count[:nn], left[:nn], right[:nn]
    box_lo, box_hi = box_lo[:nn], box_hi[:nn]
    pre, size = _layout(left, right, levels)
    out_lo, out_hi = np.empty((nn, 3), np.float32), np.empty((nn, 3), np.float32)
    # round outwards, so that the float32 boxes still contain the primitives
    out_lo[pre] = np.nextafter(box_lo.astype(np.float32), np.float32(-np.inf))
    out_hi[pre] = np.nextafter(box_hi.astype(np.float32), np.float32(np.inf))
    leaf = left < 0
    first, cnt = np.zeros(nn, np.int32), np.zeros(nn, np.int32)
    first[pre[leaf]] = start[leaf]
    cnt[pre[leaf]] = count[leaf]
    skip = np.empty(nn, np.int32)
    skip[pre] = pre + size
    return Bvh(out_lo, out_hi, skip, first, cnt, order.astype(np.int32),
               time.perf_counter() - t0)


def _curve_segments(bufs: Any, s: int) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                 np.ndarray]:
    """Shape ``s``'s curve segments (geometry.rdsl's layout of their entries in F): their
    boxes (their control points' grown by the largest radius among them, as Embree's; a
    B-spline's Bezier control points, whose hull holds the segment alone),
    their slot entry -2 - (offset in P of the first control point) and slot data
    (stdlib/render/bvh.rdsl)."""
    base = int(bufs.G.reshape(-1, 4)[s, 0])
    nseg = int(bufs.F[base])
    if nseg >= 2**24:  # the slot data holds the index as a float
        raise CompileError(f"the rdsl BVH (--accel bvh) takes curves of at most {2**24 - 1:,} "
                           f"segments, got {nseg:,}; render with Embree (--accel embree)", None)
    o = bufs.F[base + 2:base + 2 + nseg].astype(np.int64)
    span = 4 if bufs.G.reshape(-1, 4)[s, 3] & 128 else 2  # B-spline or linear
    q = bufs.P[o[:, None] + np.arange(4 * span)].astype(np.float64).reshape(-1, span, 4)
    if span == 4:  # the same curve's Bezier control points: a tighter hull
        q = np.einsum("ij,sjk->sik", BSPLINE_TO_BEZIER, q)
    r = q[:, :, 3].max(axis=1, keepdims=True)
    data = np.zeros((nseg, 3))
    data[:, 0] = np.arange(nseg)
    if span == 2:  # whether the previous segment ends where this one starts, and the next
        data[1:, 1] = o[:-1] + 4 == o[1:]
        data[:-1, 2] = o[1:] == o[:-1] + 4
    return q[:, :, :3].min(axis=1) - r, q[:, :, :3].max(axis=1) + r, -2 - o, data


def _record_box(P: np.ndarray, o: int, flags: int) -> tuple[np.ndarray, np.ndarray]:
    """The box of the sphere, SDF grid or disk of record ``o`` in P."""
    if flags & 4:  # a sphere: center and radius
        c, r = P[o + 24:o + 27], P[o + 27]
        return c - r, c + r
    rows = P[o:o + 12].reshape(3, 4)
    if flags & 32:  # an SDF grid: the unit cube's image under to_world's rows
        corners = np.array([[(k >> a) & 1 for a in range(3)] for k in range(8)], float)
        world = corners @ rows[:, :3].T + rows[:, 3]
        return world.min(axis=0), world.max(axis=0)
    half = np.hypot(rows[:, 0], rows[:, 1])  # a disk: the unit disk's image
    return rows[:, 3] - half, rows[:, 3] + half


def _primitives(bufs: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                                    np.ndarray]:
    """The scene's primitives: their boxes (lo, hi), their global triangle index (-1 for an
    analytic shape, -2 - offset for a curve segment), their shape and their slot data (3
    floats; zero but for curve segments), triangles first, from the flattened buffers."""
    G = bufs.G.reshape(-1, 4)
    tris, shapes, los, his = [], [], [], []
    records, curves = [], []
    for s, mesh in enumerate(bufs.meshes):
        if isinstance(mesh, tuple):
            tris.append(np.arange(G[s, 0], G[s, 0] + len(mesh[1])))
            shapes.append(np.full(len(mesh[1]), s))
        elif G[s, 3] & 192:
            curves.append(s)
        else:
            records.append(s)
    tri = np.concatenate(tris) if tris else np.zeros(0, np.int64)
    shape = np.concatenate(shapes) if shapes else np.zeros(0, np.int64)
    if len(tri):
        corners = bufs.P.reshape(-1)[(3 * bufs.F.reshape(-1, 3)[tri])[..., None]
                                     + np.arange(3)].astype(np.float64)  # (T, 3, 3)
        los.append(corners.min(axis=1))
        his.append(corners.max(axis=1))
    P = bufs.P.astype(np.float64)
    for s in records:
        lo, hi = _record_box(P, int(G[s, 0]), int(G[s, 3]))
        los.append(lo[None])
        his.append(hi[None])
    datas = [np.zeros((len(tri) + len(records), 3))]
    tri = np.r_[tri, np.full(len(records), -1)]
    shape = np.r_[shape, np.array(records, np.int64)]
    for s in curves:
        lo, hi, entry, data = _curve_segments(bufs, s)
        los.append(lo)
        his.append(hi)
        tri, shape = np.r_[tri, entry], np.r_[shape, np.full(len(entry), s)]
        datas.append(data)
    data = np.concatenate(datas)
    if not los:
        return np.zeros((0, 3)), np.zeros((0, 3)), tri, shape, data
    return np.concatenate(los), np.concatenate(his), tri, shape, data


def flatten_bvh(bvh: Bvh, tri: np.ndarray, shape: np.ndarray, P: np.ndarray, F: np.ndarray,
                data: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``BV`` and ``BI`` (stdlib/render/bvh.rdsl's layout) of a BVH over primitives of
    global triangle index ``tri`` (-1: analytic, -2 - offset: a curve segment), shape
    ``shape`` and, for the others than triangles, slot data ``data`` (N, 3)."""
    n, m = bvh.nodes, len(bvh.prims)
    bi = np.zeros(HEADER + NODE_INTS * n + PRIM_INTS * m + 1, np.int32)
    bi[0], bi[1], bi[2] = n, HEADER + NODE_INTS * n, NODE_FLOATS * n
    nodes = bi[HEADER:HEADER + NODE_INTS * n].reshape(n, NODE_INTS)
    nodes[:, 0], nodes[:, 1], nodes[:, 2] = bvh.skip, bvh.first, bvh.count
    slots = bi[HEADER + NODE_INTS * n:HEADER + NODE_INTS * n + PRIM_INTS * m].reshape(m, 2)
    slots[:, 0], slots[:, 1] = tri[bvh.prims], shape[bvh.prims]
    bv = np.zeros(NODE_FLOATS * n + TRI_FLOATS * m + 1, np.float32)
    boxes = bv[:NODE_FLOATS * n].reshape(n, NODE_FLOATS)
    boxes[:, 0:3], boxes[:, 3:6] = bvh.lo, bvh.hi
    t = tri[bvh.prims]
    is_tri = t >= 0
    slot = bv[NODE_FLOATS * n:NODE_FLOATS * n + TRI_FLOATS * m].reshape(m, TRI_FLOATS)
    if is_tri.any():
        idx = F.reshape(-1, 3)[t[is_tri]]
        v = P.reshape(-1)[3 * idx[..., None] + np.arange(3)]  # (k, 3, 3), float32
        slot[is_tri] = np.concatenate([v[:, 0], v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]], axis=1)
    if data is not None and m:
        slot[~is_tri, :3] = data[bvh.prims][~is_tri]
    return bv, bi


def scene_bvh(bufs: Any, leaf_size: int = 4, bins: int = 16) -> tuple[np.ndarray, np.ndarray,
                                                                      Bvh]:
    """The BVH over a scene's flattened buffers (runtime/render/renderer.py's
    ``SceneBuffers``): ``BV``, ``BI`` and the tree."""
    lo, hi, tri, shape, data = _primitives(bufs)
    bvh = build_bvh(lo, hi, leaf_size, bins)
    bv, bi = flatten_bvh(bvh, tri, shape, bufs.P, bufs.F, data)
    return bv, bi, bvh


__all__ = ["Bvh", "build_bvh", "flatten_bvh", "scene_bvh"]
