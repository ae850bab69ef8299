"""Measures of a deformed surface that share nothing with Tegument's solver.

Used by the tests, the demo and the benchmarks to compare skinning, Corrective Smooth and
Pyramid Deform on the same frames. Plain numpy on the mesh's own arrays, plus Blender's
``mathutils.bvhtree`` for triangle overlaps; nothing here imports ``tegument``.

- :func:`spike_measure`: per vertex, how much further it stands from the mean of its one-ring
  than at rest, over the mean rest length of its ring edges. Smooth deformation keeps it near 0;
  a spike or a tear shows as a large value.
- :func:`coincident_groups` and :func:`seam_gap`: vertices that coincide at rest (split seams of
  glTF, FBX and USD imports) and how far apart they end up.
- :func:`self_intersection_pairs` (and their count, :func:`self_intersections`): pairs of faces
  that intersect although they share no vertex (vertices coincident at rest count as shared, so a
  closed split seam is not an intersection). BVHTree splits each quad along one diagonal of its
  choosing; :func:`split_self_intersection_pairs` counts under each of Blender's own quad methods
  and :func:`any_split_self_intersection_pairs` under every split of every quad at once.
- :func:`convergence_error` and :func:`worst_moving`: issue 28's convergence error of a solve
  against the same solve run to a standstill, and its worst over the frames of a pose that move.
"""

from __future__ import annotations

import numpy as np


def polygon_edges(corner_verts: np.ndarray, polygon_sizes: np.ndarray) -> np.ndarray:
    """``(E, 2)`` unique undirected edges (smaller index first) of the polygons."""
    corner_verts = np.asarray(corner_verts, dtype=np.int64)
    sizes = np.asarray(polygon_sizes, dtype=np.int64)
    starts = np.concatenate(([0], np.cumsum(sizes)[:-1]))
    following = np.arange(len(corner_verts)) + 1
    ends = np.repeat(starts + sizes, sizes)
    following[following == ends] = np.repeat(starts, sizes)[following == ends]
    pairs = np.stack([corner_verts, corner_verts[following]], axis=1)
    pairs.sort(axis=1)
    return np.unique(pairs[pairs[:, 0] != pairs[:, 1]], axis=0)


def _ring_means(positions: np.ndarray, edges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    n = len(positions)
    sums = np.zeros((n, 3))
    counts = np.zeros(n)
    for a, b in ((0, 1), (1, 0)):
        np.add.at(sums, edges[:, a], positions[edges[:, b]])
        np.add.at(counts, edges[:, a], 1.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return sums / counts[:, None], counts


def spike_measure(positions: np.ndarray, rest: np.ndarray, corner_verts: np.ndarray, polygon_sizes: np.ndarray) -> np.ndarray:
    """Per vertex: (|x − mean of its ring| now − the same at rest) ÷ mean rest length of its ring
    edges; 0 for vertices without edges. Non-finite positions give non-finite values."""
    positions = np.asarray(positions, dtype=np.float64)
    rest = np.asarray(rest, dtype=np.float64)
    edges = polygon_edges(corner_verts, polygon_sizes)
    now, counts = _ring_means(positions, edges)
    then, _ = _ring_means(rest, edges)
    lengths = np.linalg.norm(rest[edges[:, 0]] - rest[edges[:, 1]], axis=1)
    ring_length = np.zeros(len(rest))
    for column in (0, 1):
        np.add.at(ring_length, edges[:, column], lengths)
    has_ring = counts > 0
    out = np.zeros(len(rest))
    growth = np.linalg.norm(positions - now, axis=1) - np.linalg.norm(rest - then, axis=1)
    out[has_ring] = growth[has_ring] / (ring_length[has_ring] / counts[has_ring])
    return out


def mesh_size(rest: np.ndarray) -> float:
    """The diagonal of the rest positions' bounding box."""
    rest = np.asarray(rest, dtype=np.float64)
    return float(np.linalg.norm(rest.max(axis=0) - rest.min(axis=0))) if len(rest) else 0.0


def coincident_groups(rest: np.ndarray, tolerance: float = 1e-6) -> np.ndarray:
    """Per vertex, the smallest index of the vertices it coincides with at rest (itself where
    none does): split seams map to one representative. Vertices closer than half of
    ``tolerance`` × the mesh size along every axis are always joined, never ones further apart
    than ``tolerance`` × the mesh size along an axis."""
    rest = np.asarray(rest, dtype=np.float64)
    label = np.arange(len(rest))
    if len(rest) < 2:
        return label
    cell = tolerance * max(mesh_size(rest), 1e-30)
    # Two vertices closer than half a cell along an axis share a cell along it in the grid
    # either unshifted or shifted by half a cell: the 8 shifted grids cover every such pair.
    for shift in np.array(np.meshgrid([0.0, 0.5], [0.0, 0.5], [0.0, 0.5])).reshape(3, -1).T:
        keys = np.floor(rest / cell + shift).astype(np.int64)
        _, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
        inverse = inverse.ravel()
        joined = np.flatnonzero(first[inverse] != np.arange(len(rest)))
        for i, j in zip(joined, first[inverse[joined]]):
            a, b = _root(label, int(i)), _root(label, int(j))
            label[max(a, b)] = min(a, b)
    return np.array([_root(label, i) for i in range(len(rest))])


def _root(label: np.ndarray, i: int) -> int:
    """Union-find root with path halving."""
    while label[i] != i:
        label[i] = label[label[i]]
        i = label[i]
    return int(i)


def seam_gap(positions: np.ndarray, groups: np.ndarray) -> float:
    """The largest distance between a vertex and its group's representative (0 without seams)."""
    positions = np.asarray(positions, dtype=np.float64)
    split = groups != np.arange(len(groups))
    if not split.any():
        return 0.0
    return float(np.linalg.norm(positions[split] - positions[groups[split]], axis=1).max())


def self_intersection_pairs(positions: np.ndarray, corner_verts: np.ndarray, polygon_sizes: np.ndarray,
                            groups: np.ndarray | None = None) -> set[tuple[int, int]]:
    """Pairs ``(i, j)``, ``i < j``, of polygons that intersect and share no vertex (``groups``, e.g.
    from :func:`coincident_groups`, makes vertices coincident at rest count as shared, so a closed
    split seam is not an intersection).

    Blender's ``BVHTree.overlap`` of the mesh with itself decides intersection.
    """
    from mathutils.bvhtree import BVHTree

    corner_verts = np.asarray(corner_verts, dtype=np.int64)
    sizes = np.asarray(polygon_sizes, dtype=np.int64)
    starts = np.concatenate(([0], np.cumsum(sizes)[:-1]))
    polygons = [corner_verts[s:s + k].tolist() for s, k in zip(starts, sizes)]
    tree = BVHTree.FromPolygons(np.asarray(positions, dtype=np.float64).tolist(), polygons, all_triangles=False, epsilon=0.0)
    shared_id = np.asarray(groups if groups is not None else np.arange(int(corner_verts.max(initial=-1)) + 1))
    sets = [frozenset(shared_id[p].tolist()) for p in polygons]
    return {(i, j) for i, j in tree.overlap(tree) if i < j and not (sets[i] & sets[j])}


#: The ways Blender's own triangulation (``bmesh.ops.triangulate``, the Triangulate modifier) may
#: split a quad; FIXED and ALTERNATE are its two diagonals.
QUAD_METHODS = ("BEAUTY", "FIXED", "ALTERNATE", "SHORT_EDGE", "LONG_EDGE")


def _overlapping_polygons(positions, triangles, polygon_of, polygons, groups) -> set[tuple[int, int]]:
    """Pairs of source polygons (sharing no vertex) two of whose ``triangles`` overlap by Blender's BVHTree."""
    from mathutils.bvhtree import BVHTree

    tree = BVHTree.FromPolygons(np.asarray(positions, dtype=np.float64).tolist(), triangles, all_triangles=True, epsilon=0.0)
    shared_id = np.asarray(groups if groups is not None else np.arange(len(positions)))
    sets = [frozenset(shared_id[p].tolist()) for p in polygons]
    found = set()
    for i, j in tree.overlap(tree):
        a, b = sorted((polygon_of[i], polygon_of[j]))
        if a != b and not (sets[a] & sets[b]):
            found.add((a, b))
    return found


def _polygons(corner_verts, polygon_sizes):
    corner_verts = np.asarray(corner_verts, dtype=np.int64)
    sizes = np.asarray(polygon_sizes, dtype=np.int64)
    starts = np.concatenate(([0], np.cumsum(sizes)[:-1]))
    return [corner_verts[s:s + k].tolist() for s, k in zip(starts, sizes)]


def split_self_intersection_pairs(positions: np.ndarray, corner_verts: np.ndarray, polygon_sizes: np.ndarray,
                                  quad_method: str, groups: np.ndarray | None = None) -> set[tuple[int, int]]:
    """:func:`self_intersection_pairs` of the mesh as Blender's ``bmesh.ops.triangulate`` splits it
    with ``quad_method`` (one of :data:`QUAD_METHODS`; ngons by BEAUTY), pairs of source polygons."""
    import bmesh

    polygons = _polygons(corner_verts, polygon_sizes)
    bm = bmesh.new()
    verts = [bm.verts.new(p) for p in np.asarray(positions, dtype=np.float64).tolist()]
    source = bm.faces.layers.int.new("tegument_polygon")
    for i, p in enumerate(polygons):
        face = bm.faces.new([verts[v] for v in p])
        face[source] = i
    bmesh.ops.triangulate(bm, faces=bm.faces[:], quad_method=quad_method, ngon_method="BEAUTY")
    bm.verts.index_update()
    triangles = [[v.index for v in f.verts] for f in bm.faces]
    polygon_of = [f[source] for f in bm.faces]
    bm.free()
    return _overlapping_polygons(positions, triangles, polygon_of, polygons, groups)


def any_split_self_intersection_pairs(positions: np.ndarray, corner_verts: np.ndarray, polygon_sizes: np.ndarray,
                                      groups: np.ndarray | None = None) -> set[tuple[int, int]]:
    """Pairs of polygons that intersect under *some* split of their quads, each quad split its own
    way: every quad stands for the four triangles of its two splits (``abc acd abd bcd``), other
    polygons for their fan, and Blender's BVHTree decides. A superset of
    :func:`split_self_intersection_pairs` for every quad method, and of what any renderer draws."""
    polygons = _polygons(corner_verts, polygon_sizes)
    triangles, polygon_of = [], []
    for i, p in enumerate(polygons):
        if len(p) == 4:
            a, b, c, d = p
            split = [[a, b, c], [a, c, d], [a, b, d], [b, c, d]]
        else:
            split = [[p[0], p[k], p[k + 1]] for k in range(1, len(p) - 1)]
        triangles.extend(split)
        polygon_of.extend([i] * len(split))
    return _overlapping_polygons(positions, triangles, polygon_of, polygons, groups)


def self_intersections(positions: np.ndarray, corner_verts: np.ndarray, polygon_sizes: np.ndarray,
                       groups: np.ndarray | None = None) -> int:
    """How many :func:`self_intersection_pairs` there are."""
    return len(self_intersection_pairs(positions, corner_verts, polygon_sizes, groups))


# ------------------------------------------------------------------------- convergence (issue 28)

def convergence_error(result: np.ndarray, converged: np.ndarray, source: np.ndarray) -> tuple[float, float]:
    """``(error, displacement)``: issue 28's convergence error RMS |x − x_inf| / RMS |x_inf − input|
    of ``result`` against the converged solve ``converged`` of the input ``source`` (0 where the
    solve does not move the input), and that RMS displacement."""
    def rms(a, b):
        return float(np.sqrt(((np.asarray(a, np.float64) - b) ** 2).sum(axis=1).mean()))

    displacement = rms(converged, source)
    return (rms(result, converged) / displacement if displacement > 0 else 0.0), displacement


def worst_moving(errors: list[float], displacements: list[float], fraction: float = 0.1) -> float:
    """The worst error over the frames whose displacement is at least ``fraction`` of the last
    frame's: the first frames of a pose barely move, and their error is a ratio of two tiny numbers."""
    moving = [e for e, d in zip(errors, displacements) if d >= fraction * displacements[-1]]
    return max(moving)
