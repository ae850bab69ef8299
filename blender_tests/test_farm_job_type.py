"""The Flamenco job type (``addon/farm/tegument_bake.js``) compiled by Node.js against a stand-in
for Flamenco's job compiler (``flamenco_host.js`` says which parts of Flamenco it stands in for).

The scene here is written out by hand — what ``tegument list-bakes`` prints for two deformed
characters and a UV Warp node on one of them — so that every task, command and dependency can be
asserted exactly; ``test_farm.py`` compiles the JSON of a real scene and runs the tasks.
"""

from __future__ import annotations

import json
import os
import pathlib
import shutil
import subprocess
import zipfile

import pytest

from conftest import ROOT, _extension_zip

JOB_TYPE = ROOT / "addon" / "farm" / "tegument_bake.js"
HOST = pathlib.Path(__file__).with_name("flamenco_host.js")
BLENDFILE = "/farm/shots/010/shot.blend"


def node_executable() -> str:
    """Node.js, or a skip saying why (a failure under CI, which installs it: .ci/run)."""
    found = shutil.which("node")
    if found is None:
        message = "Node.js (`node`) is not installed: the Flamenco job type cannot be compiled here (apt install nodejs)"
        if os.environ.get("CI") == "true":
            pytest.fail(message + "; CI must have it (.ci/run installs it)")
        pytest.skip(message)
    return found


def compile_job(tmp_path: pathlib.Path, settings: dict, *, expect_error: bool = False):
    """Compiles a job of the Tegument type; returns the host's result, or the error message."""
    job = tmp_path / "job.json"
    job.write_text(json.dumps({"name": "Tegument test", "settings": settings}))
    done = subprocess.run([node_executable(), str(HOST), str(JOB_TYPE), str(job)], capture_output=True, text=True)
    if expect_error:
        assert done.returncode == 1, f"the job compiled, expected an error: {done.stdout}"
        return done.stderr.strip()
    assert done.returncode == 0, f"compiling the job failed: {done.stderr}"
    return json.loads(done.stdout)


def deform_bake(name: str, depends_on=(), frames=(1, 48)) -> dict:
    return {
        "kind": "pyramid_deform", "id": name, "object": name, "frames": list(frames),
        "caches": [f"tegument/{name}.pc2"], "writes_objects": [], "depends_on": list(depends_on),
        "reads_objects": [], "chunked": False,
        "args": ["--command", "tegument", "bake", "--objects", name, "--frames", "{first}-{last}"],
    }


WARP_ARGS = ["--command", "tegument", "warp-bake", "--material", "Skin", "--node", "Tegument UV Warp",
             "--frames", "{first}-{last}", "--chunk", "--preroll", "{preroll}"]


def scene(*, warp_frames=(1, 48)) -> dict:
    """Two deformed characters, Alice and Bob, and a UV Warp node on Alice's skin."""
    return {
        "blendfile": "shot.blend", "scene": "Scene", "preroll": 4,
        "bakes": [
            deform_bake("Alice"),
            deform_bake("Bob"),
            {
                "kind": "uv_warp", "id": "Skin/Tegument UV Warp", "material": "Skin", "node": "Tegument UV Warp",
                "object": "Alice", "frames": list(warp_frames),
                "caches": ["tegument/warp/Skin_Tegument_UV_Warp_1001_####.exr"], "depends_on": ["Alice"],
                "reads_objects": ["Alice"], "chunked": True, "args": WARP_ARGS,
            },
        ],
    }


def settings(**overrides) -> dict:
    """What Blender's Flamenco add-on submits: every setting, the hidden ones evaluated."""
    base = {"blendfile": BLENDFILE, "scene_bakes": json.dumps(scene()), "bakes": "everything", "bake_list": "",
            "frames": "", "chunk_size": 12, "preroll": 4}
    base.update(overrides)
    return base


def blender(args: list[str]) -> dict:
    """One `blender-render` command as the job type writes it: Flamenco's own variables for Blender."""
    return {"name": "blender-render",
            "parameters": {"exe": "{blender}", "exeArgs": "{blenderArgs}", "argsBefore": [], "blendfile": BLENDFILE,
                           "args": args}}


def warp_chunk(first: int, last: int, preroll: int) -> dict:
    args = [a.replace("{first}", str(first)).replace("{last}", str(last)).replace("{preroll}", str(preroll))
            for a in WARP_ARGS]
    return {"name": f"UV Warp Skin/Tegument UV Warp {first}-{last}", "type": "blender",
            "commands": [blender(args)], "dependencies": ["Pyramid Deform Alice 1-48"]}


def deform_task(name: str) -> dict:
    return {"name": f"Pyramid Deform {name} 1-48", "type": "blender",
            "commands": [blender(["--command", "tegument", "bake", "--objects", name, "--frames", "1-48"])],
            "dependencies": []}


def test_two_characters_and_a_warp_node_over_48_frames_in_chunks_of_12(tmp_path):
    compiled = compile_job(tmp_path, settings())
    assert compiled["tasks"] == [
        deform_task("Alice"),
        deform_task("Bob"),
        # The first chunk starts where the bake starts: cold, as a bake that ran through does.
        warp_chunk(1, 12, 0),
        warp_chunk(13, 24, 4),
        warp_chunk(25, 36, 4),
        warp_chunk(37, 48, 4),
    ]


def test_the_job_type_declares_its_settings_for_the_flamenco_add_on(tmp_path):
    job_type = compile_job(tmp_path, settings())["job_type"]
    assert job_type["label"] == "Tegument Bake"
    by_key = {s["key"]: s for s in job_type["settings"]}
    assert list(by_key) == ["bakes", "bake_list", "frames", "chunk_size", "preroll", "scene_bakes", "blendfile"]
    assert by_key["bakes"]["choices"] == ["everything", "pyramid_deform", "uv_warp", "listed"]
    # Filled in by Blender's Flamenco add-on at submission, from the Tegument add-on.
    assert by_key["scene_bakes"]["eval"] == "C.scene.tegument_farm_bakes" and by_key["scene_bakes"]["visible"] == "hidden"
    assert by_key["blendfile"]["required"] and by_key["scene_bakes"]["required"]
    for key in ("bakes", "bake_list", "frames", "chunk_size", "preroll"):
        assert by_key[key]["visible"] == "submission", key


def test_settings_the_job_leaves_out_take_their_defaults(tmp_path):
    compiled = compile_job(tmp_path, {"blendfile": BLENDFILE, "scene_bakes": json.dumps(scene())})
    assert [t["name"] for t in compiled["tasks"]][2:] == [f"UV Warp Skin/Tegument UV Warp {a}-{a + 11}" for a in (1, 13, 25, 37)]


def test_a_frame_range_chunk_size_and_preroll_of_the_job(tmp_path):
    compiled = compile_job(tmp_path, settings(frames="1-30", chunk_size=8, preroll=6, bakes="uv_warp"))
    tasks = compiled["tasks"]
    assert [t["name"] for t in tasks] == [f"UV Warp Skin/Tegument UV Warp {a}-{b}" for a, b in
                                         ((1, 8), (9, 16), (17, 24), (25, 30))]
    # Alice is not in the job: her cache is taken as baked, nothing to wait for.
    assert all(t["dependencies"] == [] for t in tasks)
    args = [t["commands"][0]["parameters"]["args"] for t in tasks]
    assert [a[a.index("--preroll") + 1] for a in args] == ["0", "6", "6", "6"]
    # A pre-roll longer than the frames before the chunk stops at the bake's first frame.
    tasks = compile_job(tmp_path, settings(chunk_size=3, preroll=5, bakes="uv_warp"))["tasks"]
    prerolls = [t["commands"][0]["parameters"]["args"][-1] for t in tasks[:3]]
    assert prerolls == ["0", "3", "5"]


def test_listed_bakes_keep_their_dependencies_in_order(tmp_path):
    # The warp is listed first; its deformer still comes first and the chunks wait for it.
    compiled = compile_job(tmp_path, settings(bakes="listed", bake_list="Skin/Tegument UV Warp, Alice"))
    names = [t["name"] for t in compiled["tasks"]]
    assert names[0] == "Pyramid Deform Alice 1-48" and len(names) == 5 and "Pyramid Deform Bob 1-48" not in names
    assert all(t["dependencies"] == ["Pyramid Deform Alice 1-48"] for t in compiled["tasks"][1:])
    compiled = compile_job(tmp_path, settings(bakes="pyramid_deform"))
    assert [t["name"] for t in compiled["tasks"]] == ["Pyramid Deform Alice 1-48", "Pyramid Deform Bob 1-48"]


def test_a_deformer_that_collides_with_another_waits_for_it(tmp_path):
    described = scene()
    described["bakes"][0]["depends_on"] = ["Bob"]  # Alice's collider collection holds Bob
    compiled = compile_job(tmp_path, settings(scene_bakes=json.dumps(described)))
    names = [t["name"] for t in compiled["tasks"]]
    assert names[:2] == ["Pyramid Deform Bob 1-48", "Pyramid Deform Alice 1-48"]
    assert compiled["tasks"][1]["dependencies"] == ["Pyramid Deform Bob 1-48"]


@pytest.mark.parametrize("overrides, message", [
    ({"bakes": "listed", "bake_list": "Alice, Carol"},
     'Tegument bake: no bake named "Carol" in the .blend; it has "Alice", "Bob", "Skin/Tegument UV Warp"'),
    ({"bakes": "listed", "bake_list": " , "}, "Tegument bake: Bakes is listed, but Bake List is empty"),
    ({"bakes": "all"}, 'Tegument bake: Bakes must be everything, pyramid_deform, uv_warp or listed, got "all"'),
    ({"frames": "1-x"}, 'Tegument bake: Frames expects START-END (like 1001-1100) or nothing, got "1-x"'),
    ({"frames": "48-1"}, "Tegument bake: Frames 48-1: the last frame 1 comes before the first 48"),
    ({"frames": "10-48"}, "Tegument bake: the cache of Alice starts at frame 1 in the .blend, but Frames asks for "
                          "10-48: set Alice's Start to 10 in Blender and submit again, or leave Frames empty"),
    ({"chunk_size": 0}, "Tegument bake: chunk_size must be a whole number of at least 1, got 0"),
    ({"preroll": -1}, "Tegument bake: preroll must be a whole number of at least 0, got -1"),
    ({"scene_bakes": ""}, "Tegument bake: the scene_bakes setting is empty"),
    ({"scene_bakes": "{not json"}, "Tegument bake: scene_bakes is not the JSON of tegument list-bakes"),
    ({"scene_bakes": json.dumps({"error": "no .blend is open: a farm bakes a saved file"})},
     "Tegument bake: no .blend is open: a farm bakes a saved file"),
    ({"scene_bakes": json.dumps({"bakes": []})},
     "Tegument bake: the .blend has no Pyramid Deform object and no Tegument UV Warp node"),
])
def test_bad_settings_are_compile_errors_that_say_what_is_wrong(tmp_path, overrides, message):
    assert compile_job(tmp_path, settings(**overrides), expect_error=True).startswith(message)


def test_a_bake_with_a_problem_is_refused_at_submission(tmp_path):
    described = scene()
    described["bakes"][2]["problem"] = "Skin › Tegument UV Warp: no object: set the node's Object to the deforming mesh"
    error = compile_job(tmp_path, settings(scene_bakes=json.dumps(described)), expect_error=True)
    assert error == "Tegument bake: Skin › Tegument UV Warp: no object: set the node's Object to the deforming mesh"


def test_the_extension_zip_ships_the_job_type():
    with zipfile.ZipFile(_extension_zip()) as archive:
        assert archive.read("farm/tegument_bake.js") == JOB_TYPE.read_bytes()
