"""`bench/collect.py`: the one table of `make bench`, built from the rows of one run.

Pure Python (no Blender); it sits here because `make test` runs this folder.
"""

from __future__ import annotations

import json
import pathlib
import subprocess
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "bench"))
import collect  # noqa: E402

SKIN = "skin 100k vertices vs sphere 20k triangles"
CORE_SKIN = "skin 100489 v / 199712 tri vs collider 20172 tri"
FLESH = "skin 100489 v vs collider 20172 tri, step"
CHARACTERS = ("MakeHuman character (OBJ, welded), 13.4k vertices", "MakeHuman character (glTF round trip, split seams), 14.5k vertices",
              "MakeHuman character (Subdivision Surface between Armature and Tegument), 53.5k vertices")


def character_rows() -> list[dict]:
    """The character rows of bench/blender_bench.py `character`, distinct values per case."""
    rows = [row("blender", "MakeHuman character", "character: shared data", 1, unit="")]
    for k, case in enumerate(CHARACTERS):
        rows += [row("blender", case, "armature only: frame", 6.0 + k), row("blender", case, "Corrective Smooth (10 it.): frame", 30.0 + k),
                 row("blender", case, "Tegument (10 it.): frame", 15.0 + k),
                 row("blender", case, "Tegument frame / Corrective Smooth frame", 0.5, unit="x"),
                 row("blender", case, "pinned by bind", 6 + k, unit=""), row("blender", case, "split vertices", 1137 * k, unit=""),
                 row("blender", case, "Tegument: convergence error, worst baked frame", 0.5 - 0.01 * k, unit=""),
                 row("blender", case, "Tegument Converge: convergence error, worst frame", 0.02 + 0.01 * k, unit="")]
        rows[-1]["note"] = "Converge on, at most 12 it., each frame solved from its input (a cold start)"
        for m, method in enumerate(("skinning", "Corrective Smooth", "Tegument")):
            rows += [row("blender", case, f"{method}: spike max", 0.6 - 0.2 * m, unit=""),
                     row("blender", case, f"{method}: self-intersecting pairs", 150 - 10 * m, unit=""),
                     row("blender", case, f"{method}: seam gap", 40.0 * k * (m == 1), unit="mm")]
    return rows


def row(benchmark, case, metric, value, threads=2, unit="ms"):
    return {"benchmark": benchmark, "case": case, "metric": metric, "value": value, "unit": unit, "threads": threads, "note": ""}


def run_rows() -> list[dict]:
    """Every row the table reads, as the benchmarks name them, with distinct values."""
    rows = [row("blender", SKIN, "Tegument collisions: pinched (most in a frame)", 3, unit="")]
    for k, label in enumerate(("Tegument collisions (default it.)", "Cloth (pinned, collision quality 5)", "Shrinkwrap (Outside) + Corrective Smooth")):
        rows += [row("blender", SKIN, f"{label}: frame", 1000.0 * (k + 1)),
                 row("blender", SKIN, f"{label}: vertices inside (all frames)", 10 * k, unit=""),
                 row("blender", SKIN, f"{label}: edges crossing (all frames)", 20 * k, unit="")]
    for size, vertices in (("10k", 10088), ("100k", 99848), ("1M", 998786)):
        for threads in (1, 2):
            case = f"sphere {size} ({vertices} v)"
            rows += [row("pyramid", case, "targets: per iteration", 2.0 / threads, threads),
                     row("pyramid", case, "targets: bandwidth reference", 1.0, threads),
                     row("pyramid", case, "targets: iteration / reference", 2.0 / threads, threads, unit="x")]
    rows += [row("collide", CORE_SKIN, "one in-loop pass", 100.0), row("collide", CORE_SKIN, "pass 1 (swept collider)", 400.0),
             row("collide", CORE_SKIN, "bandwidth reference", 0.5), row("collide", CORE_SKIN, "in-loop pass / reference", 200.0, unit="x")]
    for benchmark, scale in (("flesh", 1.0), ("flesh_converge", 2.0)):  # plain iterations, then Converge
        rows.append(row(benchmark, FLESH, "collisions only", 800.0 * scale))
        for k, feature in enumerate(("dynamics", "strain limits (unified)", "strain limits (post)", "compliant collider", "all three")):
            rows += [row(benchmark, FLESH, f"+ {feature}", (810.0 + 10 * k) * scale),
                     row(benchmark, FLESH, f"added by {feature}", (10.0 + 10 * k) * scale),
                     row(benchmark, FLESH, f"+ {feature}: worst stretch (all frames)", 1.1 + 0.01 * k, unit="× rest"),
                     row(benchmark, FLESH, f"+ {feature}: penetrations (all frames, audit)", float(k), unit="")]
    for n in (1024, 2048, 4096):
        case = f"{n}x{n} cylinder 33k verts, 25% rigid"
        scale = (n // 1024) ** 2
        rows += [row("warp", case, "frame (warm: surface+solve+invert)", 100.0 * scale),
                 row("warp", case, "  CPU time per frame (all threads)", 180.0 * scale),
                 row("warp", case, "    level 0 (finest) + prolong", 40.0 * scale),
                 row("warp", case, "  inversion", 20.0 * scale),
                 row("warp", case, "peak memory (VmHWM, whole process)", 70.0 * scale, unit="MiB"),
                 row("warp", case, "bandwidth reference (1 pass)", 2.0 * scale),
                 row("warp", case, "rigid stretch error, identity", 0.3, unit=""),
                 row("warp", case, "rigid stretch error, warped", 0.1, unit="")]
    return rows + character_rows() + scaling_rows()


SCALING = ("armature-bent tube, 100k vertices", "armature-bent tube, 5.00M vertices")


def scaling_rows() -> list[dict]:
    """The rows of bench/bake_scaling.py for two sizes (largest first: the table sorts them)."""
    rows = []
    for k, (case, vertices) in enumerate(((SCALING[1], 5_000_000), (SCALING[0], 100_000))):
        big = 50 if k == 0 else 1
        rows += [row("scaling", case, "vertices", vertices, unit=""),
                 row("scaling", case, "armature only: frame", 3.0 * big), row("scaling", case, "Corrective Smooth (10 it.): frame", 20.0 * big),
                 row("scaling", case, "Tegument (default it.): frame", 9.0 * big),
                 row("scaling", case, "Tegument frame / Corrective Smooth frame", 0.45, unit="x"),
                 row("scaling", case, "Tegument frame per vertex", 90.0 if k else 100.0, unit="ns"),
                 row("scaling", case, "bind", 0.5 * big, unit="s"), row("scaling", case, "bind: peak memory", 60.0 * big, unit="MiB"),
                 row("scaling", case, "bind: peak memory per vertex", 600.0, unit="B")]
        rows += [row("scaling", case, f"Tegument frame: {phase}", (m + 1) * big) for m, phase in enumerate(collect.FRAME_PHASES)]
    return rows


def test_summary_puts_each_comparison_side_by_side():
    lines = collect.summary(collect.Rows(run_rows()))
    by = {(line.comparison.split(",")[0].split(" (")[0], line.method): line for line in lines}
    # The deformer comparison is the bake loop benchmark's 100k tube.
    assert by[("deformer", "Tegument Pyramid Deform")].ms_per_frame == 9.0
    assert by[("deformer", "Tegument Pyramid Deform")].times_bandwidth == 1.0  # the 100k iteration, 2 threads
    assert by[("deformer", "Blender Corrective Smooth")].ms_per_frame == 20.0
    assert by[("deformer", "Blender Corrective Smooth")].note == "its own cost 17.0 ms"
    cloth = by[("collisions", "Blender Cloth pinned to the animation, collision quality 5")]
    assert (cloth.ms_per_frame, cloth.vertices_inside, cloth.edges_crossing) == (2000.0, 10, 20)
    assert by[("collisions", "Tegument Pyramid Deform + collisions")].times_bandwidth == 200.0
    warps = [line for line in lines if line.comparison.startswith("UV warp")]
    assert [line.ms_per_frame for line in warps] == [100.0, 3.87, 400.0, 14.03, 1600.0, 119.31]
    assert [line.peak_mib for line in warps[::2]] == [70.0, 280.0, 1120.0]
    assert [line.times_bandwidth for line in warps[::2]] == [50.0, 50.0, 50.0]  # frame ÷ that size's reference
    flesh = [line for line in lines if line.comparison.startswith("flesh")]
    assert [line.ms_per_frame for line in flesh] == [800.0, 810.0, 820.0, 830.0, 840.0, 850.0,
                                                     1600.0, 1620.0, 1640.0, 1660.0, 1680.0, 1700.0]
    assert flesh[4].method == "+ compliant collider" and "10 it." in flesh[4].comparison
    assert flesh[4].note == "1.05× collisions only (adds +40 ms); worst edge 1.130× rest, 3 penetrations"
    assert "Converge" in flesh[10].comparison and flesh[10].note.startswith("1.05× collisions only (adds +80 ms)")
    loops = [line for line in lines if line.comparison.startswith("hot loops")]
    assert len(loops) == 6 + 2 + 6
    assert loops[6].times_bandwidth == 200.0 and loops[7].times_bandwidth == 800.0  # in-loop and pass 1 ÷ 0.5 ms


def test_the_character_lines_compare_corrective_smooth_and_tegument_on_each_variant():
    lines = [line for line in collect.summary(collect.Rows(run_rows())) if line.comparison.startswith("real character")]
    assert [(line.case, line.method, line.ms_per_frame) for line in lines] == [
        (case, method, ms + k) for k, case in enumerate(CHARACTERS)
        for method, ms in (("armature only (skinning)", 6.0), ("Blender Corrective Smooth (10 it.)", 30.0),
                           ("Tegument Pyramid Deform (10 it.)", 15.0))]
    assert lines[4].note == "spike max 0.40, 140 self-intersecting face pairs, seam gap 40.00 mm"
    assert lines[5].note.startswith("0.50× Corrective Smooth's frame; 7 vertices pinned by bind (1137 split at seams); spike max 0.20, 130")
    assert lines[5].note.endswith("; convergence error, worst frame: 49.0 % at the defaults, 3.0 % with Converge from each frame's input (at most 12 it.)")


def test_with_both_solver_settings_the_character_lines_add_the_other_one_in_the_same_minutes():
    rows = run_rows()
    for k, case in enumerate(CHARACTERS):
        rows += [row("blender", case, "Tegument (Converge on, 24 it.): frame", 40.0 + k),
                 row("blender", case, "Tegument (Converge on, 24 it.) frame / Corrective Smooth frame", 1.25 + k, unit="x"),
                 row("blender", case, "Tegument (Converge on, 24 it.): iterations a frame", 7.5, unit="")]
    lines = [line for line in collect.summary(collect.Rows(rows)) if line.comparison.startswith("real character")]
    assert [line.method for line in lines[:4]] == ["armature only (skinning)", "Blender Corrective Smooth (10 it.)",
                                                    "Tegument Pyramid Deform (10 it.)", "Tegument Pyramid Deform (Converge on, 24 it.)"]
    assert [line.ms_per_frame for line in lines[3::4]] == [40.0, 41.0, 42.0]
    assert lines[7].note == "2.25× Corrective Smooth's frame in the same minutes; 7.5 iterations a frame"


def test_the_scaling_lines_go_by_size_with_the_frame_phases_and_the_growth_per_vertex():
    lines = [line for line in collect.summary(collect.Rows(run_rows())) if line.comparison.startswith("bake loop at scale")]
    assert [(line.case, line.ms_per_frame) for line in lines] == [
        (SCALING[0], 3.0), (SCALING[0], 20.0), (SCALING[0], 9.0), (SCALING[1], 150.0), (SCALING[1], 1000.0), (SCALING[1], 450.0)]
    assert lines[2].peak_mib == 60.0
    assert lines[2].note == ("0.45× Corrective Smooth's frame; 90 ns per vertex; ms: evaluate 1.0, read 2.0, solve 3.0, write 4.0, "
                             "rest -1.0; bind 0.50 s, peak memory 600 B per vertex")
    assert "100 ns per vertex (1.11× at 100k vertices)" in lines[5].note


def test_without_the_shared_data_the_character_line_says_why():
    rows = [r for r in run_rows() if not r["case"].startswith("MakeHuman")]
    rows.append(dict(row("blender", "MakeHuman character", "character: shared data", 0, unit=""), note="/x/makehuman: missing base.obj"))
    lines = [line for line in collect.summary(collect.Rows(rows)) if line.comparison.startswith("real character")]
    assert [(line.method, line.note) for line in lines] == [("not measured", "/x/makehuman: missing base.obj")]


def test_a_missing_figure_is_named():
    rows = [r for r in run_rows() if r["metric"] != "Cloth (pinned, collision quality 5): frame"]
    with pytest.raises(collect.MissingFigure, match=r"Cloth \(pinned, collision quality 5\): frame"):
        collect.summary(collect.Rows(rows))


def test_command_writes_the_json_and_the_table_with_the_load_of_each_step(tmp_path):
    rows = run_rows()
    for name in ("pyramid", "collide", "flesh", "flesh_converge", "self_collision", "warp", "warp_convergence", "blender", "scaling"):
        (tmp_path / f"{name}.json").write_text(json.dumps([r for r in rows if r["benchmark"] == name]))
    (tmp_path / "machine.txt").write_text("Test CPU, 2 cores\nBlender 5.0.1\n")
    run = {"started": "2026-11-23T15:00:00+00:00", "seconds": 600.0, "steps": [
        {"step": "warp", "seconds": 60.0, "uptime_before": " 15:00:00 up 1 day,  load average: 1.50, 1.20, 1.00",
         "uptime_after": " 15:01:00 up 1 day,  load average: 2.50, 1.60, 1.10", "other_processes_cores": 0.8, "exit_code": 0}]}
    (tmp_path / "run.json").write_text(json.dumps(run))
    out_json, out_md = tmp_path / "results.json", tmp_path / "table.md"
    subprocess.run([sys.executable, str(ROOT / "bench" / "collect.py"), "--results", str(tmp_path), "--json", str(out_json),
                    "--markdown", str(out_md), "--plot", "images/benchmark.png"], check=True)
    data = json.loads(out_json.read_text())
    assert data["machine"] == "Test CPU, 2 cores; Blender 5.0.1" and len(data["rows"]) == len(rows)
    table = out_md.read_text()
    assert "| warp | 60 s | 1.50, 1.20, 1.00 | 2.50, 1.60, 1.10 | 0.8 |" in table
    assert "| Blender Cloth pinned to the animation, collision quality 5 | 2 000 | 10 | 20 |" in table
    assert "![The comparisons of this run](images/benchmark.png)" in table
    (tmp_path / "blender.json").unlink()
    failed = subprocess.run([sys.executable, str(ROOT / "bench" / "collect.py"), "--results", str(tmp_path), "--json", str(out_json),
                             "--markdown", str(out_md)], capture_output=True, text=True)
    assert failed.returncode != 0 and "blender.json is missing" in failed.stderr
