"""An independent penetration checker for the tests: numpy only.

The product audits its own bakes (``tegument.audit``), but that audit shares
its triangulation, edge lists, BVH and predicates with the solver: a bug there
would blind the solver and its audit at once. The tests therefore judge
"no penetration" with this module, which imports neither ``tegument`` nor
Blender and shares no code with ``rust/``. Everything it needs it derives
itself: triangles fanned from the polygons, edges from the triangles, the
inside test by generalized winding number, crossings by exact orientation
signs in float64.

Conventions (what counts as a penetration):

* A skin **vertex** penetrates a *closed* collider when it is strictly inside
  the collider's triangle surface (winding number above one half) and farther
  than ``tolerance`` from that surface. The collider's thickness is a margin
  the solver keeps, not part of the collider: skin resting at thickness
  distance, or touching the surface within ``tolerance``, is contact, not
  penetration. Open colliders have no inside; only crossings are checked.
* An **edge crosses** a triangle when its two ends lie strictly on opposite
  sides of the triangle's plane and the line between them passes through the
  closed triangle: a segment through a triangle's edge or corner crosses (on
  a closed surface that is a way through it), a segment ending on the plane or
  lying in it does not (that is touching).
* Edges are those of the fanned triangles, diagonals included: two triangle
  surfaces interpenetrate exactly when an edge of one crosses a triangle of
  the other, so both directions are checked (skin edges through collider
  triangles, collider edges through skin triangles).
* A polygon ``(v0, v1, …, vk)`` is fanned from its first corner:
  ``(v0, v1, v2), (v0, v2, v3), …``, as Blender's own quads are usually read.
"""

from __future__ import annotations

import dataclasses
import pathlib

import numpy as np

# Memory bound of the vectorised passes: pairs (or point × triangle terms) per chunk.
_CHUNK = 1 << 20


# --- Topology ------------------------------------------------------------------------------------


def fan_triangles(corner_verts, polygon_sizes) -> np.ndarray:
    """``(T, 3)`` int64 triangles of polygons in Blender's layout, fanned from each first corner."""
    corner_verts = np.asarray(corner_verts, dtype=np.int64).ravel()
    sizes = np.asarray(polygon_sizes, dtype=np.int64).ravel()
    if (sizes < 3).any() or sizes.sum() != len(corner_verts):
        raise ValueError("polygon sizes must be ≥ 3 and add up to the number of corners")
    starts = np.concatenate(([0], np.cumsum(sizes)[:-1]))
    count = sizes - 2
    polygon = np.repeat(np.arange(len(sizes)), count)
    k = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)  # fan index in its polygon
    first = starts[polygon]
    return np.stack([corner_verts[first], corner_verts[first + k + 1], corner_verts[first + k + 2]], axis=1)


def triangle_edges(triangles) -> np.ndarray:
    """``(E, 2)`` unique edges ``(min, max)`` of triangles, degenerate ones left out."""
    t = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    edges = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])
    edges = np.sort(edges, axis=1)
    edges = edges[edges[:, 0] != edges[:, 1]]
    return np.unique(edges, axis=0)


def is_closed(triangles) -> bool:
    """True when every edge of the triangles is shared by exactly two of them (a closed surface)."""
    t = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    if len(t) == 0:
        return False
    edges = np.sort(np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    return bool((counts == 2).all())


# --- Broad phase ---------------------------------------------------------------------------------


def _boxes(points: np.ndarray, elements: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    corners = points[elements]  # (n, k, 3)
    return corners.min(axis=1), corners.max(axis=1)


def overlapping_pairs(a_min, a_max, b_min, b_max, margin: float = 0.0):
    """Index pairs ``(i, j)`` whose boxes ``a[i]`` and ``b[j]`` overlap (grown by ``margin``).

    Sort and sweep on the axis along which the ``b`` boxes spread most, then the full box test;
    yields the pairs in chunks to bound memory.
    """
    if len(a_min) == 0 or len(b_min) == 0:
        return
    axis = int(np.argmax(b_max.max(axis=0) - b_min.min(axis=0)))
    order = np.argsort(b_min[:, axis], kind="stable")
    sorted_low = b_min[order, axis]
    widest = float((b_max[:, axis] - b_min[:, axis]).max())
    # Candidates of a[i]: the b whose low end lies in [a.low - widest - margin, a.high + margin].
    lo = np.searchsorted(sorted_low, a_min[:, axis] - widest - margin, side="left")
    hi = np.searchsorted(sorted_low, a_max[:, axis] + margin, side="right")
    counts = hi - lo
    step = max(1, _CHUNK)
    start = 0
    n = len(a_min)
    while start < n:
        # Take as many a boxes as keep this chunk's candidate count under the bound.
        cumulative = np.cumsum(counts[start:])
        stop = start + max(1, int(np.searchsorted(cumulative, step, side="right")))
        c = counts[start:stop]
        total = int(c.sum())
        if total:
            i = np.repeat(np.arange(start, stop), c)
            offsets = np.arange(total) - np.repeat(np.cumsum(c) - c, c)
            j = order[np.repeat(lo[start:stop], c) + offsets]
            keep = ((a_min[i] <= b_max[j] + margin) & (b_min[j] <= a_max[i] + margin)).all(axis=1)
            if keep.any():
                yield i[keep], j[keep]
        start = stop


# --- Predicates ----------------------------------------------------------------------------------


def _orient(a, b, c, d) -> np.ndarray:
    """Signed volume (×6) of tetrahedra ``(a, b, c, d)``, row by row."""
    return np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a)


def segments_cross_triangles(p, q, a, b, c) -> np.ndarray:
    """Row-wise: does segment ``p→q`` cross triangle ``(a, b, c)``? (the module's convention)."""
    p, q, a, b, c = (np.asarray(x, dtype=np.float64).reshape(-1, 3) for x in (p, q, a, b, c))
    side_p = _orient(a, b, c, p)
    side_q = _orient(a, b, c, q)
    opposite = ((side_p > 0) & (side_q < 0)) | ((side_p < 0) & (side_q > 0))
    # The line p→q against the triangle's three edges: all of one sign (zeros allowed,
    # on an edge or a corner) means it passes through the closed triangle.
    u = _orient(p, q, a, b)
    v = _orient(p, q, b, c)
    w = _orient(p, q, c, a)
    through = ((u >= 0) & (v >= 0) & (w >= 0)) | ((u <= 0) & (v <= 0) & (w <= 0))
    degenerate = (u == 0) & (v == 0) & (w == 0)
    return opposite & through & ~degenerate


def edges_crossing(edge_points, edges, triangle_points, triangles) -> np.ndarray:
    """Indices into ``edges`` of the edges that cross any of the triangles."""
    edge_points = np.asarray(edge_points, dtype=np.float64)
    triangle_points = np.asarray(triangle_points, dtype=np.float64)
    edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    triangles = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    hit = np.zeros(len(edges), dtype=bool)
    e_min, e_max = _boxes(edge_points, edges)
    t_min, t_max = _boxes(triangle_points, triangles)
    for i, j in overlapping_pairs(e_min, e_max, t_min, t_max):
        e, t = edges[i], triangles[j]
        crossing = segments_cross_triangles(
            edge_points[e[:, 0]], edge_points[e[:, 1]],
            triangle_points[t[:, 0]], triangle_points[t[:, 1]], triangle_points[t[:, 2]],
        )
        hit[i[crossing]] = True
    return np.nonzero(hit)[0]


def winding_numbers(points, vertices, triangles) -> np.ndarray:
    """Generalized winding number of each point about a triangle surface (1 inside a closed,
    outward-facing surface, 0 outside, ½ on it): the triangles' solid angles (Van Oosterom and
    Strackee) summed over 4π."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    vertices = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    out = np.zeros(len(points))
    rows = max(1, _CHUNK // max(1, len(t)))
    # Component arrays, written out: several times faster than einsum/cross/norm on (P, T, 3).
    corners = [[vertices[t[:, k], axis][None, :] for axis in range(3)] for k in range(3)]
    for s in range(0, len(points), rows):
        p = points[s : s + rows]
        (ax, ay, az), (bx, by, bz), (cx, cy, cz) = (
            [corner[axis] - p[:, axis : axis + 1] for axis in range(3)] for corner in corners
        )
        la = np.sqrt(ax * ax + ay * ay + az * az)
        lb = np.sqrt(bx * bx + by * by + bz * bz)
        lc = np.sqrt(cx * cx + cy * cy + cz * cz)
        numerator = ax * (by * cz - bz * cy) + ay * (bz * cx - bx * cz) + az * (bx * cy - by * cx)
        denominator = (
            la * lb * lc
            + (ax * bx + ay * by + az * bz) * lc
            + (bx * cx + by * cy + bz * cz) * la
            + (cx * ax + cy * ay + cz * az) * lb
        )
        out[s : s + rows] = np.arctan2(numerator, denominator).sum(axis=1) / (2.0 * np.pi)
    return out


def distances_to_triangles(points, vertices, triangles) -> np.ndarray:
    """Distance from each point to the nearest of the triangles (exact, brute force: use it on
    the few points that need it)."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    vertices = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    A, B, C = vertices[t[:, 0]], vertices[t[:, 1]], vertices[t[:, 2]]
    best = np.full(len(points), np.inf)
    rows = max(1, _CHUNK // max(1, len(t)))
    for s in range(0, len(points), rows):
        p = points[s : s + rows, None, :]
        best[s : s + rows] = _point_triangle_distance(p, A[None], B[None], C[None]).min(axis=1)
    return best


def _point_triangle_distance(p, a, b, c) -> np.ndarray:
    # Inside the prism over the triangle: the distance to its plane; elsewhere the nearest of
    # the three edges (segments). Degenerate triangles fall through to their edges.
    n = np.cross(b - a, c - a)
    area2 = np.einsum("...k,...k->...", n, n)
    safe = np.where(area2 > 0, area2, 1.0)
    plane = np.einsum("...k,...k->...", p - a, n)
    foot = p - (plane / safe)[..., None] * n
    inside = np.ones(np.broadcast_shapes(p.shape, a.shape)[:-1], dtype=bool)
    for u, v in ((a, b), (b, c), (c, a)):
        inside &= np.einsum("...k,...k->...", np.cross(v - u, foot - u), n) >= 0
    inside &= area2 > 0
    to_plane = np.abs(plane) / np.sqrt(safe)

    def segment(u, v):
        d = v - u
        dd = np.einsum("...k,...k->...", d, d)
        s = np.clip(np.einsum("...k,...k->...", p - u, d) / np.where(dd > 0, dd, 1.0), 0.0, 1.0)
        return np.linalg.norm(p - (u + s[..., None] * d), axis=-1)

    edges = np.minimum(np.minimum(segment(a, b), segment(b, c)), segment(c, a))
    return np.where(inside, np.minimum(to_plane, edges), edges)


def points_inside(points, vertices, triangles, tolerance: float = 1e-5) -> np.ndarray:
    """Indices of the points strictly inside the closed triangle surface, deeper than
    ``tolerance``."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    vertices = np.asarray(vertices, dtype=np.float64)
    low, high = vertices.min(axis=0), vertices.max(axis=0)
    near = np.nonzero(((points >= low) & (points <= high)).all(axis=1))[0]  # outside the box: outside
    if len(near) == 0:
        return near
    inside = near[winding_numbers(points[near], vertices, triangles) > 0.5]
    if len(inside):
        inside = inside[distances_to_triangles(points[inside], vertices, triangles) > tolerance]
    return inside


# --- Spheres -------------------------------------------------------------------------------------


def uv_sphere_inradius(radius: float, segments: int, rings: int) -> float:
    """Distance from the centre of a UV sphere (Blender's ``primitive_uv_sphere_add``: its
    vertices on the sphere of ``radius``, ``segments`` around, ``rings`` from pole to pole) to
    its nearest face plane, from the formula of its vertices rather than from any mesh."""
    theta = 2 * np.pi / segments
    phi = np.pi * np.arange(rings + 1) / rings  # polar angle of each ring, pole to pole

    def at(p, t):
        return radius * np.stack([np.sin(p) * np.cos(t), np.sin(p) * np.sin(t), np.cos(p)], axis=-1)

    best = np.inf
    for k in range(rings):
        corners = [at(phi[k], 0.0), at(phi[k], theta), at(phi[k + 1], theta), at(phi[k + 1], 0.0)]
        distinct = [c for i, c in enumerate(corners) if all(np.linalg.norm(c - d) > 1e-12 * radius for d in corners[:i])]
        a, b, c = distinct[:3]
        n = np.cross(b - a, c - a)
        best = min(best, abs(float(np.dot(a, n))) / float(np.linalg.norm(n)))
    return best


def points_inside_sphere(points, centre, radius: float) -> np.ndarray:
    """Indices of the points closer than ``radius`` to ``centre`` (the analytic check of a
    spherical collider: pass its inradius)."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    return np.nonzero(np.linalg.norm(points - np.asarray(centre, dtype=np.float64), axis=1) < radius)[0]


# --- A skin against its colliders ----------------------------------------------------------------


@dataclasses.dataclass
class Penetrations:
    """What :func:`find_penetrations` found (indices, not just counts, to show in a failure)."""

    vertices_inside: np.ndarray  # skin vertex indices inside a closed collider
    skin_edges_crossing: np.ndarray  # (k, 2) skin edges crossing a collider triangle
    collider_edges_crossing: list  # per collider: (k, 2) of its edges crossing a skin triangle
    open_colliders: list  # indices of the colliders without an inside

    def counts(self) -> dict[str, int]:
        return {
            "vertices_inside": len(self.vertices_inside),
            "skin_edges_crossing": len(self.skin_edges_crossing),
            "collider_edges_crossing": sum(len(e) for e in self.collider_edges_crossing),
        }

    @property
    def total(self) -> int:
        return sum(self.counts().values())


def find_penetrations(skin_positions, skin_triangles, colliders, tolerance: float = 1e-5) -> Penetrations:
    """Every penetration of a skin (positions, triangles) by ``colliders``, a sequence of
    ``(positions, triangles)`` in the same space."""
    skin = np.asarray(skin_positions, dtype=np.float64)
    skin_triangles = np.asarray(skin_triangles, dtype=np.int64).reshape(-1, 3)
    skin_edges = triangle_edges(skin_triangles)
    inside, crossing, collider_crossing, open_ = [], [], [], []
    for k, (positions, triangles) in enumerate(colliders):
        positions = np.asarray(positions, dtype=np.float64)
        triangles = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
        if is_closed(triangles):
            inside.append(points_inside(skin, positions, triangles, tolerance))
        else:
            open_.append(k)
        crossing.append(edges_crossing(skin, skin_edges, positions, triangles))
        edges = triangle_edges(triangles)
        collider_crossing.append(edges[edges_crossing(positions, edges, skin, skin_triangles)])
    vertices = np.unique(np.concatenate(inside)) if inside else np.zeros(0, np.int64)
    edges_hit = skin_edges[np.unique(np.concatenate(crossing))] if crossing else np.zeros((0, 2), np.int64)
    return Penetrations(vertices, edges_hit, collider_crossing, open_)


# --- Caches --------------------------------------------------------------------------------------

PC2_MAGIC = b"POINTCACHE2\0"
PC2_HEADER = 32


def read_pc2(path) -> np.ndarray:
    """``(frames, vertices, 3)`` float32 positions of a PC2 point cache, read from its bytes."""
    data = pathlib.Path(path).read_bytes()
    if data[:12] != PC2_MAGIC:
        raise ValueError(f"{path} is not a PC2 cache")
    version, vertices, frames = (int(np.frombuffer(data, "<i4", 1, offset)[0]) for offset in (12, 16, 28))
    if version != 1 or len(data) != PC2_HEADER + 12 * vertices * frames:
        raise ValueError(f"{path}: version {version}, or its length does not match {frames} frames × {vertices} vertices")
    return np.frombuffer(data, "<f4", offset=PC2_HEADER).reshape(frames, vertices, 3)


def write_pc2(path, frames, start: float = 1.0) -> None:
    """Writes ``(frames, vertices, 3)`` positions as a PC2 cache (to plant penetrations in tests)."""
    frames = np.ascontiguousarray(frames, dtype="<f4")
    header = PC2_MAGIC + np.array([1, frames.shape[1]], "<i4").tobytes()
    header += np.array([start, 1.0], "<f4").tobytes() + np.array([frames.shape[0]], "<i4").tobytes()
    pathlib.Path(path).write_bytes(header + frames.tobytes())


def check_cache(path, corner_verts, polygon_sizes, colliders_at, to_world=None, tolerance: float = 1e-5):
    """Penetrations of every frame of a baked skin cache: a list of :class:`Penetrations`.

    ``colliders_at(k)`` gives the colliders ``[(positions, triangles), …]`` in world space at the
    cache's frame ``k`` (0-based); ``to_world`` is the skin object's 4 × 4 world matrix (the cache
    is in object space), identity if omitted.
    """
    cache = read_pc2(path).astype(np.float64)
    triangles = fan_triangles(corner_verts, polygon_sizes)
    m = np.eye(4) if to_world is None else np.asarray(to_world, dtype=np.float64)
    return [find_penetrations(frame @ m[:3, :3].T + m[:3, 3], triangles, colliders_at(k), tolerance) for k, frame in enumerate(cache)]
