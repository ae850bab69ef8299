# SPDX-License-Identifier: GPL-3.0-or-later
"""Blender mesh data as numpy arrays in the wheel's layout, whole arrays at a time."""

from __future__ import annotations

import bpy
import numpy as np


# Reading through the generic attribute API is a block copy; the older
# `vertices.foreach_get("co")` goes element by element (0.2 ms against 27 ms
# for 100k vertices in Blender 5.0), which matters once per frame.

def positions(mesh: bpy.types.Mesh, out: np.ndarray | None = None) -> np.ndarray:
    """Vertex positions, float32 ``(N, 3)``, in object space; into ``out`` when
    it has the mesh's size (a bake reuses one array: see ``FrameBuffers``)."""
    count = len(mesh.vertices)
    if out is None or out.shape != (count, 3):
        out = np.empty((count, 3), dtype=np.float32)
    attribute = mesh.attributes.get("position")
    if attribute is not None and attribute.data_type == "FLOAT_VECTOR":
        attribute.data.foreach_get("vector", out.ravel())
    else:
        mesh.vertices.foreach_get("co", out.ravel())
    return out


def first_non_finite(positions: np.ndarray) -> int | None:
    """The first vertex with a NaN or infinite coordinate, or None (one pass when all are finite)."""
    if np.isfinite(positions).all():
        return None
    return int(np.argwhere(~np.isfinite(positions))[0][0])


def corner_verts(mesh: bpy.types.Mesh) -> np.ndarray:
    """The vertex of every face corner, int32 ``(L,)``."""
    out = np.empty(len(mesh.loops), dtype=np.int32)
    attribute = mesh.attributes.get(".corner_vert")
    if attribute is not None and attribute.data_type == "INT" and attribute.domain == "CORNER":
        attribute.data.foreach_get("value", out)
    else:
        mesh.loops.foreach_get("vertex_index", out)
    return out


def polygon_sizes(mesh: bpy.types.Mesh) -> np.ndarray:
    """The corner count of every polygon, int32 ``(P,)``."""
    out = np.empty(len(mesh.polygons), dtype=np.int32)
    mesh.polygons.foreach_get("loop_total", out)
    return out


def set_vertex_selection(mesh: bpy.types.Mesh, indices: np.ndarray) -> None:
    """Selects exactly ``indices`` (and the edges and faces between them)."""
    selected = np.zeros(len(mesh.vertices), dtype=bool)
    selected[indices] = True
    edge_verts = np.empty(len(mesh.edges) * 2, dtype=np.int32)
    mesh.edges.foreach_get("vertices", edge_verts)
    corners = corner_verts(mesh)
    starts = np.concatenate(([0], np.cumsum(polygon_sizes(mesh))[:-1])).astype(np.intp)
    _set_bool_attribute(mesh, ".select_vert", "POINT", selected)
    _set_bool_attribute(mesh, ".select_edge", "EDGE", selected[edge_verts].reshape(-1, 2).all(axis=1))
    if len(starts):
        _set_bool_attribute(mesh, ".select_poly", "FACE", np.logical_and.reduceat(selected[corners], starts))
    mesh.update()


def _set_bool_attribute(mesh: bpy.types.Mesh, name: str, domain: str, values: np.ndarray) -> None:
    # Selection lives in internal boolean attributes. Meshes built with
    # `Mesh.from_pydata` in Blender 5.0 can carry a `.select_edge` of the wrong
    # type (INT32_2D), on which `MeshEdges.foreach_set("select")` crashes
    # Blender; such an attribute holds no usable selection and is replaced.
    attribute = mesh.attributes.get(name)
    if attribute is not None and (attribute.data_type != "BOOLEAN" or attribute.domain != domain):
        mesh.attributes.remove(attribute)
        attribute = None
    if attribute is None:
        attribute = mesh.attributes.new(name, "BOOLEAN", domain)
    attribute.data.foreach_set("value", values)


def vertex_group_weights(mesh: bpy.types.Mesh, group_index: int) -> np.ndarray:
    """Weights of one vertex group, float32 ``(N,)``, 0 where a vertex is not in it.

    Blender exposes vertex-group weights to Python only per vertex (they are
    not attributes, not even on the evaluated mesh), so this is the one
    per-vertex loop in the add-on; it runs once per bake, not per frame.
    """
    weights = np.zeros(len(mesh.vertices), dtype=np.float32)
    for vertex in mesh.vertices:
        for element in vertex.groups:
            if element.group == group_index:
                weights[vertex.index] = element.weight
                break
    return weights
