"""Records the hard-posed MakeHuman character's Bake with Self Collision as the add-on runs it, for
``rust/core/examples/self_replay.rs`` to replay through the core without Blender (issue 30).

What it records is exactly what the Bake operator hands the wheel: the bind's rest positions and
polygons, each frame's world-space input to ``PyramidDeformer.step``, the iterations, closeness,
Converge, tolerance and the Self Collision settings. The deformer's ``step`` is wrapped only to
record its arguments; each frame is then solved plainly (``solve``: fast, the recording does not
need the step's result, only the next frame's input, which the armature gives). The file is written
outside the project tree (a new temporary directory unless a path is given); nothing here enters
``make bench`` or CI.

    make extension
    .venv/bin/python bench/record_self_replay.py dist/tegument-0.1.0-linux_x64.zip [out.replay] [--tube]
    cargo run --release -p tegument-core --example self_replay -- <out.replay> [frames]

Needs ``../shared/data/makehuman`` (as the character bench does). The layout of the file is in the
example's header. With ``--tube`` it records instead the Blender test's tube
(``demo/scene.py::bent_tube``, the scene of ``blender_tests/test_self_collision.py``: a capped tube of 32 × 48 bent 150° over 12
frames by a two-bone armature), the scene whose frame 9 spiked under a stopping rule the core's own
copy of the tube did not reproduce (issue 30, twenty-first round).
"""

import importlib
import pathlib
import sys
import tempfile

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parent.parent


def record(zip_path: pathlib.Path, out: pathlib.Path, tube: bool = False) -> None:
    sys.path.insert(0, str(ROOT / "demo"))
    import extension

    user = extension.isolated_user_folder("tegument-replay-user-")
    import character_demo

    addon = extension.install(zip_path, user)
    workdir = pathlib.Path(tempfile.mkdtemp(prefix="tegument-replay-"))
    extension.new_blend(workdir / "replay.blend")
    bake = importlib.import_module(addon + ".deform.bake")
    evaluate = importlib.import_module(addon + ".deform.evaluate")
    frames: list[np.ndarray] = []
    seen: dict = {}

    class Recorder:
        """The deformer, with ``step`` recorded and answered by a plain solve."""

        def __init__(self, real):
            object.__setattr__(self, "_real", real)

        def __getattr__(self, name):
            return getattr(self._real, name)

        def __setattr__(self, name, value):
            seen[name] = value
            setattr(self._real, name, value)

        def step(self, world, colliders, iterations, closeness, out=None, **options):
            if colliders is not None:
                raise RuntimeError("the replay records self-collision alone; the scene has colliders")
            settings = options.pop("self_collision")
            if options:
                raise RuntimeError(f"the replay does not record these step options: {sorted(options)}")
            if getattr(settings, "weights", None) is not None:
                raise RuntimeError("the replay records Self Collision without a vertex group")
            frames.append(np.array(world, dtype=np.float32))
            seen.update(iterations=iterations, closeness=closeness, self_collision=settings)
            return self._real.solve(world, iterations=iterations, closeness=closeness, out=out)

    solve_frame = bake.solve_frame
    bake.solve_frame = lambda scene, obj, frame, deformer, *a, **k: solve_frame(scene, obj, frame, Recorder(deformer), *a, **k)
    if tube:
        import scene

        obj = scene.bent_tube()
        character_demo.add_and_bake(obj, "//replay.pc2", frames=(1, 12), self_collision=True)
    else:
        obj, _ = character_demo.build("obj", workdir)
        character_demo.add_and_bake(obj, "//replay.pc2", self_collision=True)
    rest, corners, sizes = evaluate.bound_mesh(obj)
    settings = seen["self_collision"]
    closeness, tolerance = seen["closeness"], seen.get("tolerance")
    head = np.zeros(16, np.uint32)
    head[:6] = [len(rest), len(corners), len(sizes), len(frames), seen["iterations"], int(bool(seen.get("accelerated")))]
    words = head.view(np.float32)
    words[6] = np.nan if tolerance is None else float(tolerance)
    words[7] = np.nan if closeness is None else float(closeness)
    words[8], words[9], words[10] = settings.thickness, settings.friction, settings.kinetic_friction
    head[11], head[12] = settings.rings, int(bool(obj.tegument.scale_safe))
    with open(out, "wb") as f:
        for part, dtype in ((head, "<u4"), (rest, "<f4"), (corners, "<u4"), (sizes, "<u4"), (np.stack(frames), "<f4")):
            f.write(np.ascontiguousarray(part, dtype=dtype).tobytes())
    print(f"{out}: {len(rest)} vertices, {len(sizes)} polygons, {len(frames)} frames, {seen['iterations']} iterations")


if __name__ == "__main__":
    tube = "--tube" in sys.argv[1:]
    arguments = [a for a in sys.argv[1:] if a != "--tube"]
    if len(arguments) not in (1, 2):
        sys.exit(__doc__)
    name = "tube.replay" if tube else "character.replay"
    target = pathlib.Path(arguments[1]) if len(arguments) == 2 else pathlib.Path(tempfile.mkdtemp(prefix="tegument-replay-")) / name
    if target.resolve().is_relative_to(ROOT):
        sys.exit(f"{target}: write the recording outside the project tree")
    record(pathlib.Path(arguments[0]), target, tube)
