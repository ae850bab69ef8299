"""Pyramid Deform on a real character (issue 26), through the installed extension as a user drives it.

The CC0 MakeHuman character from ``../shared/data/makehuman`` in its hard pose
(``demo/character.py``: elbows and knees at 130°, arms raised, a forearm twisted 80°, the spine
bent), in the three variants of ``demo/character_demo.py``: loaded from the OBJ (welded), after a
round trip through Blender's glTF exporter and importer (split seams), and with a Subdivision
Surface modifier (level 1) between the Armature and Tegument (~53k vertices evaluated; measured on
that evaluated mesh). Each is bound with Add Pyramid Deform and baked to PC2 over the pose's 12 frames with the
default settings; the cache is then compared with the skinning input at frames 4, 8 and 12 using
``demo/measures.py`` alone (spike measure, seam gap, Blender's BVHTree self-overlap).

Plus two open meshes bent by an armature (a sleeve open at both ends, a disc with a hole), and the
user's mesh data checked unchanged by bind and bake.
"""

from __future__ import annotations

import functools
import pathlib
import tempfile

import bpy
import numpy as np
import pytest

from conftest import shared_data

import character_demo
import measures

MEASURED_FRAMES = (4, 8, 12)
PINNED_AT_MOST = 0.005  # of the vertices: the issue's "at most 0.5% follow the input"
SEAM_GAP_AT_MOST = 1e-5  # of the mesh size


@functools.cache
def baked(variant: str) -> dict:
    """Builds, binds and bakes one variant once per session; returns what the tests check.

    Cached because each variant costs seconds to build and bake; every test then reads its own
    figure. The scene is rebuilt by the next test's factory reset, which this does not depend on.
    """
    workdir = pathlib.Path(tempfile.mkdtemp(prefix=f"tegument-character-{variant}-"))
    bpy.ops.wm.save_as_mainfile(filepath=str(workdir / f"{variant}.blend"))  # "//" caches land here
    obj, _ = character_demo.build(variant, workdir)
    before = mesh_snapshot(obj.data)
    bind = character_demo.add_and_bake(obj, f"//{variant}.pc2")
    after = mesh_snapshot(obj.data)
    # What Tegument deforms: the mesh, or for "subdivided" the stack above Tegument at rest.
    rest, corners, sizes = character_demo.rest_topology(obj)
    groups = measures.coincident_groups(rest)
    cache = character_demo.read_cache(obj)
    frames = {}
    for frame in MEASURED_FRAMES:
        skin = character_demo.upstream_local(obj, frame)
        result = cache[frame - character_demo.POSE_FRAMES[0]]
        frames[frame] = {
            "skinning": character_demo.frame_figures(skin, rest, corners, sizes, groups),
            "tegument": character_demo.frame_figures(result, rest, corners, sizes, groups),
        }
    figures = {
        "bind": bind, "frames": frames, "split_vertices": int((groups != np.arange(len(groups))).sum()),
        "mesh_size": measures.mesh_size(rest), "cache_finite": bool(np.isfinite(cache).all()),
        "cache_frames": len(cache), "before": before, "after": after,
    }
    print(f"\n[{variant}] {report_line(figures)}")
    return figures


def report_line(figures: dict) -> str:
    bind = figures["bind"]
    parts = [f"{bind['vertices']} vertices ({figures['split_vertices']} split), pinned {bind['pinned']} "
             f"({100 * bind['pinned'] / bind['vertices']:.2f}%), {bind['ms_per_frame']:.1f} ms per frame"]
    for frame, pair in figures["frames"].items():
        skin, ours = pair["skinning"], pair["tegument"]
        parts.append(f"frame {frame}: spike max {skin['spike_max']:.3f} -> {ours['spike_max']:.3f}, "
                     f"seam gap {ours['seam_gap']:.2e}, self-intersections {skin['self_intersections']} -> {ours['self_intersections']}")
    return "; ".join(parts)


# How foreach_get reads each attribute type: (property, values per element, dtype).
ATTRIBUTE_LAYOUT = {
    "FLOAT": ("value", 1, np.float32), "INT": ("value", 1, np.int32), "INT8": ("value", 1, np.int8),
    "BOOLEAN": ("value", 1, bool), "FLOAT2": ("vector", 2, np.float32), "FLOAT_VECTOR": ("vector", 3, np.float32),
    "FLOAT_COLOR": ("color", 4, np.float32), "BYTE_COLOR": ("color", 4, np.float32),
    "INT16_2D": ("value", 2, np.int16), "INT32_2D": ("value", 2, np.int32), "QUATERNION": ("value", 4, np.float32),
    "FLOAT4X4": ("value", 16, np.float32),
}


def mesh_snapshot(mesh) -> dict[str, bytes]:
    """The bytes of everything a user's mesh holds that bind or bake could touch, by name."""
    def read(collection, attribute, dtype, width=1):
        values = np.empty(len(collection) * width, dtype)
        collection.foreach_get(attribute, values)
        return values.tobytes()

    snapshot = {
        "vertices.co": read(mesh.vertices, "co", np.float32, 3),
        "loops.vertex_index": read(mesh.loops, "vertex_index", np.int32),
        "polygons.loop_start": read(mesh.polygons, "loop_start", np.int32),
        "polygons.loop_total": read(mesh.polygons, "loop_total", np.int32),
        "edges.vertices": read(mesh.edges, "vertices", np.int32, 2),
    }
    for layer in mesh.uv_layers:
        snapshot[f"uv {layer.name}"] = read(layer.uv, "vector", np.float32, 2)
    for vertex in mesh.vertices:
        snapshot[f"groups of {vertex.index}"] = np.array([(g.group, g.weight) for g in vertex.groups], np.float64).tobytes()
    for attribute in mesh.attributes:
        if attribute.data_type not in ATTRIBUTE_LAYOUT:
            raise AssertionError(f"attribute {attribute.name}: type {attribute.data_type} is not in ATTRIBUTE_LAYOUT; add it")
        key, width, dtype = ATTRIBUTE_LAYOUT[attribute.data_type]
        snapshot[f"attribute {attribute.name} ({attribute.domain}, {attribute.data_type})"] = read(attribute.data, key, dtype, width)
    return snapshot


def figures_of(variant: str) -> dict:
    shared_data("makehuman")
    return baked(variant)


@pytest.mark.parametrize("variant", character_demo.VARIANTS)
def test_bind_leaves_at_most_half_a_percent_following_the_input(variant):
    figures = figures_of(variant)
    bind = figures["bind"]
    assert bind["vertices"] > (50000 if variant == "subdivided" else 13000)
    assert bind["pinned"] <= PINNED_AT_MOST * bind["vertices"], report_line(figures)


@pytest.mark.parametrize("variant", character_demo.VARIANTS)
def test_the_cache_is_finite_and_whole(variant):
    figures = figures_of(variant)
    assert figures["cache_frames"] == character_demo.POSE_FRAMES[1] - character_demo.POSE_FRAMES[0] + 1
    assert figures["cache_finite"]
    assert all(pair["tegument"]["finite"] for pair in figures["frames"].values())


@pytest.mark.parametrize("variant", character_demo.VARIANTS)
def test_split_seams_stay_closed(variant):
    figures = figures_of(variant)
    if variant == "gltf":
        assert figures["split_vertices"] > 1000, "the glTF round trip no longer splits the seams: this test lost its point"
    limit = SEAM_GAP_AT_MOST * figures["mesh_size"]
    for frame, pair in figures["frames"].items():
        assert pair["skinning"]["seam_gap"] <= limit, f"frame {frame}: the input itself opens the seams"
        assert pair["tegument"]["seam_gap"] <= limit, f"frame {frame}: {report_line(figures)}"


@pytest.mark.parametrize("variant", character_demo.VARIANTS)
def test_no_spike_above_the_skinning_input(variant):
    figures = figures_of(variant)
    for frame, pair in figures["frames"].items():
        assert pair["tegument"]["spike_max"] <= pair["skinning"]["spike_max"], f"frame {frame}: {report_line(figures)}"


@pytest.mark.parametrize("variant", character_demo.VARIANTS)
def test_no_more_self_intersections_than_the_skinning_input(variant):
    figures = figures_of(variant)
    for frame, pair in figures["frames"].items():
        assert pair["tegument"]["self_intersections"] <= pair["skinning"]["self_intersections"], f"frame {frame}: {report_line(figures)}"


def test_the_pose_is_as_hard_as_the_issue_asks():
    shared_data("makehuman")
    import character

    _, rig = character_demo.build("obj", pathlib.Path(tempfile.mkdtemp()))
    bpy.context.scene.frame_set(character_demo.POSE_FRAMES[1])
    for side in "LR":
        assert character.flexion_degrees(rig, f"upperarm02.{side}", f"lowerarm01.{side}") >= 120
        assert character.flexion_degrees(rig, f"upperleg02.{side}", f"lowerleg01.{side}") >= 120


@pytest.mark.parametrize("variant", ("obj", "gltf"))
def test_converge_bakes_the_hard_pose_within_five_percent_of_converged(variant):
    """Issue 28 on a real character: baked with Converge (each frame from the last one's result,
    stopping at its tolerance, within its iteration limit), every frame of the pose that moves (at least a
    tenth of the last frame's displacement) is within 5 % of the same solve run to a standstill
    (RMS |x − x_inf| / RMS |x_inf − input|), on the welded quads and on the triangles of the glTF
    round trip, which converge more slowly."""
    shared_data("makehuman")
    import tegument

    workdir = pathlib.Path(tempfile.mkdtemp(prefix=f"tegument-converge-{variant}-"))
    bpy.ops.wm.save_as_mainfile(filepath=str(workdir / f"{variant}.blend"))
    obj, _ = character_demo.build(variant, workdir)
    character_demo.add_and_bake(obj, f"//{variant}.pc2", converge=True)
    settings = obj.tegument
    assert settings.converge and settings.iterations == tegument.DEFAULTS.accelerated_iterations
    cache = character_demo.read_cache(obj)
    rest, corners, sizes = character_demo.rest_topology(obj)
    reference = tegument.PyramidDeformer(rest, corners, sizes, scale_safe=settings.scale_safe)
    reference.accelerated = True
    matrix = np.array(obj.matrix_world, dtype=np.float64)

    def world(local):
        return (local @ matrix[:3, :3].T + matrix[:3, 3]).astype(np.float32)

    first, last = character_demo.POSE_FRAMES
    errors, scales = [], []
    for frame in range(first, last + 1):
        source = world(character_demo.upstream_local(obj, frame))
        x_inf = reference.solve(source, iterations=1000, closeness=settings.closeness)
        error, scale = measures.convergence_error(world(cache[frame - first]), x_inf, source)
        errors.append(error)
        scales.append(scale)
    assert sum(scale >= 0.1 * scales[-1] for scale in scales) >= 6, scales
    assert measures.worst_moving(errors, scales) <= 0.05, errors


@pytest.mark.parametrize("variant", character_demo.VARIANTS)
def test_bind_and_bake_leave_the_users_mesh_unchanged(variant):
    """Byte for byte: positions, loops, polygons, edges, UVs, vertex-group weights and every
    attribute, on every variant: the bind is a mesh of its own (``obj.tegument.bind_mesh``), so
    nothing is added to the user's mesh, not even an attribute."""
    figures = figures_of(variant)
    before, after = figures["before"], figures["after"]
    assert sorted(after) == sorted(before), f"added {sorted(set(after) - set(before))}, lost {sorted(set(before) - set(after))}"
    changed = [name for name in before if before[name] != after[name]]
    assert not changed
    assert after == before
    if variant == "subdivided":
        own_vertices = len(np.frombuffer(before["vertices.co"], np.float32)) // 3
        assert figures["bind"]["vertices"] > 3 * own_vertices, "the bind is not the subdivided stack's"


# ---------------------------------------------------------------------------- open boundaries


def boundary_vertices(corners: np.ndarray, sizes: np.ndarray) -> np.ndarray:
    """Vertices on an edge used by one polygon only."""
    starts = np.concatenate(([0], np.cumsum(sizes)[:-1]))
    following = np.arange(len(corners)) + 1
    ends = np.repeat(starts + sizes, sizes)
    following[following == ends] = np.repeat(starts, sizes)[following == ends]
    pairs = np.sort(np.stack([corners, corners[following]], axis=1), axis=1)
    edges, counts = np.unique(pairs, axis=0, return_counts=True)
    return np.unique(edges[counts == 1])


OPEN_MESHES = {"sleeve": character_demo.open_sleeve, "holed disc": character_demo.holed_disc}


@functools.cache
def open_baked(name: str) -> dict:
    workdir = pathlib.Path(tempfile.mkdtemp(prefix="tegument-open-"))
    bpy.ops.wm.save_as_mainfile(filepath=str(workdir / "open.blend"))
    obj, _ = OPEN_MESHES[name]()
    bind = character_demo.add_and_bake(obj, "//open.pc2")
    rest, corners, sizes = character_demo.topology(obj.data)
    lower = obj.vertex_groups["Lower"].index
    weight = np.array([next((g.weight for g in v.groups if g.group == lower), 0.0) for v in obj.data.vertices])
    cache = character_demo.read_cache(obj)
    groups = np.arange(len(rest))
    skin = character_demo.upstream_local(obj, character_demo.POSE_FRAMES[1])
    return {"bind": bind, "rest": rest, "corners": corners, "sizes": sizes, "bending": (weight > 0.01) & (weight < 0.99),
            "cache": cache, "skin": skin,
            "skin_spike": character_demo.frame_figures(skin, rest, corners, sizes, groups, intersections=False)["spike_max"],
            "spike": character_demo.frame_figures(cache[-1], rest, corners, sizes, groups, intersections=False)["spike_max"]}


@pytest.mark.parametrize("name", OPEN_MESHES)
def test_open_boundaries_deform_with_the_surface(name):
    """Bind encodes the border (nothing pinned), and where the border bends it leaves the input:
    shape-kept with the surface, not following the rig. (Where the input is rigid both agree.)"""
    found = open_baked(name)
    assert found["bind"]["pinned"] == 0, found["bind"]["warnings"]
    assert np.isfinite(found["cache"]).all()
    boundary = boundary_vertices(found["corners"], found["sizes"])
    assert len(boundary) >= 2 * 32, "two boundary loops expected"
    bending = boundary[found["bending"][boundary]]
    assert len(bending) >= 16, "a border must lie inside the bend for this test to mean anything"
    size = measures.mesh_size(found["rest"])
    departure = np.linalg.norm(found["cache"][-1][bending] - found["skin"][bending], axis=1)
    assert departure.min() > 1e-5 * size, f"{int((departure <= 1e-5 * size).sum())} bending border vertices sit on the input"
    assert np.linalg.norm(found["cache"][-1] - found["rest"], axis=1).max() > 0.1 * size  # the surface did move


@pytest.mark.parametrize("name", OPEN_MESHES)
def test_open_boundaries_spike_no_more_than_the_skinning_input(name):
    found = open_baked(name)
    print(f"\n[{name}] spike max {found['skin_spike']:.3f} -> {found['spike']:.3f}")
    assert found["spike"] <= found["skin_spike"], f"spike max {found['spike']:.3f} against skinning's {found['skin_spike']:.3f}"
