"""The MakeHuman character under Pyramid Deform: the variants the tests, the demo and the bench share,
the figures they compare, and the demo's pictures of it.

Three variants of the hard-posed character (``character.HARD_POSE``), each as a user would have it:

- ``"obj"``: loaded from MakeHuman's OBJ (:func:`character.load_character`): welded, closed;
- ``"gltf"``: the same after a round trip through Blender's own glTF exporter and importer, which
  splits the vertices at every UV seam (the mesh arrives with open edges along the seams);
- ``"subdivided"``: the OBJ character with a Subdivision Surface modifier (level 1) between the
  Armature and Tegument (~53k vertices evaluated, the mesh itself keeps its ~13k): Tegument binds
  and bakes the stack above it, and the measures here are taken on that evaluated mesh
  (:func:`rest_topology`, :func:`upstream_local`).

Plus two small open meshes bent by a two-bone armature: a sleeve (a tube open at both ends) and a
disc with a hole. :func:`figures` measures skinning (the input) against Tegument's cache with
``demo/measures.py`` only, so nothing it reports comes from the solver itself.
"""

from __future__ import annotations

import contextlib
import math
import pathlib
import time

import bpy
import numpy as np

import character
import extension
import measures

POSE_FRAMES = (1, 12)  # rest keyed at 1, the hard pose at 12 (character.animate_pose)
VARIANTS = ("obj", "gltf", "subdivided")


def _select_only(*objects) -> None:
    bpy.ops.object.select_all(action="DESELECT")
    for obj in objects:
        obj.select_set(True)
    bpy.context.view_layer.objects.active = objects[0]


def build(variant: str, workdir: pathlib.Path) -> tuple[bpy.types.Object, bpy.types.Object]:
    """``(mesh object, armature)`` of the posed character in the current scene, frames 1–12."""
    if variant not in VARIANTS:
        raise ValueError(f"unknown character variant {variant!r}: one of {', '.join(VARIANTS)}")
    obj, rig = character.load_character()
    character.animate_pose(rig, frame_start=POSE_FRAMES[0], frame_end=POSE_FRAMES[1])
    if variant == "gltf":
        path = pathlib.Path(workdir) / "human.glb"
        _select_only(obj, rig)
        bpy.ops.export_scene.gltf(filepath=str(path), use_selection=True, export_animations=True)
        mesh, armature = obj.data, rig.data
        bpy.data.objects.remove(obj)
        bpy.data.objects.remove(rig)
        bpy.data.meshes.remove(mesh)
        bpy.data.armatures.remove(armature)
        for action in list(bpy.data.actions):
            bpy.data.actions.remove(action)
        bpy.ops.import_scene.gltf(filepath=str(path))
        obj = next(o for o in bpy.data.objects if o.type == "MESH")
        rig = next(o for o in bpy.data.objects if o.type == "ARMATURE")
    elif variant == "subdivided":
        # After the Armature (which deforms the ~13k-vertex cage), before Tegument (added last).
        subdivision = obj.modifiers.new("Subdivision", "SUBSURF")
        subdivision.levels = subdivision.render_levels = 1
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = POSE_FRAMES
    scene.frame_set(POSE_FRAMES[0])
    return obj, rig


# ------------------------------------------------------------------------------ open meshes


def _grid_polygons(rows: int, columns: int, wrap: bool) -> np.ndarray:
    """Quads of a ``rows × columns`` vertex grid, rows in order, columns wrapped round if ``wrap``."""
    quads = []
    span = columns if wrap else columns - 1
    for r in range(rows - 1):
        for c in range(span):
            a, b = r * columns + c, r * columns + (c + 1) % columns
            quads.append((a, b, b + columns, a + columns))
    return np.asarray(quads, dtype=np.int32)


def _mesh_object(name: str, positions: np.ndarray, quads: np.ndarray) -> bpy.types.Object:
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(positions.tolist(), [], quads.tolist())
    mesh.validate()
    mesh.shade_smooth()
    obj = bpy.data.objects.new(name, mesh)
    bpy.context.collection.objects.link(obj)
    return obj


def _bend_rig(obj, name: str, head, joint, tail, axis: str, degrees: float, blend: float, along) -> bpy.types.Object:
    """Two bones (``head``→``joint``→``tail``), weights blended over ``blend`` across the joint along
    ``along`` (a unit vector), the second bone turned by ``degrees`` about its local ``axis`` at
    frame 12 (rest at 1)."""
    armature = bpy.data.armatures.new(name)
    rig = bpy.data.objects.new(name, armature)
    bpy.context.collection.objects.link(rig)
    _select_only(rig)
    bpy.ops.object.mode_set(mode="EDIT")
    upper = armature.edit_bones.new("Upper")
    upper.head, upper.tail = head, joint
    lower = armature.edit_bones.new("Lower")
    lower.head, lower.tail = joint, tail
    lower.parent = upper
    lower.use_connect = True
    bpy.ops.object.mode_set(mode="OBJECT")
    positions = np.array([v.co[:] for v in obj.data.vertices])
    t = np.clip(((positions - np.asarray(joint)) @ np.asarray(along)) / blend + 0.5, 0.0, 1.0)
    t = t * t * (3 - 2 * t)  # smoothstep: the weights blend without a kink
    for bone, weights in (("Upper", 1.0 - t), ("Lower", t)):
        group = obj.vertex_groups.new(name=bone)
        for index, weight in enumerate(weights):
            if weight > 0:
                group.add([index], float(weight), "REPLACE")
    obj.parent = rig
    obj.modifiers.new("Armature", "ARMATURE").object = rig
    pose = rig.pose.bones["Lower"]
    pose.rotation_mode = "XYZ"
    pose.keyframe_insert("rotation_euler", frame=POSE_FRAMES[0])
    setattr(pose.rotation_euler, axis, math.radians(degrees))
    pose.keyframe_insert("rotation_euler", frame=POSE_FRAMES[1])
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = POSE_FRAMES
    scene.frame_set(POSE_FRAMES[0])
    return rig


def open_sleeve(segments: int = 32, rings: int = 40, radius: float = 0.1, length: float = 1.0):
    """A tube along +X open at both ends, bent 100° at 4/5 of its length: ``(mesh object, armature)``."""
    angle = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    x = np.linspace(0, length, rings)
    positions = np.stack([np.repeat(x, segments), np.tile(radius * np.cos(angle), rings),
                          np.tile(radius * np.sin(angle), rings)], axis=1)
    obj = _mesh_object("Sleeve", positions, _grid_polygons(rings, segments, wrap=True))
    # The joint near the far end, the weights blending up to it: that open end bends with the
    # sleeve (as a cuff at a wrist does), where a pinned end and a shape-kept one differ.
    rig = _bend_rig(obj, "SleeveRig", (0, 0, 0), (0.8 * length, 0, 0), (1.2 * length, 0, 0), "z", 100.0, 0.5 * length, (1, 0, 0))
    return obj, rig


def holed_disc(segments: int = 64, rings: int = 16, inner: float = 0.15, outer: float = 0.5):
    """A flat annulus in the XY plane, folded 90° about the line x = 0, the hole's border inside the
    fold: ``(mesh object, armature)``."""
    angle = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    radii = np.linspace(inner, outer, rings)
    positions = np.stack([np.outer(radii, np.cos(angle)).ravel(), np.outer(radii, np.sin(angle)).ravel(),
                          np.zeros(segments * rings)], axis=1)
    obj = _mesh_object("Disc", positions, _grid_polygons(rings, segments, wrap=True))
    # A bone along +X with no roll has its local X axis along world -Y: turning about it folds
    # the far half up out of the disc's plane.
    rig = _bend_rig(obj, "DiscRig", (-outer, 0, 0), (0, 0, 0), (outer, 0, 0), "x", 90.0, 0.3, (1, 0, 0))
    return obj, rig


# ---------------------------------------------------------------------------------- figures


def upstream_local(obj, frame: int) -> np.ndarray:
    """Object-space positions of the stack above Tegument at ``frame`` (the skinning input), read
    without the add-on: Tegument's modifier (last in the stack) is hidden meanwhile."""
    modifier = obj.modifiers.get("Tegument")
    shown = modifier.show_viewport if modifier else False
    if modifier:
        modifier.show_viewport = False
    try:
        bpy.context.scene.frame_set(frame)
        evaluated = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
        positions = np.empty(len(evaluated.data.vertices) * 3, np.float32)
        evaluated.data.vertices.foreach_get("co", positions)
    finally:
        if modifier:
            modifier.show_viewport = shown
    return positions.reshape(-1, 3)


@contextlib.contextmanager
def corrective_smooth(obj):
    """Blender's Corrective Smooth (10 iterations) at the end of ``obj``'s stack, bound at the
    pose's rest frame, with any Tegument modifier hidden meanwhile: the stack the comparisons
    call "Corrective Smooth". Bound at the rest frame rather than ORCO: ORCO is the mesh's own
    vertices, which a Subdivision Surface above Corrective Smooth no longer has."""
    tegument_modifier = obj.modifiers.get("Tegument")
    if tegument_modifier is not None:
        tegument_modifier.show_viewport = False
    bpy.context.scene.frame_set(POSE_FRAMES[0])
    smooth = obj.modifiers.new("CorrectiveSmooth", "CORRECTIVE_SMOOTH")
    try:
        smooth.iterations = 10
        smooth.rest_source = "BIND"
        bpy.context.view_layer.objects.active = obj
        with bpy.context.temp_override(object=obj, active_object=obj):
            if bpy.ops.object.correctivesmooth_bind(modifier=smooth.name) != {"FINISHED"}:
                raise RuntimeError(f"Corrective Smooth did not bind on {obj.name}")
        yield smooth
    finally:
        obj.modifiers.remove(smooth)
        if tegument_modifier is not None:
            tegument_modifier.show_viewport = True


def topology(mesh) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(rest positions, corner vertices, polygon sizes)`` of a mesh datablock."""
    rest = np.empty(len(mesh.vertices) * 3, np.float32)
    mesh.vertices.foreach_get("co", rest)
    corners = np.empty(len(mesh.loops), np.int32)
    mesh.loops.foreach_get("vertex_index", corners)
    sizes = np.empty(len(mesh.polygons), np.int32)
    mesh.polygons.foreach_get("loop_total", sizes)
    return rest.reshape(-1, 3), corners, sizes


def rest_topology(obj, frame: int = POSE_FRAMES[0]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`topology` of what Tegument deforms: the mesh's own where the stack above Tegument
    keeps its vertices, otherwise that stack evaluated at ``frame`` (the rest pose), read without
    the add-on (a Subdivision Surface after the Armature: the subdivided rest)."""
    own = topology(obj.data)
    modifier = obj.modifiers.get("Tegument")
    shown = modifier.show_viewport if modifier else False
    if modifier:
        modifier.show_viewport = False
    try:
        bpy.context.scene.frame_set(frame)
        evaluated = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
        if len(evaluated.data.vertices) == len(own[0]):
            return own
        return topology(evaluated.data)
    finally:
        if modifier:
            modifier.show_viewport = shown


def pinned_count(obj) -> int:
    """The vertices bind left following the input, as the add-on reports them (its bind warning
    "N vertices follow the rig: …"; 0 when there is no such warning)."""
    for part in obj.tegument.bind_warnings.split(";"):
        words = part.split()
        if len(words) > 2 and words[0].isdigit() and words[1] in ("vertex", "vertices") and words[2].startswith("follow"):
            return int(words[0])
    return 0


def frame_figures(positions: np.ndarray, rest: np.ndarray, corners: np.ndarray, sizes: np.ndarray,
                  groups: np.ndarray, intersections: bool = True) -> dict:
    """Spike maximum, seam gap, finiteness and (optionally) self-intersecting face pairs of one frame."""
    spikes = measures.spike_measure(positions, rest, corners, sizes)
    figures = {
        "finite": bool(np.isfinite(positions).all()),
        "spike_max": float(np.nanmax(spikes)),
        "seam_gap": measures.seam_gap(positions, groups),
    }
    if intersections:
        figures["self_intersections"] = measures.self_intersections(positions, corners, sizes, groups)
    return figures


def add_and_bake(obj, cache_path: str, frames=POSE_FRAMES, converge: bool = False, self_collision: bool = False) -> dict:
    """Add Pyramid Deform to ``obj`` and bake ``frames`` through the add-on's operators, as a user
    would (default iterations and closeness; with ``converge``, Converge on with its iteration
    limit; with ``self_collision``, Self Collision on at its defaults); returns the bind's figures
    and the bake's time."""
    _select_only(obj)
    if bpy.ops.tegument.deform_add() != {"FINISHED"}:
        raise RuntimeError(f"Add Pyramid Deform failed on {obj.name}: {obj.tegument.warnings}")
    settings = obj.tegument
    if converge:
        import tegument

        settings.converge, settings.iterations = True, tegument.DEFAULTS.accelerated_iterations
    settings.self_collision.enabled = self_collision
    pinned, warnings = pinned_count(obj), settings.bind_warnings
    settings.cache_path = cache_path
    settings.frame_start, settings.frame_end = frames
    started = time.perf_counter()
    if bpy.ops.tegument.bake() != {"FINISHED"}:
        raise RuntimeError(f"the bake of {obj.name} failed (its message is above)")
    wall = time.perf_counter() - started
    return {"vertices": settings.bound_vertices, "pinned": pinned, "warnings": warnings,
            "iterations": settings.iterations, "closeness": round(settings.closeness, 4),
            "ms_per_frame": settings.last_frame_ms,
            "ms_per_frame_wall": 1000 * wall / (frames[1] - frames[0] + 1)}


def read_cache(obj) -> np.ndarray:
    """Tegument's PC2 cache of ``obj`` as ``(frames, vertices, 3)`` object-space positions."""
    data = pathlib.Path(bpy.path.abspath(obj.tegument.cache_path)).read_bytes()
    vertices, frames = np.frombuffer(data[16:20], "<i4")[0], np.frombuffer(data[28:32], "<i4")[0]
    return np.frombuffer(data, "<f4", offset=32).reshape(frames, vertices, 3)


# ------------------------------------------------------------------------------------ demo

# Cycles on the CPU, small: the character's pictures cost a few seconds each on 2 cores.
RENDER_SAMPLES = 16
SPIKE_TOP = 0.5  # the top of the heat map's colour scale (spike measure)


def _camera(name: str, location, target, lens: float):
    from mathutils import Vector

    data = bpy.data.cameras.new(name)
    data.lens = lens
    camera = bpy.data.objects.new(name, data)
    bpy.context.collection.objects.link(camera)
    camera.location = location
    camera.rotation_euler = (Vector(target) - Vector(location)).to_track_quat("-Z", "Y").to_euler()
    return camera


def _heat_material(name: str, attribute: str) -> bpy.types.Material:
    """Emission from a colour attribute: the heat map's colours shown as they are."""
    material = bpy.data.materials.new(name)
    material.use_nodes = True
    nodes, links = material.node_tree.nodes, material.node_tree.links
    nodes.clear()
    colour = nodes.new("ShaderNodeAttribute")
    colour.attribute_name = attribute
    emission = nodes.new("ShaderNodeEmission")
    output = nodes.new("ShaderNodeOutputMaterial")
    links.new(colour.outputs["Color"], emission.inputs["Color"])
    links.new(emission.outputs["Emission"], output.inputs["Surface"])
    return material


def _skin_material() -> bpy.types.Material:
    material = bpy.data.materials.new("Skin")
    material.use_nodes = True
    shader = material.node_tree.nodes["Principled BSDF"]
    shader.inputs["Base Color"].default_value = (0.72, 0.55, 0.45, 1.0)
    shader.inputs["Roughness"].default_value = 0.6
    return material


def _render(camera, path: pathlib.Path, size) -> pathlib.Path:
    scene = bpy.context.scene
    scene.camera = camera
    scene.render.resolution_x, scene.render.resolution_y = size
    scene.render.filepath = str(path)
    bpy.ops.render.render(write_still=True)
    return path


def _linear_to_srgb(c: np.ndarray) -> np.ndarray:
    return np.where(c <= 0.0031308, 12.92 * c, 1.055 * np.power(np.clip(c, 0, None), 1 / 2.4) - 0.055)


def run(out: pathlib.Path, stage) -> dict:
    """The character in ``make demo``: bake the welded OBJ character, compare with skinning, render.

    Opens a fresh file of its own in ``out/character/``; writes ``character_before_after.png``
    (whole body, elbow and knee close-ups: skinning above, Pyramid Deform below) and
    ``character_spike_heat_map.png`` (the spike measure of both, with its scale) into ``out``.
    """
    import pictures

    folder = out / "character"
    folder.mkdir(parents=True, exist_ok=True)
    info: dict = {}
    with stage("character") as info:
        extension.new_blend(folder / "character.blend")
        try:
            obj, rig = build("obj", folder)
        except character.CharacterDataMissing as error:
            print(f"[demo] character skipped: {error}")
            info["skipped"] = str(error)
            return info
        bake = add_and_bake(obj, "//Human.pc2")
        last = POSE_FRAMES[1]
        rest, corners, sizes = topology(obj.data)
        groups = measures.coincident_groups(rest)
        skin = upstream_local(obj, last)
        ours = read_cache(obj)[-1]
        # Corrective Smooth (10 iterations) on the same input, for the numbers only.
        smooth = obj.modifiers.new("CorrectiveSmooth", "CORRECTIVE_SMOOTH")
        smooth.iterations, smooth.rest_source = 10, "ORCO"
        bpy.ops.object.modifier_move_to_index(modifier=smooth.name, index=1)
        smoothed = upstream_local(obj, last)
        obj.modifiers.remove(smooth)
        rows = {label: frame_figures(p, rest, corners, sizes, groups)
                for label, p in (("skinning", skin), ("corrective_smooth", smoothed), ("pyramid_deform", ours))}
        info.update(bake, frame=last, figures=rows, elbow_flexion=round(character.flexion_degrees(rig, "upperarm02.L", "lowerarm01.L"), 1),
                    knee_flexion=round(character.flexion_degrees(rig, "upperleg02.L", "lowerleg01.L"), 1))

        # Pictures at the last frame: the Tegument modifier on or off, then the heat maps.
        scene = bpy.context.scene
        scene.frame_set(last)
        scene.render.engine = "CYCLES"
        scene.cycles.device = "CPU"
        scene.cycles.samples = RENDER_SAMPLES
        scene.cycles.use_adaptive_sampling = False
        # Denoised: 16 samples leave the shadowed skin speckled, and OIDN costs ~2 s a picture.
        scene.cycles.use_denoising = True
        scene.cycles.denoiser = "OPENIMAGEDENOISE"
        scene.render.image_settings.file_format = "PNG"
        scene.render.image_settings.color_mode = "RGBA"
        scene.view_settings.view_transform = "Standard"
        world = bpy.data.worlds.new("World")
        world.color = (0.35, 0.35, 0.38)
        scene.world = world
        # A key light and a fill from the cameras' side: few samples leave no noisy dark shadows.
        for name, energy, rotation in (("Key", 3.0, (50, 10, -30)), ("Fill", 1.2, (70, 0, 40))):
            sun = bpy.data.objects.new(name, bpy.data.lights.new(name, "SUN"))
            sun.data.energy = energy
            sun.rotation_euler = tuple(math.radians(a) for a in rotation)
            bpy.context.collection.objects.link(sun)
        obj.data.materials.append(_skin_material())
        bones = rig.pose.bones
        elbow = rig.matrix_world @ bones["lowerarm01.L"].head
        knee = rig.matrix_world @ bones["lowerleg01.L"].head
        centre = np.asarray(ours).mean(axis=0)
        low, high = ours.min(axis=0), ours.max(axis=0)
        # MakeHuman's left is Blender's +X; the character faces -Y.
        whole = _camera("Whole", (centre[0] + 1.0, centre[1] - 2.6, centre[2] + 0.5), centre, 60.0)
        # The left elbow and knee from outside and in front, close enough for the crease to show.
        elbow_cam = _camera("Elbow", (elbow.x + 0.75, elbow.y - 0.45, elbow.z + 0.15), elbow, 50.0)
        knee_cam = _camera("Knee", (knee.x + 0.8, knee.y - 0.3, knee.z + 0.15), knee, 50.0)
        info["cameras"] = {"elbow": list(elbow), "knee": list(knee), "bounds": [low.tolist(), high.tolist()]}
        modifier = obj.modifiers["Tegument"]
        shots = {}
        for label, show in (("skinning", False), ("pyramid", True)):
            modifier.show_render = show
            for view, camera, size in (("whole", whole, (240, 320)), ("elbow", elbow_cam, (240, 320)), ("knee", knee_cam, (240, 320))):
                shots[(label, view)] = _render(camera, folder / f"{label}_{view}.png", size)
        modifier.show_render = True

        # Heat maps: the spike measure as a colour attribute on two copies of the mesh.
        heat = {}
        for label, positions in (("skinning", skin), ("pyramid", ours)):
            values = measures.spike_measure(positions, rest, corners, sizes)
            heat[label] = values
            mesh = bpy.data.meshes.new(f"Heat_{label}")
            mesh.from_pydata(positions.tolist(), [], [corners[s:s + k].tolist() for s, k in
                                                     zip(np.concatenate(([0], np.cumsum(sizes)[:-1])), sizes)])
            mesh.shade_smooth()
            colours = pictures.heat_colours(np.clip(values, 0, None), SPIKE_TOP)
            colours[:, :3] = np.where(colours[:, :3] <= 0.04045, colours[:, :3] / 12.92,
                                      ((colours[:, :3] + 0.055) / 1.055) ** 2.4)  # display → linear: shown as is
            attribute = mesh.color_attributes.new("spike", "FLOAT_COLOR", "POINT")
            attribute.data.foreach_set("color", colours.astype(np.float32).ravel())
            copy = bpy.data.objects.new(f"Heat_{label}", mesh)
            copy.data.materials.append(_heat_material(f"Heat_{label}", "spike"))
            copy.matrix_world = obj.matrix_world
            bpy.context.collection.objects.link(copy)
            copy.hide_render = True
        obj.hide_render = True
        scene.cycles.use_denoising = False  # flat emission colours: nothing to denoise
        for label in ("skinning", "pyramid"):
            copy = bpy.data.objects[f"Heat_{label}"]
            copy.hide_render = False
            shots[(label, "heat")] = _render(whole, folder / f"heat_{label}.png", (240, 320))
            shots[(label, "heat_elbow")] = _render(elbow_cam, folder / f"heat_elbow_{label}.png", (240, 320))
            copy.hide_render = True
        obj.hide_render = False
        info["spike_top_of_scale"] = SPIKE_TOP
        info["pictures"] = _compose(out, shots, rows, heat, info)
        bpy.ops.wm.save_as_mainfile(filepath=str(folder / "character.blend"))
        print(f"[demo] character: {bake['vertices']} vertices, {bake['pinned']} pinned, {bake['ms_per_frame']:.1f} ms per frame; "
              f"frame {last} spike max / self-intersecting pairs: " + ", ".join(
                  f"{label} {row['spike_max']:.2f} / {row['self_intersections']}" for label, row in rows.items()))
    return info


def _compose(out: pathlib.Path, shots: dict, rows: dict, heat: dict, info: dict) -> dict:
    """The two pictures, labelled, with matplotlib (as the flesh pictures are)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.image as mpimg
    import matplotlib.pyplot as plt
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import LinearSegmentedColormap, Normalize

    import pictures

    names = {"skinning": "skinning (Armature)", "pyramid": "Pyramid Deform (Tegument)"}
    figure_rows = {"skinning": rows["skinning"], "pyramid": rows["pyramid_deform"]}
    fig, axes = plt.subplots(2, 3, figsize=(7.2, 6.6), dpi=100)
    for r, label in enumerate(("skinning", "pyramid")):
        for c, view in enumerate(("whole", "elbow", "knee")):
            ax = axes[r, c]
            ax.imshow(mpimg.imread(shots[(label, view)]))
            ax.set_xticks([]), ax.set_yticks([])
            ax.set_title(f"{names[label]}\n{view}" if c == 0 else view, fontsize=8)
        axes[r, 0].set_ylabel(f"spike max {figure_rows[label]['spike_max']:.2f}\n"
                              f"self-intersecting pairs {figure_rows[label]['self_intersections']}", fontsize=8)
    fig.suptitle(f"MakeHuman character, frame {info['frame']}: elbows and knees flexed 130°, forearm twisted 80°", fontsize=9)
    fig.tight_layout()
    before_after = out / "character_before_after.png"
    fig.savefig(before_after)
    plt.close(fig)

    fig, axes = plt.subplots(1, 4, figsize=(9.6, 3.9), dpi=100, gridspec_kw={"width_ratios": [1, 1, 1, 1]})
    for k, (label, view) in enumerate((("skinning", "heat"), ("pyramid", "heat"), ("skinning", "heat_elbow"), ("pyramid", "heat_elbow"))):
        ax = axes[k]
        ax.imshow(mpimg.imread(shots[(label, view)]))
        ax.set_xticks([]), ax.set_yticks([])
        ax.set_title(f"{names[label]}\n{'elbow' if 'elbow' in view else 'whole'}; max {float(np.nanmax(heat[label])):.2f}", fontsize=8)
    ramp = LinearSegmentedColormap.from_list("inferno9", pictures._INFERNO)
    fig.colorbar(ScalarMappable(Normalize(0, SPIKE_TOP), ramp), ax=axes, fraction=0.025, pad=0.02,
                 label=f"spike measure (≥ {SPIKE_TOP} shown as the top colour)")
    fig.suptitle("Spike measure per vertex: growth of |x − mean of its ring| over the ring's mean rest edge", fontsize=9)
    heat_map = out / "character_spike_heat_map.png"
    fig.savefig(heat_map)
    plt.close(fig)
    return {"before_after": str(before_after), "heat_map": str(heat_map)}
