"""The demo's flesh part: Pyramid Deform's dynamics, compliant colliders and strain limits.

Three small scenes, each in its own fresh file (``out/demo/flesh/<scene>.blend``, so the add-on's
``//`` cache paths land beside it), built with Blender's operators and baked through the installed
extension, as ``blender_tests/test_flesh.py`` builds them (the logic is copied, not imported: the
demo must not depend on the test suite's layout). Every figure comes from what Blender plays back:
the skin's PC2 cache and, for a compliant collider, its Tegument Compliance modifier; penetrations
are counted a second time with ``tegument.audit``, independently of the bake's own totals.

Each scene gives one matplotlib picture and a dict for ``report.json``.
"""

from __future__ import annotations

import pathlib

import bpy
import extension
import numpy as np
from scene import add_sphere, world_mesh

FPS = 24
AUDIT_KEYS = ("vertices_inside", "edges_crossing", "collider_edges_crossing")


# --- Scene plumbing -----------------------------------------------------------------------------

def fresh_file(folder: pathlib.Path, name: str, frames: int) -> None:
    """An empty scene saved as ``folder/name.blend``, with the extension enabled."""
    extension.new_blend(folder / f"{name}.blend")
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, frames
    scene.render.fps, scene.render.fps_base = FPS, 1.0


def grid(subdivisions: int, size: float, name: str = "Skin"):
    bpy.ops.mesh.primitive_grid_add(x_subdivisions=subdivisions, y_subdivisions=subdivisions, size=size)
    skin = bpy.context.object
    skin.name = name
    return skin


def add_deform(skin, frames: int, **settings) -> None:
    bpy.context.view_layer.objects.active = skin
    if bpy.ops.tegument.deform_add() != {"FINISHED"}:
        raise RuntimeError("Add Pyramid Deform failed")
    skin.tegument.frame_start, skin.tegument.frame_end = 1, frames
    for key, value in settings.items():
        setattr(skin.tegument, key, value)


def bake(skin, cache_path: str) -> np.ndarray:
    """Bakes into `cache_path` (one file per variant, so every cache of the demo stays on disk)."""
    from bl_ext.user_default.tegument import pc2

    skin.tegument.cache_path = cache_path
    bpy.context.view_layer.objects.active = skin
    if bpy.ops.tegument.bake() != {"FINISHED"}:
        raise RuntimeError(f"the bake of {skin.name} failed (its message is above)")
    cache = pc2.read(bpy.path.abspath(skin.tegument.cache_path))[0]
    if not np.isfinite(cache).all():
        raise RuntimeError(f"the bake of {skin.name} holds non-finite positions")
    return cache.copy()


def rest_of(obj) -> np.ndarray:
    return np.array([v.co[:] for v in obj.data.vertices], dtype=np.float32)


def independent_audit(tegument, skin, cache, colliders) -> dict[str, int]:
    """Totals of ``tegument.audit`` over the cached frames against the colliders as played back."""
    mesh = skin.data
    corners = np.array([loop.vertex_index for loop in mesh.loops], dtype=np.int32)
    sizes = np.array([p.loop_total for p in mesh.polygons], dtype=np.int32)
    m = np.array(skin.matrix_world)
    totals = dict.fromkeys(AUDIT_KEYS, 0)
    for k, frame_positions in enumerate(cache):
        world = (frame_positions.astype(np.float64) @ m[:3, :3].T + m[:3, 3]).astype(np.float32)
        bodies = [tegument.Collider(*world_mesh(c, k + 1), thickness=0.0, friction=0.0) for c in colliders]
        found = tegument.audit(world, corners, sizes, bodies)
        for key in totals:
            totals[key] += int(getattr(found, key))
    return totals


def bake_audit(skin) -> dict[str, int]:
    s = skin.tegument
    return {"vertices_inside": s.audit_vertices_inside, "edges_crossing": s.audit_edges_crossing,
            "collider_edges_crossing": s.audit_collider_edges_crossing, "pinched_vertices": s.pinched_vertices}


def pyplot():
    import matplotlib

    matplotlib.use("Agg")  # no display in the demo's Blender
    import matplotlib.pyplot as plt

    return plt


# --- Dynamics -----------------------------------------------------------------------------------

MOTION = 0.5  # the object slides this far along x over frames 1–7, then stops
DYNAMICS_FRAMES = 96  # 4 s at 24 fps: long enough to settle with damping 1


def dynamics(folder: pathlib.Path, out: pathlib.Path) -> dict:
    fresh_file(folder, "dynamics", DYNAMICS_FRAMES)
    skin = grid(10, 1.0)
    edit = bpy.context.preferences.edit
    interpolation, edit.keyframe_new_interpolation_type = edit.keyframe_new_interpolation_type, "LINEAR"
    try:
        for frame in (1, 7):
            skin.location.x = MOTION * (frame - 1) / 6
            skin.keyframe_insert("location", index=0, frame=frame)
    finally:
        edit.keyframe_new_interpolation_type = interpolation
    add_deform(skin, DYNAMICS_FRAMES, closeness=0.1, dynamic=True, mass=1.0, damping=1.0)
    rest = rest_of(skin)
    variants = {}
    for label, mass, substeps in (("mass 1, 1 substep", 1.0, 1), ("mass 1, 4 substeps", 1.0, 4), ("mass 4, 1 substep", 4.0, 1)):
        skin.tegument.mass, skin.tegument.substeps = mass, substeps
        cache = bake(skin, f"//tegument/dynamics_mass{mass:g}_sub{substeps}.pc2")
        variants[label] = cache
    skin.tegument.mass, skin.tegument.substeps = 1.0, 1
    bake(skin, "//tegument/dynamics.pc2")  # the saved file plays the plain variant back
    bpy.ops.wm.save_mainfile()

    # Object space: the flesh behind its input is at negative x, ahead of it (overshoot) at positive x.
    offsets = {label: (cache[:, :, 0] - rest[:, 0]).mean(axis=1) for label, cache in variants.items()}
    one, four = variants["mass 1, 1 substep"], variants["mass 1, 4 substeps"]
    substep_gap = float(np.linalg.norm(one - four, axis=2).max())
    substep_gap_last = float(np.linalg.norm(one[-1] - four[-1], axis=1).max())
    frames = np.arange(1, DYNAMICS_FRAMES + 1)

    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7.0, 3.8), dpi=100)
    ax.axvspan(1, 7, color="0.92", label="input moving")
    styles = {"mass 1, 1 substep": {"color": "tab:blue", "lw": 2.4},
              "mass 1, 4 substeps": {"color": "tab:orange", "lw": 1.2, "ls": "--"},
              "mass 4, 1 substep": {"color": "tab:green", "lw": 1.4, "alpha": 0.8}}
    for label, offset in offsets.items():
        ax.plot(frames, offset, label=label, **styles[label])
    ax.axhline(0.0, color="0.3", lw=0.8)
    ax.set_xlim(1, DYNAMICS_FRAMES)
    ax.set_xlabel("frame (24 fps)")
    ax.set_ylabel("mean offset from the input along x")
    # Said as measured: the substeps agree on where the flesh comes to rest, not on the swing
    # (backward Euler's own damping shrinks with the substep's length).
    ax.set_title(f"Dynamics: a patch slides {MOTION} and stops; the flesh lags, overshoots, settles\n"
                 f"closeness 0.1, damping 1. 1 vs 4 substeps: {substep_gap_last:.4f} apart at the end, "
                 f"{substep_gap:.2f} at most (4 swing more)", fontsize=9)
    ax.legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    picture = out / "flesh_dynamics.png"
    fig.savefig(picture)
    plt.close(fig)

    base = offsets["mass 1, 1 substep"]
    heavy = offsets["mass 4, 1 substep"]
    return {
        "picture": str(picture), "frames": DYNAMICS_FRAMES, "motion": MOTION, "vertices": len(rest),
        "closeness": 0.1, "damping": 1.0,
        "lag_while_moving": round(float(base[:7].min()), 5),
        "peak_overshoot": round(float(base[7:].max()), 5),
        "peak_overshoot_frame": int(frames[7:][np.argmax(base[7:])]),
        "settle_error": round(float(abs(base[-1])), 6),
        "mass_4": {"peak_overshoot": round(float(heavy[7:].max()), 5), "settle_error": round(float(abs(heavy[-1])), 6)},
        "substeps_1_vs_4_max_difference": round(substep_gap, 6),
        "substeps_1_vs_4_last_frame_difference": round(substep_gap_last, 6),
    }


# --- Compliant colliders ------------------------------------------------------------------------

COMPLIANCE_FRAMES = 12  # the arm goes down over 8 frames, then holds: the picture is of the settled result


def plane_section(positions: np.ndarray, triangles: np.ndarray, y: float = 0.0) -> np.ndarray:
    """Segments ``(S, 2, 2)`` (x, z) where the triangles cross the plane ``Y = y``."""
    p = positions[triangles].astype(np.float64)  # (T, 3, 3)
    d = p[:, :, 1] - y
    segments = []
    for tri, dist in zip(p, d):
        points = []
        for a, b in ((0, 1), (1, 2), (2, 0)):
            if (dist[a] < 0) != (dist[b] < 0):
                t = dist[a] / (dist[a] - dist[b])
                q = tri[a] + t * (tri[b] - tri[a])
                points.append((q[0], q[2]))
        if len(points) == 2:
            segments.append(points)
    return np.array(segments).reshape(-1, 2, 2)


def compliance(folder: pathlib.Path, out: pathlib.Path, tegument) -> dict:
    frames = COMPLIANCE_FRAMES
    fresh_file(folder, "compliance", frames)
    skin = grid(30, 1.6)
    torso = add_sphere("Torso", [(0.0, 0.0, -0.32)] * frames)
    # 0.2 deeper into the torso than the skin between them allows.
    arm = add_sphere("Arm", [(0.0, 0.0, 0.5 - 0.05 * min(k, 8)) for k in range(frames)])
    soft = arm.vertex_groups.new(name="Soft")
    soft.add([v.index for v in arm.data.vertices if v.co.z < 0.05], 1.0, "REPLACE")
    arm.tegument_collider.stiffness = 100.0
    add_deform(skin, frames, closeness=0.2)
    skin.tegument.collider_collection = bpy.data.collections["Colliders"]
    bpy.ops.wm.save_mainfile()

    rows = np.abs(rest_of(skin)[:, 1])
    row = rows <= rows.min() + 1e-6  # the skin's row of vertices nearest the section plane
    results = {}
    for label, group in (("kinematic", ""), ("compliant", "Soft")):
        arm.tegument_collider.compliant_group = group
        cache = bake(skin, f"//tegument/compliance_{label}.pc2")
        own = bake_audit(skin)
        independent = independent_audit(tegument, skin, cache, [torso, arm])
        arm_now, arm_triangles = world_mesh(arm, frames)
        torso_now, torso_triangles = world_mesh(torso, frames)
        entry = {"bake_audit": own, "independent_audit": independent, "warnings": skin.tegument.warnings,
                 "max_recession": round(float(skin.tegument.max_recession), 5)}
        if group:
            modifier = arm.modifiers.get("Tegument Compliance")
            if modifier is None:
                raise RuntimeError("a compliant bake left the arm without its Tegument Compliance modifier")
            modifier.show_viewport = False  # the arm as animated, to measure how far it gave way
            animated, _ = world_mesh(arm, frames)
            modifier.show_viewport = True
            recession = np.linalg.norm(arm_now - animated, axis=1)
            skin_top = float(cache[-1][np.linalg.norm(cache[-1][:, :2], axis=1) < 0.05, 2].max())
            entry.update(played_back_recession=round(float(recession.max()), 5),
                         arm_lowest=round(float(arm_now[:, 2].min()), 5), skin_top_under_arm=round(skin_top, 5),
                         gap=round(float(arm_now[:, 2].min()) - skin_top, 5),
                         arm_cache=bpy.path.abspath(modifier.filepath))
            entry["animated_section"] = plane_section(animated, arm_triangles)
        entry["sections"] = {"arm": plane_section(arm_now, arm_triangles), "torso": plane_section(torso_now, torso_triangles)}
        profile = cache[-1][row]
        entry["profile"] = profile[np.argsort(profile[:, 0])]
        results[label] = entry
    bpy.ops.wm.save_mainfile()  # the file plays the compliant bake back, receded arm included

    from matplotlib.collections import LineCollection

    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(8.0, 4.4), dpi=100, sharey=True)
    for ax, label in zip(axes, ("kinematic", "compliant")):
        entry = results[label]
        ax.add_collection(LineCollection(entry["sections"]["torso"], colors="0.45", lw=1.5))
        if "animated_section" in entry:
            ax.add_collection(LineCollection(entry["animated_section"], colors="tab:red", lw=0.8, linestyles="dotted"))
            ax.plot([], [], color="tab:red", lw=0.8, ls=":", label="arm as animated")
        ax.add_collection(LineCollection(entry["sections"]["arm"], colors="tab:red", lw=1.5))
        ax.plot(entry["profile"][:, 0], entry["profile"][:, 2], color="tab:blue", lw=1.8, marker=".", ms=3)
        ax.plot([], [], color="tab:red", lw=1.5, label="arm (played back)")
        ax.plot([], [], color="0.45", lw=1.5, label="torso (kinematic)")
        ax.plot([], [], color="tab:blue", lw=1.8, label="skin (cache)")
        penetrations = sum(entry["independent_audit"].values())
        if label == "kinematic":
            title = f"kinematic arm: {entry['bake_audit']['pinched_vertices']} pinched\n(audit: {penetrations} penetrations)"
        else:
            title = f"compliant arm: {penetrations} penetrations\n(receded {entry['played_back_recession']:.3f}, gap {entry['gap']:.3f})"
        ax.set_title(title, fontsize=10)
        ax.set_aspect("equal")
        ax.set_xlim(-0.62, 0.62)
        ax.set_ylim(-0.68, 0.9)
        ax.set_xlabel("x")
        ax.legend(fontsize=7, loc="upper right", ncol=2, framealpha=0.9)
    axes[0].set_ylabel("z (section at y = 0)")
    fig.suptitle(f"Compliant colliders: the arm is animated 0.2 deeper than the skin allows (frame {frames})", fontsize=10)
    fig.tight_layout()
    picture = out / "flesh_compliance.png"
    fig.savefig(picture)
    plt.close(fig)

    for entry in results.values():
        for key in ("sections", "profile", "animated_section"):
            entry.pop(key, None)
    return {"picture": str(picture), "frames": frames, "skin_vertices": len(skin.data.vertices),
            "stiffness": 100.0, "closeness": 0.2, **results}


# --- Strain limits ------------------------------------------------------------------------------

EPS = 0.1


def strain(folder: pathlib.Path, out: pathlib.Path, tegument) -> dict:
    # A rough sphere pressed into the skin, then dragged sideways (seed 002, Figure 1).
    rise = [(-0.3, 0.0, -0.32 + 0.03 * k) for k in range(6)]
    centres = rise + [(-0.3 + 0.05 * k, 0.0, rise[-1][2]) for k in range(1, 9)]
    frames = len(centres)
    fresh_file(folder, "strain", frames)
    skin = grid(40, 2.0)
    sphere = add_sphere("Rough", centres, friction=2.0)
    add_deform(skin, frames, closeness=0.5)
    skin.tegument.collider_collection = bpy.data.collections["Colliders"]
    bpy.ops.wm.save_mainfile()

    mesh = skin.data
    edges = np.array([e.vertices[:] for e in mesh.edges])
    rest = rest_of(skin)

    def length(x):
        return np.linalg.norm(x[edges[:, 0]] - x[edges[:, 1]], axis=1)

    rest_length = length(rest)
    polygons = [list(p.vertices) for p in mesh.polygons]
    # Each face takes the worst stretch of its edges, so a single overstretched edge shows.
    edge_index = {tuple(sorted(e)): k for k, e in enumerate(edges.tolist())}
    face_edges = [[edge_index[tuple(sorted((p[i], p[(i + 1) % len(p)])))] for i in range(len(p))] for p in polygons]

    variants = (("no limit", {"limit_stretch": False}),
                ("UNIFIED", {"limit_stretch": True, "max_stretch": EPS, "strain_mode": "UNIFIED"}),
                ("POST", {"limit_stretch": True, "max_stretch": EPS, "strain_mode": "POST"}))
    results, shown = {}, {}
    for label, settings in variants:
        for key, value in settings.items():
            setattr(skin.tegument, key, value)
        cache = bake(skin, f"//tegument/strain_{label.replace(' ', '_').lower()}.pc2")
        ratios = np.stack([length(frame) / rest_length for frame in cache])
        worst_frame = int(np.argmax(ratios.max(axis=1)))
        results[label] = {
            "worst_stretch": round(float(ratios.max()), 5), "worst_stretch_frame": worst_frame + 1,
            "reported_worst_stretch": round(float(skin.tegument.worst_stretch), 5),
            "edge_frames_over_limit_by_1pct": int((ratios > (1.0 + EPS) * 1.01).sum()),
            "bake_audit": bake_audit(skin), "independent_audit": independent_audit(tegument, skin, cache, [sphere]),
            "warnings": skin.tegument.warnings,
        }
        shown[label] = (cache[-1], ratios[-1])
    bpy.ops.wm.save_mainfile()  # the file plays the POST bake back (the last one)

    from matplotlib.collections import PolyCollection

    plt = pyplot()
    # The limit in the middle of the scale: limited skin stays in its lower half, and the
    # unlimited stretch (far past it) saturates instead of flattening everything else.
    top = 1.0 + 2 * EPS
    fig, axes = plt.subplots(1, 3, figsize=(11.0, 4.6), dpi=100)
    for ax, (label, _) in zip(axes, variants):
        positions, ratio = shown[label]
        faces = [positions[p][:, :2] for p in polygons]
        colours = np.array([ratio[f].max() for f in face_edges])
        collection = PolyCollection(faces, array=colours, cmap="magma", edgecolors="face", linewidths=0.2)
        collection.set_clim(1.0, top)
        ax.add_collection(collection)
        centre = centres[-1]
        ax.add_patch(plt.Circle(centre[:2], 0.3, fill=False, color="tab:cyan", lw=1.0, ls="--"))
        entry = results[label]
        penetrations = sum(entry["independent_audit"].values())
        audit = entry["independent_audit"]
        heading = "no limit" if label == "no limit" else f'{label}, max stretch {EPS:g}'
        ax.set_title(f"{heading}\nworst stretch {entry['worst_stretch']:.3f}\naudit: {penetrations} penetrations\n"
                     f"({audit['vertices_inside']} vertices, {audit['edges_crossing'] + audit['collider_edges_crossing']} edges)",
                     fontsize=9)
        ax.set_aspect("equal")
        ax.set_xlim(-1.0, 0.6)
        ax.set_ylim(-0.65, 0.65)
        ax.set_xticks([])
        ax.set_yticks([])
    fig.subplots_adjust(left=0.02, right=0.86, top=0.74, bottom=0.03, wspace=0.06)
    bar = fig.colorbar(collection, cax=fig.add_axes([0.88, 0.08, 0.015, 0.62]), extend="max")
    bar.ax.axhline(1.0 + EPS, color="tab:cyan", lw=1.5)
    bar.set_label("edge length / rest (worst edge of each face)")
    fig.suptitle(f"Strain limits: a rough sphere (friction 2, dashed) pressed in and dragged +x; top view, frame {frames}",
                 fontsize=10)
    picture = out / "flesh_strain.png"
    fig.savefig(picture)
    plt.close(fig)
    return {"picture": str(picture), "frames": frames, "skin_vertices": len(rest), "max_stretch": EPS,
            "friction": 2.0, "closeness": 0.5, **results}


def run(out: pathlib.Path, tegument, stage) -> dict:
    """All three scenes; `stage` is the demo's timer. Replaces the open file: run it last."""
    folder = out / "flesh"
    report = {}
    with stage("flesh_dynamics") as info:
        report["dynamics"] = dynamics(folder, out)
        info["picture"] = report["dynamics"]["picture"]
    with stage("flesh_compliance") as info:
        report["compliance"] = compliance(folder, out, tegument)
        info["picture"] = report["compliance"]["picture"]
    with stage("flesh_strain") as info:
        report["strain"] = strain(folder, out, tegument)
        info["picture"] = report["strain"]["picture"]
    return report
