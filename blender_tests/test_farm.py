"""Farm bakes end to end: a scene's `list-bakes` JSON, the Flamenco job type compiled from it, and
every task of the job run as a worker runs it — each in a fresh process through the `bpy` CLI
entry point (``farm_worker.py``), in dependency order, two at a time on this two-core machine —
against a single local bake of the same .blend.

- Pyramid Deform caches: byte for byte the local bake's.
- UV Warp sequences: chunks that start cold after a pre-roll stay within the convergence
  tolerance of issue 28 (5 %) of the bake that ran through, measured on the redirection texture.
- A task killed mid-way (SIGKILL, no clean-up) and run again leaves the cache a clean run leaves.
"""

from __future__ import annotations

import json
import os
import pathlib
import subprocess
import sys
import time

import bpy
import numpy as np
import pytest

from test_farm_job_type import compile_job, node_executable
from test_robustness import addon, mesh_object
from test_uv_warp_node import disc, float_image

HERE = pathlib.Path(__file__).resolve().parent
WORKER = HERE / "farm_worker.py"
FRAMES = (1, 48)
CHUNK = 12
WARP_RES = 64
TOLERANCE = 0.05  # convergence error of issue 28
NODE = "Tegument UV Warp"


# ------------------------------------------------------------------ the scene

def squash_keys(obj, name: str, scale: tuple[float, float, float], values: dict[int, float]) -> None:
    """A shape key scaling the mesh by ``scale``, keyed at ``values`` (frame: value)."""
    if obj.data.shape_keys is None:
        obj.shape_key_add(name="Basis")
    key = obj.shape_key_add(name=name)
    co = np.empty(len(key.data) * 3, np.float32)
    key.data.foreach_get("co", co)
    key.data.foreach_set("co", (co.reshape(-1, 3) * np.array(scale, np.float32)).ravel())
    for frame, value in values.items():
        key.value = value
        key.keyframe_insert("value", frame=frame)


def grid(name: str, n: int) -> bpy.types.Object:
    """An n × n quad grid over [-1, 1]², UV-mapped over the unit square."""
    c = np.linspace(-1.0, 1.0, n + 1)
    x, y = np.meshgrid(c, c)
    vertices = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], 1)
    faces = [(j * (n + 1) + i, j * (n + 1) + i + 1, (j + 1) * (n + 1) + i + 1, (j + 1) * (n + 1) + i)
             for j in range(n) for i in range(n)]
    obj = mesh_object(name, vertices, faces)
    layer = obj.data.uv_layers.new(name="UVMap")
    corners = np.array([loop.vertex_index for loop in obj.data.loops])
    layer.uv.foreach_set("vector", ((vertices[corners, :2] + 1) / 2).astype(np.float32).ravel())
    return obj


def build_scene(tmp_path: pathlib.Path) -> pathlib.Path:
    """Two deformed characters and a UV Warp node over 48 frames, saved as ``tmp_path/shot.blend``.

    Alice: a skin patch squashed and stretched by a shape key, with dynamics (her frames carry
    history), and the UV Warp node of material Skin on her. Bob: a ball that bulges into a
    wall (collisions: history too).
    """
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = FRAMES
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "shot.blend"))

    alice = grid("Alice", 12)
    squash_keys(alice, "Squash", (0.5, 1.0, 1.0), {1: 0.0, 14: 1.0, 30: 0.2, 48: 0.9})
    assert bpy.ops.tegument.deform_add() == {"FINISHED"}
    alice.tegument.frame_start, alice.tegument.frame_end = FRAMES
    alice.tegument.dynamic = True
    alice.tegument.use_gravity = False

    bpy.ops.mesh.primitive_uv_sphere_add(segments=12, ring_count=6, radius=0.5, location=(3.0, 0.0, 0.0))
    bob = bpy.context.active_object
    bob.name = "Bob"
    squash_keys(bob, "Bulge", (1.6, 1.6, 1.6), {1: 0.0, 24: 1.0, 48: 0.0})
    wall = mesh_object("Wall", [(3.7, -1, -1), (3.7, 1, -1), (3.7, 1, 1), (3.7, -1, 1)], [(0, 1, 2, 3)])
    walls = bpy.data.collections.new("Walls")
    scene.collection.children.link(walls)
    walls.objects.link(wall)
    scene.collection.objects.unlink(wall)
    bpy.context.view_layer.objects.active = bob
    assert bpy.ops.tegument.deform_add() == {"FINISHED"}
    bob.tegument.frame_start, bob.tegument.frame_end = FRAMES
    bob.tegument.collider_collection = walls

    material = bpy.data.materials.new("Skin")
    alice.data.materials.append(material)
    tree = material.node_tree
    tree.nodes.clear()
    node = tree.nodes.new("TegumentUVWarpNode")
    node.name = NODE
    node.object = alice
    node.resolution = WARP_RES
    node.frame_start, node.frame_end = FRAMES
    node.rigidity_image = float_image("Rigidity", disc(0.2, n=WARP_RES))
    tree.nodes.active = node
    assert bpy.ops.tegument.warp_bind(material="Skin", node=NODE) == {"FINISHED"}
    bpy.ops.wm.save_mainfile()
    return tmp_path / "shot.blend"


# ------------------------------------------------------------------ the worker

def worker(args: list[str], *, kill_after: int | None = None) -> subprocess.CompletedProcess:
    """Blender's command line, run by ``farm_worker.py`` in a fresh process."""
    env = dict(os.environ)
    env.pop("TEGUMENT_TEST_KILL_AFTER", None)
    if kill_after is not None:
        env["TEGUMENT_TEST_KILL_AFTER"] = str(kill_after)
    return subprocess.run([sys.executable, str(WORKER), *args], capture_output=True, text=True, env=env)


def start(command: dict, kill_after: int | None = None) -> subprocess.Popen:
    """A `blender-render` command as a Flamenco worker runs it: ``{blender}`` is this machine's Blender
    (farm_worker.py), ``{blenderArgs}`` Flamenco's default ``-b -y``."""
    assert command["name"] == "blender-render"
    p = command["parameters"]
    assert (p["exe"], p["exeArgs"]) == ("{blender}", "{blenderArgs}")
    argv = [sys.executable, str(WORKER), "-b", "-y", *p["argsBefore"], p["blendfile"], *p["args"]]
    env = dict(os.environ)
    env.pop("TEGUMENT_TEST_KILL_AFTER", None)
    if kill_after is not None:
        env["TEGUMENT_TEST_KILL_AFTER"] = str(kill_after)
    return subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)


def run_job(tasks: list[dict], *, die_once: dict[str, int] | None = None, slots: int = 2) -> dict[str, list[int]]:
    """Runs the compiled tasks as a Flamenco Manager schedules them: a task starts when every task
    it depends on has finished, ``slots`` at a time; a task that fails is run again (Flamenco
    re-queues a task whose worker died). ``die_once`` kills a task's first run after that many
    frames. Returns the exit codes of each task's runs."""
    die_once = dict(die_once or {})
    waiting = list(tasks)
    running: dict[str, subprocess.Popen] = {}
    finished: set[str] = set()
    codes: dict[str, list[int]] = {t["name"]: [] for t in tasks}
    logs: dict[str, list[str]] = {t["name"]: [] for t in tasks}
    deadline = time.monotonic() + 600
    try:
        while waiting or running:
            assert time.monotonic() < deadline, f"the job did not finish; running: {list(running)}"
            for task in list(waiting):
                if len(running) >= slots:
                    break
                if all(d in finished for d in task["dependencies"]):
                    (command,) = task["commands"]
                    running[task["name"]] = start(command, die_once.pop(task["name"], None))
                    waiting.remove(task)
            for name, process in list(running.items()):
                if process.poll() is None:
                    continue
                del running[name]
                logs[name].append(process.stdout.read())
                codes[name].append(process.returncode)
                if process.returncode == 0:
                    finished.add(name)
                else:
                    assert len(codes[name]) < 3, f"task {name} failed twice:\n" + "\n---\n".join(logs[name])
                    waiting.insert(0, next(t for t in tasks if t["name"] == name))
            time.sleep(0.05)
    finally:
        # A failed assertion must not leave Blender processes running on after the test.
        for process in running.values():
            process.kill()
            process.wait()
    return codes


# ------------------------------------------------------------------ reading what was baked

def pc2_bytes(path: pathlib.Path) -> bytes:
    data = path.read_bytes()
    header = np.frombuffer(data[12:32], dtype="<i4,<i4,<f4,<f4,<i4")[0]
    _, vertices, _, _, frames = header
    assert data[:12] == b"POINTCACHE2\0" and len(data) == 32 + 12 * vertices * frames, f"{path} is not a whole PC2 cache"
    return data


def redirection(path: pathlib.Path) -> np.ndarray:
    import tegument

    return tegument.read_exr(path)[0]


def convergence_error(got: np.ndarray, reference: np.ndarray) -> float:
    """Issue 28's convergence error on a redirection texture: RMS |got − reference| over the valid
    texels, divided by RMS |reference − identity| (each texel's own UV)."""
    n = reference.shape[0]
    c = (np.arange(n) + 0.5) / n
    u, v = np.meshgrid(c, c)  # row 0 = lowest v, as the texture is stored
    identity = np.stack([u, v], -1)
    valid = reference[..., 2] > 0.5
    moved = np.sqrt(np.mean(np.sum((reference[..., :2] - identity) ** 2, -1)[valid]))
    off = np.sqrt(np.mean(np.sum((got[..., :2] - reference[..., :2]) ** 2, -1)[valid]))
    return float(off / moved) if moved > 0 else float(off)


def sequence(folder: pathlib.Path) -> list[str]:
    return sorted(p.name for p in folder.glob("*.exr"))


STEM = "Skin_Tegument_UV_Warp_1001"


# ------------------------------------------------------------------ the tests

@pytest.fixture
def shot(tmp_path):
    """The saved scene, and a copy baked locally in one go (the reference)."""
    node_executable()  # before any baking: a skip or a failure should cost nothing
    farm = tmp_path / "farm"
    farm.mkdir()
    blend = build_scene(farm)
    local = tmp_path / "local"
    local.mkdir()
    bpy.ops.wm.save_as_mainfile(filepath=str(local / "shot.blend"), copy=True)
    bpy.ops.wm.open_mainfile(filepath=str(local / "shot.blend"))
    cli = addon().cli
    assert cli.main(["bake"]) == 0
    assert cli.main(["warp-bake", "--material", "Skin", "--node", NODE]) == 0
    return blend, local


def test_a_farm_bake_equals_a_local_bake_and_survives_killed_tasks(shot, tmp_path):
    blend, local = shot
    farm = blend.parent

    listed = worker([str(blend), "--command", "tegument", "list-bakes"])
    assert listed.returncode == 0, listed.stderr
    (line,) = [l for l in listed.stdout.splitlines() if l.startswith("{")]
    described = json.loads(line)
    assert [(b["kind"], b["id"], b["frames"], b["depends_on"]) for b in described["bakes"]] == [
        ("pyramid_deform", "Alice", [1, 48], []),
        ("pyramid_deform", "Bob", [1, 48], []),
        ("uv_warp", f"Skin/{NODE}", [1, 48], ["Alice"]),
    ]
    assert [b["caches"] for b in described["bakes"]] == [
        ["tegument/Alice.pc2"], ["tegument/Bob.pc2"], [f"tegument/warp/{STEM}_####.exr"]]

    compiled = compile_job(tmp_path, {"blendfile": str(blend), "scene_bakes": line, "bakes": "everything",
                                      "bake_list": "", "frames": "", "chunk_size": CHUNK,
                                      "preroll": described["preroll"]})
    tasks = compiled["tasks"]
    chunk_names = [f"UV Warp Skin/{NODE} {a}-{a + CHUNK - 1}" for a in range(1, 49, CHUNK)]
    assert [(t["name"], t["dependencies"]) for t in tasks] == [
        ("Pyramid Deform Alice 1-48", []), ("Pyramid Deform Bob 1-48", []),
        *[(name, ["Pyramid Deform Alice 1-48"]) for name in chunk_names]]

    # The job type and `list-bakes --chunk-size` (the plain command lines for other farms) agree.
    plain = worker([str(blend), "--command", "tegument", "list-bakes", "--chunk-size", str(CHUNK),
                    "--output", str(tmp_path / "plain.json")])
    assert plain.returncode == 0, plain.stderr
    plain_tasks = [t["args"] for b in json.loads((tmp_path / "plain.json").read_text())["bakes"] for t in b["tasks"]]
    assert plain_tasks == [t["commands"][0]["parameters"]["args"] for t in tasks]

    # Alice's worker dies 10 frames into her bake (nothing is cached yet), and the worker of the
    # third warp chunk dies after 5 of its frames; Flamenco runs both tasks again.
    codes = run_job(tasks, die_once={"Pyramid Deform Alice 1-48": 10, chunk_names[2]: 5})
    assert codes["Pyramid Deform Alice 1-48"] == [-9, 0] and codes[chunk_names[2]] == [-9, 0]
    assert all(c == [0] for name, c in codes.items() if name not in ("Pyramid Deform Alice 1-48", chunk_names[2]))

    for name in ("Alice", "Bob"):
        assert pc2_bytes(farm / "tegument" / f"{name}.pc2") == pc2_bytes(local / "tegument" / f"{name}.pc2"), name

    warp_farm, warp_local = farm / "tegument" / "warp", local / "tegument" / "warp"
    assert sequence(warp_farm) == sequence(warp_local) == [f"{STEM}_{f:04d}.exr" for f in range(1, 49)]
    errors = {f: convergence_error(redirection(warp_farm / f"{STEM}_{f:04d}.exr"),
                                   redirection(warp_local / f"{STEM}_{f:04d}.exr")) for f in range(1, 49)}
    worst = max(errors, key=errors.get)
    assert errors[worst] <= TOLERANCE, f"frame {worst}: convergence error {errors[worst]:.3f} against the local bake"
    # The first chunk starts where the bake starts: the same solves, the same files.
    assert all(errors[f] == 0.0 for f in range(1, CHUNK + 1))
    # A worker that dies cannot clean up: the killed chunk left its hidden staging folder (never
    # read; docs/farm.md says it may be deleted), and nothing else.
    assert [p.name.startswith(".tegument-warp-") for p in warp_farm.iterdir() if p.is_dir()] == [True]

    # The chunks left the node and the .blend as they were; warp-attach points the node at the
    # farm's sequence (refusing while a frame is missing) and saves.
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    assert bpy.data.materials["Skin"].node_tree.nodes[NODE].baked_frames == 0
    frame_7 = warp_farm / f"{STEM}_0007.exr"
    frame_7.rename(tmp_path / frame_7.name)
    refused = worker([str(blend), "--command", "tegument", "warp-attach", "--save"])
    assert refused.returncode == 1
    assert f"error: Skin › {NODE}: frame 7 of the sequence is missing ({frame_7}): bake it first" in refused.stderr
    (tmp_path / frame_7.name).rename(frame_7)
    attached = worker([str(blend), "--command", "tegument", "warp-attach", "--save"])
    assert attached.returncode == 0, attached.stderr
    assert f"Tegument UV Warp: Skin › {NODE} plays frames 1–48" in attached.stdout
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    node = bpy.data.materials["Skin"].node_tree.nodes[NODE]
    assert (node.baked_start, node.baked_frames) == FRAMES
    texture = node.node_tree.nodes["Warp 1001"]
    assert texture.image.filepath == f"//tegument/warp/{STEM}_0001.exr"
    assert (texture.image_user.frame_start, texture.image_user.frame_duration) == (1, 48)

    # A finished cache survives a re-run that dies: the deform cache is replaced only whole.
    before = pc2_bytes(farm / "tegument" / "Alice.pc2")
    (alice_task,) = [t for t in tasks if t["name"] == "Pyramid Deform Alice 1-48"]
    dying = start(alice_task["commands"][0], kill_after=20)
    dying.communicate()
    assert dying.returncode == -9
    assert pc2_bytes(farm / "tegument" / "Alice.pc2") == before


def test_preroll_is_what_keeps_chunks_within_the_tolerance(shot, tmp_path):
    """A chunk's cold start differs from the bake that ran through; the default pre-roll brings it
    within 5 % with a wide margin (at least ten times closer than without)."""
    blend, local = shot
    farm = blend.parent
    alice = worker([str(blend), "--command", "tegument", "bake", "--objects", "Alice"])
    assert alice.returncode == 0, alice.stdout + alice.stderr
    preroll = addon().farm.DEFAULT_PREROLL
    errors = {}
    for frames_before in (0, preroll):
        done = worker([str(blend), "--command", "tegument", "warp-bake", "--material", "Skin", "--node", NODE,
                       "--frames", "13-24", "--chunk", "--preroll", str(frames_before)])
        assert done.returncode == 0, done.stdout + done.stderr
        errors[frames_before] = max(
            convergence_error(redirection(farm / "tegument" / "warp" / f"{STEM}_{f:04d}.exr"),
                              redirection(local / "tegument" / "warp" / f"{STEM}_{f:04d}.exr")) for f in range(13, 25))
        # A chunk writes its own frames and nothing else.
        assert sequence(farm / "tegument" / "warp") == [f"{STEM}_{f:04d}.exr" for f in range(13, 25)]
    print(f"worst convergence error of chunk 13-24: no pre-roll {errors[0]:.4f}, pre-roll {preroll} {errors[preroll]:.4f}")
    assert errors[preroll] <= TOLERANCE and errors[preroll] * 10 <= errors[0], errors


# ------------------------------------------------------------------ in one process: the listing and bad input

def test_list_bakes_is_what_flamenco_evaluates_and_what_the_job_type_reads(tmp_path, capfd):
    build_scene(tmp_path)
    a = addon()
    capfd.readouterr()
    assert a.cli.main(["list-bakes"]) == 0
    printed = json.loads(capfd.readouterr().out)
    # What Blender's Flamenco add-on does with the job type's hidden setting (job_types_propgroup.py).
    evaluated = eval("C.scene.tegument_farm_bakes", {}, {"bpy": bpy, "C": bpy.context, "settings": None})
    assert json.loads(evaluated) == printed == a.farm.scene_bakes()
    assert printed["blendfile"] == "shot.blend" and printed["preroll"] == a.farm.DEFAULT_PREROLL
    warp = printed["bakes"][2]
    assert warp["args"] == ["--command", "tegument", "warp-bake", "--material", "Skin", "--node", NODE,
                            "--frames", "{first}-{last}", "--chunk", "--preroll", "{preroll}"]
    assert "problem" not in warp

    # A node without an object is listed with its problem (the job type refuses it at submission).
    bpy.data.materials["Skin"].node_tree.nodes[NODE].object = None
    (warp,) = [b for b in a.farm.scene_bakes()["bakes"] if b["kind"] == "uv_warp"]
    assert warp["problem"] == f"Skin › {NODE}: no object: set the node's Object to the deforming mesh"
    assert warp["depends_on"] == []


def test_deformers_colliding_with_each_other_cannot_be_ordered(tmp_path, capfd):
    build_scene(tmp_path)
    alice, bob = bpy.data.objects["Alice"], bpy.data.objects["Bob"]
    for obj, other in ((alice, bob), (bob, alice)):
        collection = bpy.data.collections.new(f"{obj.name} colliders")
        bpy.context.scene.collection.children.link(collection)
        collection.objects.link(other)
        obj.tegument.collider_collection = collection
    capfd.readouterr()
    assert addon().cli.main(["list-bakes"]) == 2
    assert capfd.readouterr().err.strip() == (
        "error: these Pyramid Deform objects read each other's caches as colliders: Alice → Bob → Alice; a farm "
        "cannot order their bakes (bake them together locally, or take one out of the other's collider collection)")
    # The same message reaches the job type through the property Flamenco evaluates.
    assert json.loads(bpy.context.scene.tegument_farm_bakes)["error"].startswith("these Pyramid Deform objects")


@pytest.mark.parametrize("argv, message", [
    (["list-bakes"], "error: no .blend is open: a farm bakes a saved file"),
    (["bake"], "error: nothing to bake: no object has Pyramid Deform (no .blend is open: was the file given to "
               "Blender found?)"),
    (["warp-bake", "--frames", "48-1"], "error: --frames 48-1: the last frame 1 comes before the first 48"),
    (["warp-bake", "--chunk", "--save"], "error: --chunk leaves the .blend as it is (chunks run at once on a farm): "
                                         "drop --save"),
    (["warp-bake", "--preroll", "-1"], "argument --preroll: expects 0 or more frames, got -1"),
    (["list-bakes", "--chunk-size", "0"], "argument --chunk-size: expects at least 1 frame, got 0"),
])
def test_bad_command_lines_are_usage_errors(argv, message, capfd):
    capfd.readouterr()
    assert addon().cli.main(argv) == 2
    assert message in capfd.readouterr().err


def test_a_worker_given_a_missing_blend_says_so(tmp_path):
    done = worker(["-b", str(tmp_path / "missing.blend"), "--command", "tegument", "list-bakes"])
    assert done.returncode != 0
    assert f"Cannot read file \"{tmp_path / 'missing.blend'}\"" in done.stderr
