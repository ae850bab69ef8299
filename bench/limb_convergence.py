"""Converge on small meshes (issue 28): the demo's armature limb bent 90°, solved cold through the
wheel at a few iteration counts, against the same solve run to a standstill.

    .venv/bin/python bench/limb_convergence.py            # the sizes of docs/performance.md

Prints one line per limb size and closeness: the convergence error (RMS |x_k − x_inf| / RMS
|x_inf − input|) at 5, 6, 10 and 50 accelerated iterations, and with the add-on's Converge settings
(its tolerance and iteration limit) with the iterations the stopping rule let it take.
"""

from __future__ import annotations

import pathlib
import sys

ROOT = pathlib.Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "demo"))

# (segments around, rings along): 6,210 / 2,442 / 1,570 / 206 vertices.
LIMBS = ((64, 96), (40, 60), (32, 48), (12, 16))
ITERATIONS = (5, 6, 10, 50)


def main() -> int:
    import bpy
    import measures
    import numpy as np
    import scene as demo_scene
    import tegument

    for segments, rings in LIMBS:
        bpy.ops.wm.read_factory_settings(use_empty=True)
        limb, rig = demo_scene.build_limb(segments=segments, rings=rings)
        demo_scene.animate_bend(rig, 1, 6, angle_deg=90)
        bpy.context.scene.frame_set(6)
        evaluated = limb.evaluated_get(bpy.context.evaluated_depsgraph_get())
        source = np.empty((len(evaluated.data.vertices), 3), np.float32)
        evaluated.data.attributes["position"].data.foreach_get("vector", source.ravel())
        mesh = limb.data
        rest = np.empty((len(mesh.vertices), 3), np.float32)
        mesh.attributes["position"].data.foreach_get("vector", rest.ravel())
        corners = np.array([loop.vertex_index for loop in mesh.loops], np.int32)
        sizes = np.array([polygon.loop_total for polygon in mesh.polygons], np.int32)
        deformer = tegument.PyramidDeformer(rest, corners, sizes, scale_safe=True)
        deformer.accelerated = True
        for closeness in (0.05, 0.01):
            x_inf = deformer.solve(source, iterations=2000, closeness=closeness)
            errors = [measures.convergence_error(deformer.solve(source, iterations=k, closeness=closeness), x_inf, source)[0]
                      for k in ITERATIONS]
            deformer.tolerance = tegument.DEFAULTS.tolerance
            stopped = deformer.solve(source, iterations=tegument.DEFAULTS.accelerated_iterations, closeness=closeness)
            took, deformer.tolerance = deformer.last_iterations, None
            print(f"{len(rest):>6} vertices, closeness {closeness}: "
                  + ", ".join(f"{k} it. {100 * e:.1f} %" for k, e in zip(ITERATIONS, errors))
                  + f"; Converge default {100 * measures.convergence_error(stopped, x_inf, source)[0]:.1f} % in {took} it.",
                  flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
