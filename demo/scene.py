"""The demo scene, built procedurally (no downloaded assets).

A limb (a capped, UV-mapped tube) driven by a two-bone armature that bends and twists it at the
elbow, so that its forearm presses into a body (a closed sphere in a collider collection); the
limb's skin carries round rigid scales painted into an image, with a rigidity image beside it.
The benchmarks and the tests build their meshes from the same functions.
"""

from __future__ import annotations

import math

import bpy
import numpy as np

# UV layout of the tube: one chart for the side (unrolled around the tube, the seam at angle 0),
# one small disc per cap beside it. Margin between charts and tile border, in UV units.
UV_MARGIN = 0.02


def tube_uv_scale(radius: float, length: float) -> float:
    """UV units per scene unit: the same in both directions, so a round feature painted in UV
    space is round on the rest surface; the side chart leaves room beside it for the two caps."""
    return min((1 - 2 * UV_MARGIN) / length, (1 - 4 * UV_MARGIN) / (2 * math.pi * radius + 4 * radius))


def tube_mesh(name: str, segments: int, rings: int, radius: float, length: float) -> bpy.types.Mesh:
    """A capped tube along +X from -length/2 to +length/2: quads along, triangle fans at the ends.

    It carries a UV map "UVMap" (see :func:`tube_corner_uvs`).
    """
    x = np.linspace(-length / 2, length / 2, rings + 1)
    angle = np.linspace(0.0, 2 * np.pi, segments, endpoint=False)
    ring = np.stack([np.zeros(segments), radius * np.cos(angle), radius * np.sin(angle)], axis=1)
    positions = np.concatenate([ring + [xi, 0, 0] for xi in x] + [[[x[0], 0, 0]], [[x[-1], 0, 0]]])
    # Built with numpy throughout: the scaling benchmark makes tubes of millions of vertices.
    i, j = (a.ravel() for a in np.meshgrid(np.arange(segments), np.arange(rings)))  # quad (i, j), row-major
    at = lambda i, j: j * segments + i % segments  # noqa: E731
    quads = np.stack([at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1)], axis=1)
    first, last = len(positions) - 2, len(positions) - 1
    k = np.arange(segments)
    fans = np.concatenate([
        np.stack([np.full(segments, first), at(k + 1, 0), at(k, 0)], axis=1),
        np.stack([np.full(segments, last), at(k, rings), at(k + 1, rings)], axis=1),
    ])
    mesh = bpy.data.meshes.new(name)
    mesh.vertices.add(len(positions))
    mesh.vertices.foreach_set("co", positions.astype(np.float32).ravel())
    corners = np.concatenate([quads.ravel(), fans.ravel()]).astype(np.int32)
    mesh.loops.add(len(corners))
    mesh.loops.foreach_set("vertex_index", corners)
    sizes = np.concatenate([np.full(len(quads), 4), np.full(len(fans), 3)]).astype(np.int32)
    mesh.polygons.add(len(sizes))
    mesh.polygons.foreach_set("loop_start", np.concatenate(([0], np.cumsum(sizes)[:-1])).astype(np.int32))
    mesh.update(calc_edges=True)
    mesh.validate()
    layer = mesh.uv_layers.new(name="UVMap")
    layer.uv.foreach_set("vector", tube_corner_uvs(segments, rings, radius, length).ravel())
    return mesh


def tube_corner_uvs(segments: int, rings: int, radius: float, length: float) -> np.ndarray:
    """``(corners, 2)`` UVs in the corner order of :func:`tube_mesh` (quads, then the two fans).

    Side: u around the tube (the seam at angle 0 gets u = 0 on one side, the full circumference
    on the other), v along it; caps: discs beside the side chart. Every chart is laid out
    counter-clockwise seen from outside the tube, like the faces.
    """
    s = tube_uv_scale(radius, length)
    i, j = np.meshgrid(np.arange(segments), np.arange(rings))  # quad (i, j), row-major like tube_mesh
    i, j = i.ravel(), j.ravel()
    du = 2 * np.pi * radius * s / segments
    dv = length * s / rings
    quad_i = np.stack([i, i + 1, i + 1, i], axis=1)
    quad_j = np.stack([j, j, j + 1, j + 1], axis=1)
    side = np.stack([UV_MARGIN + quad_i * du, UV_MARGIN + quad_j * dv], axis=2).reshape(-1, 2)

    cap_radius = radius * s
    cap_u = UV_MARGIN + 2 * np.pi * radius * s + UV_MARGIN + cap_radius
    angle = 2 * np.pi * np.arange(segments + 1) / segments
    k = np.arange(segments)

    def fan(centre, a, b, mirror):
        # A fan triangle (centre, ring corner a, ring corner b); mirror the disc where the cap
        # faces -X so that its triangles stay counter-clockwise in UV.
        sign = -1.0 if mirror else 1.0
        ring = lambda t: np.stack([centre[0] + sign * cap_radius * np.cos(t), centre[1] + cap_radius * np.sin(t)], 1)  # noqa: E731
        return np.stack([np.broadcast_to(centre, (segments, 2)), ring(angle[a]), ring(angle[b])], axis=1).reshape(-1, 2)

    first = fan(np.array([cap_u, UV_MARGIN + cap_radius]), k + 1, k, mirror=True)
    last = fan(np.array([cap_u, 2 * UV_MARGIN + 3 * cap_radius]), k, k + 1, mirror=False)
    return np.concatenate([side, first, last]).astype(np.float32)


def build_limb(name: str = "Limb", segments: int = 48, rings: int = 64, radius: float = 0.25, length: float = 2.0,
               heat_weights: bool = True):
    """A capped tube along +X with a two-bone armature that bends it at the middle.

    Skin weights by Blender's bone heat (Automatic Weights), or with ``heat_weights=False`` a
    smooth blend over the middle fifth of the tube: bone heat takes minutes on millions of vertices.
    """
    limb = bpy.data.objects.new(name, tube_mesh(name, segments, rings, radius, length))
    bpy.context.collection.objects.link(limb)
    limb.data.shade_smooth()

    bpy.ops.object.armature_add(location=(-length / 2, 0.0, 0.0))
    rig = bpy.context.active_object
    rig.name = f"{name}Rig"
    bpy.ops.object.mode_set(mode="EDIT")
    upper = rig.data.edit_bones[0]
    upper.name = "Upper"
    upper.head, upper.tail = (0, 0, 0), (length / 2, 0, 0)
    lower = rig.data.edit_bones.new("Lower")
    lower.head, lower.tail = (length / 2, 0, 0), (length, 0, 0)
    lower.parent = upper
    lower.use_connect = True
    bpy.ops.object.mode_set(mode="OBJECT")

    bpy.ops.object.select_all(action="DESELECT")
    limb.select_set(True)
    rig.select_set(True)
    bpy.context.view_layer.objects.active = rig
    bpy.ops.object.parent_set(type="ARMATURE_AUTO" if heat_weights else "ARMATURE_NAME")
    if not heat_weights:
        blend_weights(limb, length)
    return limb, rig


def blend_weights(limb, length: float, levels: int = 64) -> None:
    """"Upper"/"Lower" weights by a smoothstep along X over the middle fifth, in ``levels`` steps
    (one ``VertexGroup.add`` call per step and bone instead of one per vertex)."""
    x = np.empty(len(limb.data.vertices) * 3, dtype=np.float32)
    limb.data.vertices.foreach_get("co", x)
    t = np.clip((x[0::3] + length / 10) / (length / 5), 0.0, 1.0)
    level = np.rint(t * t * (3 - 2 * t) * (levels - 1)).astype(np.int64)
    order = np.argsort(level, kind="stable")
    bounds = np.searchsorted(level[order], np.arange(levels + 1))
    upper, lower = limb.vertex_groups["Upper"], limb.vertex_groups["Lower"]
    for k in range(levels):
        members = order[bounds[k]:bounds[k + 1]].tolist()
        if members:
            w = k / (levels - 1)
            upper.add(members, 1.0 - w, "REPLACE")
            lower.add(members, w, "REPLACE")


def animate_bend(rig, frame_start: int = 1, frame_end: int = 24, angle_deg: float = 100.0, twist_deg: float = 0.0) -> None:
    """Bends the lower bone from straight to `angle_deg` (and twists it about its length) over the frame range.

    The bend turns the forearm from +X towards +Y about the elbow at the origin.
    """
    bone = rig.pose.bones["Lower"]
    bone.rotation_mode = "YXZ"  # twist about the bone's own axis (Y) first, then bend
    for frame, bend, twist in ((frame_start, 0.0, 0.0), (frame_end, math.radians(angle_deg), math.radians(twist_deg))):
        bone.rotation_euler = (0.0, twist, bend)
        bone.keyframe_insert("rotation_euler", frame=frame)


def bent_tube(name: str = "Limb", frames: int = 12, angle_deg: float = 150.0):
    """Self Collision's test tube: a capped tube (32 around, 48 along, ~1.6k vertices) bent from
    straight to `angle_deg` over frames 1..`frames` by a two-bone armature whose weights blend over
    the middle fifth; the scene's frame range set to match. Shared by the Blender tests and
    ``bench/record_self_replay.py --tube``, so that a recording is of the tested scene."""
    limb, rig = build_limb(name, segments=32, rings=48, radius=0.25, length=2.0, heat_weights=False)
    animate_bend(rig, 1, frames, angle_deg=angle_deg)
    bpy.context.scene.frame_start, bpy.context.scene.frame_end = 1, frames
    return limb


def pressed_body_centre(angle_deg: float, along: float, body_radius: float, limb_radius: float, depth: float):
    """Where to put a sphere so that the forearm, bent to `angle_deg` about the elbow at the
    origin, reaches `depth` into it at `along` from the elbow; the sphere lies on the side the
    forearm turns towards, so the bend drives the forearm into it."""
    a = math.radians(angle_deg)
    axis = np.array([math.cos(a), math.sin(a), 0.0])
    ahead = np.array([-math.sin(a), math.cos(a), 0.0])  # the direction the bend moves the forearm
    return tuple(along * axis + (body_radius + limb_radius - depth) * ahead)


def pressed_contact_point(angle_deg: float, along: float, centre, body_radius: float):
    """The point of the body's surface nearest the forearm's axis at `along` (where it presses)."""
    a = math.radians(angle_deg)
    on_axis = along * np.array([math.cos(a), math.sin(a), 0.0])
    towards = on_axis - np.asarray(centre)
    return tuple(np.asarray(centre) + body_radius * towards / np.linalg.norm(towards))


def build_body(name: str = "Body", location=(0.9, 0.9, 0.0), radius: float = 0.6):
    """A closed UV sphere (a manifold mesh, so the audit can tell inside from outside)."""
    bpy.ops.mesh.primitive_uv_sphere_add(segments=48, ring_count=24, radius=radius, location=location)
    body = bpy.context.active_object
    body.name = name
    bpy.ops.object.shade_smooth()
    return body


def make_collider(body, collection_name: str = "Colliders", thickness: float = 0.01, friction: float = 0.3,
                  kinetic_friction: float | None = None):
    """Moves `body` into its own collection and sets its Tegument collider settings
    (kinetic friction 0.7 × the static one unless given)."""
    collection = bpy.data.collections.get(collection_name) or bpy.data.collections.new(collection_name)
    if collection.name not in bpy.context.scene.collection.children:
        bpy.context.scene.collection.children.link(collection)
    for owner in list(body.users_collection):
        owner.objects.unlink(body)
    collection.objects.link(body)
    settings = body.tegument_collider
    settings.thickness = thickness
    settings.friction = friction
    settings.kinetic_friction = 0.7 * friction if kinetic_friction is None else kinetic_friction
    return collection


def add_sphere(name: str, centres, *, radius: float = 0.3, thickness: float = 0.01, friction: float = 0.0,
               collection: str = "Colliders"):
    """A UV sphere keyed at every frame to ``centres[frame - 1]``, in a collider collection."""
    bpy.ops.mesh.primitive_uv_sphere_add(segments=32, ring_count=16, radius=radius, location=centres[0])
    sphere = bpy.context.object
    sphere.name = name
    for frame, centre in enumerate(centres, start=1):
        sphere.location = centre
        sphere.keyframe_insert("location", frame=frame)
    make_collider(sphere, collection, thickness, friction, kinetic_friction=friction)
    return sphere


def world_mesh(obj, frame: int) -> tuple[np.ndarray, np.ndarray]:
    """World positions and triangles of `obj` evaluated at `frame`, read without the add-on."""
    bpy.context.scene.frame_set(frame)
    evaluated = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
    mesh = evaluated.to_mesh()
    mesh.calc_loop_triangles()
    local = np.array([v.co[:] for v in mesh.vertices], dtype=np.float64)
    triangles = np.array([t.vertices[:] for t in mesh.loop_triangles], dtype=np.int32)
    evaluated.to_mesh_clear()
    m = np.array(evaluated.matrix_world)
    return (local @ m[:3, :3].T + m[:3, 3]).astype(np.float32), triangles


def tube_side_chart(size: int, radius: float, length: float) -> np.ndarray:
    """``(size, size)`` bool: the texels of the tube's side chart (row 0 = v = 0)."""
    s = tube_uv_scale(radius, length)
    c = (np.arange(size) + 0.5) / size
    u, v = np.meshgrid(c, c)
    return (u > UV_MARGIN) & (u < UV_MARGIN + 2 * math.pi * radius * s) & (v > UV_MARGIN) & (v < UV_MARGIN + length * s)


def scale_pattern(size: int, radius: float, length: float, spacing: float = 0.16, scale_radius: float = 0.045,
                  rigid_margin: float = 1.25):
    """Round scales over the tube's side chart, painted in numpy: ``(colour RGBA, rigidity)``,
    ``(size, size, 4)`` and ``(size, size)`` float32, row 0 = v = 0 (Blender's pixel order).

    Scales sit on a grid, a whole number of them around the tube with the seam half-way between two
    columns, so the pattern closes over the seam and no scale is cut by it (a chart border, which
    the warp keeps fixed). Each carries a light stripe along the tube, which shows shear and
    rotation. Sizes are in scene units on the rest surface; rigidity covers each scale and a margin
    (``rigid_margin`` times its radius) so the skin around it takes the stretch.
    """
    s = tube_uv_scale(radius, length)
    around = max(3, round(2 * math.pi * radius / spacing))
    step_u = 2 * math.pi * radius * s / around
    rows = max(1, int(length / spacing))
    step_v = length * s / rows
    c = (np.arange(size) + 0.5) / size
    u, v = np.meshgrid(c, c)
    # Offsets from the nearest scale centre, at ((k + ½) step_u, (j + ½) step_v) from the chart corner.
    du = (u - UV_MARGIN) - (np.floor((u - UV_MARGIN) / step_u) + 0.5) * step_u
    dv = (v - UV_MARGIN) - (np.clip(np.floor((v - UV_MARGIN) / step_v), 0, rows - 1) + 0.5) * step_v
    best, along = np.hypot(du, dv), du
    side = tube_side_chart(size, radius, length)
    r = scale_radius * s
    scale = side & (best < r)
    stripe = scale & (np.abs(along) < 0.22 * r)
    rim = scale & (best > 0.8 * r)
    colour = np.empty((size, size, 4), np.float32)
    colour[...] = (0.80, 0.58, 0.46, 1.0)  # skin
    colour[scale] = (0.10, 0.32, 0.42, 1.0)
    colour[rim] = (0.05, 0.16, 0.22, 1.0)
    colour[stripe] = (0.92, 0.86, 0.55, 1.0)
    rigidity = (side & (best < rigid_margin * r)).astype(np.float32)
    return colour, rigidity


def image_from_pixels(name: str, pixels: np.ndarray, *, is_data: bool) -> bpy.types.Image:
    """A packed image from ``(h, w, 4)`` RGBA or ``(h, w)`` grey pixels (saved inside the .blend)."""
    if pixels.ndim == 2:
        grey = pixels
        pixels = np.ones(grey.shape + (4,), np.float32)
        pixels[..., :3] = grey[..., None]
    height, width = pixels.shape[:2]
    image = bpy.data.images.new(name, width, height, alpha=True, float_buffer=is_data, is_data=is_data)
    image.pixels.foreach_set(np.ascontiguousarray(pixels, np.float32).ravel())
    image.pack()
    return image


def skin_material(obj, colour: bpy.types.Image) -> tuple[bpy.types.Material, bpy.types.Node]:
    """Principled BSDF whose base colour is the scale texture, looked up through a UV Map node;
    returns the material and the texture node (whose Vector input the demo relinks)."""
    material = bpy.data.materials.new(f"{obj.name}Skin")
    obj.data.materials.append(material)
    tree = material.node_tree
    bsdf = tree.nodes.get("Principled BSDF")
    texture = tree.nodes.new("ShaderNodeTexImage")
    texture.name = "Scales"
    texture.image = colour
    texture.interpolation = "Linear"
    uv = tree.nodes.new("ShaderNodeUVMap")
    uv.name = "UV"
    uv.uv_map = "UVMap"
    tree.links.new(uv.outputs["UV"], texture.inputs["Vector"])
    tree.links.new(texture.outputs["Color"], bsdf.inputs["Base Color"])
    bsdf.inputs["Roughness"].default_value = 0.55
    return material, texture


def body_material(obj) -> bpy.types.Material:
    """Grey clay; its Principled BSDF's Alpha can make the body see-through (see :func:`set_alpha`)."""
    material = bpy.data.materials.new(f"{obj.name}Clay")
    material.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = (0.55, 0.57, 0.62, 1.0)
    obj.data.materials.append(material)
    return material


def set_alpha(material: bpy.types.Material, alpha: float) -> None:
    material.node_tree.nodes["Principled BSDF"].inputs["Alpha"].default_value = alpha


def add_camera(name: str, location, target, lens: float = 50.0):
    data = bpy.data.cameras.new(name)
    data.lens = lens
    camera = bpy.data.objects.new(name, data)
    bpy.context.scene.collection.objects.link(camera)
    camera.location = location
    direction = np.subtract(target, location)
    camera.rotation_euler = _look_at(direction)
    return camera


def _look_at(direction):
    from mathutils import Vector

    return Vector(direction).to_track_quat("-Z", "Y").to_euler()


def add_camera_and_light(location=(0.2, -2.9, 3.6), target=(0.2, 0.3, 0.0)):
    """The scene's camera, looking from `location` at `target`; a sun and a dim world."""
    camera = add_camera("Camera", location, target, lens=50.0)
    bpy.context.scene.camera = camera
    bpy.ops.object.light_add(type="SUN", location=(0, 0, 5), rotation=(math.radians(25), math.radians(-20), 0))
    bpy.context.active_object.data.energy = 3.0
    world = bpy.data.worlds.new("DemoWorld")
    world.color = (0.05, 0.05, 0.06)
    bpy.context.scene.world = world
    return camera
