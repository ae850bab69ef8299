"""Merges one `make bench` run (``bench/results/*.json``) into ``bench/results.json`` and one table.

The table (``docs/performance-table.md``, linked from ``docs/performance.md``) puts every comparison
side by side, each measured in the same run on the same mesh: Pyramid Deform against Corrective
Smooth, collisions against Cloth and Shrinkwrap + Corrective Smooth, what dynamics, strain limits
and compliant colliders add to a step, the UV warp against the seed
paper's published GPU figures, and each hot loop as a multiple of the memory-bandwidth reference
measured in that run. Below it, every row the benchmarks wrote.

A figure the table needs but the run did not produce is an error (naming it), not a blank: a
benchmark that renamed a metric must be matched here.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import re
from dataclasses import asdict, dataclass

# The seed paper's Table 1 (shared/seeds/001_…, "Simulation times in milliseconds", NVidia GTX
# Titan): warp simulation of the grid hierarchy per frame, and the preprocessing of the
# hierarchies. 2048² is the mean of its four 2048² models (13.92–14.12 ms). Published, not measured.
SEED_GPU_WARP_MS = {1024: 3.87, 2048: 14.03, 4096: 119.31}
SEED_GPU_PREPROCESS_MS = {1024: 0.37, 2048: 1.17, 4096: 4.52}
WARP_SIZES = (1024, 2048, 4096)


class MissingFigure(LookupError):
    pass


@dataclass
class Line:
    """One line of the comparison table."""

    comparison: str
    case: str
    method: str
    ms_per_frame: float | None = None
    vertices_inside: float | None = None
    edges_crossing: float | None = None
    peak_mib: float | None = None
    times_bandwidth: float | None = None
    note: str = ""


class Rows:
    def __init__(self, rows: list[dict]):
        self.rows = rows

    def find(self, benchmark: str, case: str, metric: str, threads: int | None = None) -> dict:
        """The row of `benchmark` whose case matches the regular expression `case` and whose metric
        is `metric` (surrounding spaces ignored); with `threads`, only rows of that thread count."""
        for row in self.rows:
            if (row["benchmark"] == benchmark and re.fullmatch(case, row["case"])
                    and row["metric"].strip() == metric and (threads is None or row["threads"] == threads)):
                return row
        where = f"{benchmark} / case ~ {case!r} / {metric!r}" + (f" / {threads} threads" if threads else "")
        raise MissingFigure(f"the run has no row {where}")

    def value(self, *args, **kwargs) -> float:
        value = self.find(*args, **kwargs)["value"]
        if value is None:
            raise MissingFigure(f"the row {args} has no value")
        return float(value)


def summary(rows: Rows) -> list[Line]:
    """The comparison table's lines, from the rows of one run."""
    lines: list[Line] = []

    # Pyramid Deform against Corrective Smooth: the 100k-vertex armature-bent tube of the bake
    # loop's benchmark (bench/bake_scaling.py), both measured in the same minutes.
    tube = r"armature-bent tube, 100k vertices"
    case = rows.find("scaling", tube, "armature only: frame")["case"]
    iteration_ratio = rows.value("pyramid", r"sphere 100k .*", "targets: iteration / reference", threads=2)
    comparison = "deformer, default iterations (Corrective Smooth: 10)"
    armature = rows.value("scaling", tube, "armature only: frame")
    corrective = rows.value("scaling", tube, "Corrective Smooth (10 it.): frame")
    lines.append(Line(comparison, case, "armature only (what both start from)", armature,
                      note="frame change + depsgraph + read positions"))
    lines.append(Line(comparison, case, "Blender Corrective Smooth", corrective, note=f"its own cost {corrective - armature:.1f} ms"))
    ratio = rows.value("scaling", tube, "Tegument frame / Corrective Smooth frame")
    lines.append(Line(comparison, case, "Tegument Pyramid Deform", rows.value("scaling", tube, "Tegument (default it.): frame"),
                      times_bandwidth=iteration_ratio,
                      note=f"{ratio:.2f}× Corrective Smooth's frame; solve {rows.value('scaling', tube, 'Tegument frame: solve'):.1f} ms; "
                           "× bandwidth: one solver iteration (100k sphere, 2 threads)"))

    # Collisions: the same skin and collider, three tools, audited the same way.
    skin = r"skin .* vs sphere .*"
    case = rows.find("blender", skin, "Tegument collisions (default it.): frame")["case"]
    in_loop_ratio = rows.value("collide", r"skin .* vs collider .*", "in-loop pass / reference", threads=2)
    comparison = "collisions (per frame; counts over all frames)"
    for label, method, note in (
        ("Tegument collisions (default it.)", "Tegument Pyramid Deform + collisions",
         f"pinched {rows.value('blender', skin, 'Tegument collisions: pinched (most in a frame)'):.0f}; "
         "× bandwidth: one in-loop collision pass (tegument-core benchmark)"),
        ("Cloth (pinned, collision quality 5)", "Blender Cloth pinned to the animation, collision quality 5", ""),
        ("Shrinkwrap (Outside) + Corrective Smooth", "Blender Shrinkwrap (Outside) + Corrective Smooth (10 it.)", ""),
    ):
        lines.append(Line(comparison, case, method, rows.value("blender", skin, f"{label}: frame"),
                          vertices_inside=rows.value("blender", skin, f"{label}: vertices inside (all frames)"),
                          edges_crossing=rows.value("blender", skin, f"{label}: edges crossing (all frames)"),
                          times_bandwidth=in_loop_ratio if method.startswith("Tegument") else None, note=note))

    # Flesh: what dynamics, strain limits and a compliant collider add to a whole step on the
    # collision scene (tegument-core, the pyramid solve included), with the benchmark's 10 plain
    # iterations and with the add-on's default solver: issue 29 asks for the ratios to collisions only.
    flesh = r"skin .* vs collider .*, step"
    for benchmark, solver in (("flesh", "10 it."), ("flesh_converge", "Converge")):
        comparison = f"flesh: added cost per frame (whole step, {solver}, 2 threads)"
        case = rows.find(benchmark, flesh, "collisions only")["case"]
        baseline = rows.value(benchmark, flesh, "collisions only")
        lines.append(Line(comparison, case, "Tegument step: collisions only", baseline,
                          note="the baseline the additions below are measured against"))
        for feature in ("dynamics", "strain limits (unified)", "strain limits (post)", "compliant collider", "all three"):
            total = rows.value(benchmark, flesh, f"+ {feature}")
            added = rows.value(benchmark, flesh, f"added by {feature}")
            # Over all frames of the benchmark: its own edge measure and the audit.
            worst = rows.value(benchmark, flesh, f"+ {feature}: worst stretch (all frames)")
            found = rows.value(benchmark, flesh, f"+ {feature}: penetrations (all frames, audit)")
            lines.append(Line(comparison, case, f"+ {feature}", total,
                              note=f"{total / baseline:.2f}× collisions only (adds {added:+.0f} ms); "
                                   f"worst edge {worst:.3f}× rest, {found:.0f} penetrations"))

    lines.extend(character_lines(rows))
    lines.extend(scaling_lines(rows))

    # UV warp: each grid size against the seed's GPU figure.
    comparison = "UV warp, per frame (warm)"
    for n in WARP_SIZES:
        grid = rf"{n}x{n} .*"
        frame = rows.value("warp", grid, "frame (warm: surface+solve+invert)")
        reference = rows.value("warp", grid, "bandwidth reference (1 pass)")
        cpu = rows.value("warp", grid, "CPU time per frame (all threads)")
        lines.append(Line(comparison, rows.find("warp", grid, "frame (warm: surface+solve+invert)")["case"], "Tegument UV warp (CPU)",
                          frame, peak_mib=rows.value("warp", grid, "peak memory (VmHWM, whole process)"),
                          times_bandwidth=frame / reference,
                          note=f"CPU time {cpu:.0f} ms/frame; rigid stretch {rows.value('warp', grid, 'rigid stretch error, identity'):.3f} → "
                               f"{rows.value('warp', grid, 'rigid stretch error, warped'):.3f}"))
        lines.append(Line(comparison, f"{n}² grid", "seed paper, GTX Titan (published, not measured here)", SEED_GPU_WARP_MS[n],
                          note=f"warp simulation only; preprocessing {SEED_GPU_PREPROCESS_MS[n]} ms"))

    # Hot loops against the bandwidth reference of the same run (same data size, same threads).
    comparison = "hot loops vs memory-bandwidth reference"
    for size in ("10k", "100k", "1M"):
        for threads in (1, 2):
            sphere = rf"sphere {size} .*"
            lines.append(Line(comparison, rows.find("pyramid", sphere, "targets: per iteration", threads=threads)["case"],
                              f"pyramid solver iteration, {threads} thread{'s' * (threads > 1)}",
                              rows.value("pyramid", sphere, "targets: per iteration", threads=threads),
                              times_bandwidth=rows.value("pyramid", sphere, "targets: iteration / reference", threads=threads),
                              note=f"reference {rows.value('pyramid', sphere, 'targets: bandwidth reference', threads=threads):.2f} ms"))
    collide = r"skin .* vs collider .*"
    reference = rows.value("collide", collide, "bandwidth reference", threads=2)
    for metric, label in (("one in-loop pass", "collision in-loop pass, 2 threads"), ("pass 1 (swept collider)", "collision pass 1 (swept), 2 threads")):
        ms = rows.value("collide", collide, metric, threads=2)
        lines.append(Line(comparison, rows.find("collide", collide, metric)["case"], label, ms, times_bandwidth=ms / reference,
                          note=f"reference {reference:.2f} ms"))
    for n in WARP_SIZES:
        grid = rf"{n}x{n} .*"
        reference = rows.value("warp", grid, "bandwidth reference (1 pass)")
        for metric, label in (("level 0 (finest) + prolong", "UV warp finest level (4 iterations)"), ("inversion", "UV warp inversion")):
            ms = rows.value("warp", grid, metric)
            lines.append(Line(comparison, f"{n}² grid", label, ms, times_bandwidth=ms / reference, note=f"reference {reference:.2f} ms"))
    return lines


CHARACTER_CASES = {"OBJ, welded": r"MakeHuman character \(OBJ, welded\), .*",
                   "glTF round trip": r"MakeHuman character \(glTF round trip, split seams\), .*",
                   "subdivided": r"MakeHuman character \(Subdivision Surface between Armature and Tegument\), .*"}


def character_lines(rows: Rows) -> list[Line]:
    """The hard-posed MakeHuman character (bench/blender_bench.py `character`): time per frame of
    Corrective Smooth and Tegument, and at the pose's last frame the spike maximum and the
    self-intersecting face pairs of each method. One line saying why when the shared data was absent."""
    comparison = "real character, hard pose (per frame; shape figures at the last frame)"
    if not rows.value("blender", "MakeHuman character", "character: shared data"):
        note = rows.find("blender", "MakeHuman character", "character: shared data")["note"]
        return [Line(comparison, "MakeHuman character", "not measured", note=note)]
    lines = []
    for case in CHARACTER_CASES.values():
        name = rows.find("blender", case, "armature only: frame")["case"]
        tegument = next(r for r in rows.rows if r["benchmark"] == "blender" and re.fullmatch(case, r["case"])
                        and re.fullmatch(r"Tegument \(\d+ it\.\): frame", r["metric"]))

        def shape(method: str) -> str:
            return (f"spike max {rows.value('blender', case, f'{method}: spike max'):.2f}, "
                    f"{rows.value('blender', case, f'{method}: self-intersecting pairs'):.0f} self-intersecting face pairs, "
                    f"seam gap {rows.value('blender', case, f'{method}: seam gap'):.2f} mm")

        lines.append(Line(comparison, name, "armature only (skinning)", rows.value("blender", case, "armature only: frame"),
                          note=shape("skinning")))
        lines.append(Line(comparison, name, "Blender Corrective Smooth (10 it.)",
                          rows.value("blender", case, "Corrective Smooth (10 it.): frame"), note=shape("Corrective Smooth")))
        lines.append(Line(comparison, name, f"Tegument Pyramid Deform ({tegument['metric'].split(':')[0].split('(')[1]}",
                          tegument["value"],
                          note=f"{rows.value('blender', case, 'Tegument frame / Corrective Smooth frame'):.2f}× Corrective Smooth's frame; "
                               f"{rows.value('blender', case, 'pinned by bind'):.0f} vertices pinned by bind "
                               f"({rows.value('blender', case, 'split vertices'):.0f} split at seams); " + shape("Tegument")
                               + f"; convergence error, worst frame: {convergence(rows, case)}"))
        other = other_solver_line(rows, comparison, name, case)
        if other:
            lines.append(other)
    return lines


def other_solver_line(rows: Rows, comparison: str, name: str, case: str) -> Line | None:
    """The character baked with the other Converge setting in the same minutes (`blender_bench.py
    --character-both`, which `make bench` passes), or None when the run did not bake it."""
    frame = next((r for r in rows.rows if r["benchmark"] == "blender" and re.fullmatch(case, r["case"])
                  and re.fullmatch(r"Tegument \(Converge (on|off), \d+ it\.\): frame", r["metric"])), None)
    if frame is None:
        return None
    label = frame["metric"].split(":")[0].removeprefix("Tegument (").removesuffix(")")
    return Line(comparison, name, f"Tegument Pyramid Deform ({label})", frame["value"],
                note=f"{rows.value('blender', case, f'Tegument ({label}) frame / Corrective Smooth frame'):.2f}× Corrective Smooth's frame "
                     f"in the same minutes; {rows.value('blender', case, f'Tegument ({label}): iterations a frame'):.1f} iterations a frame")


def convergence(rows: Rows, case: str) -> str:
    """Issue 28's convergence error of the character's frames: the bake at the add-on's defaults
    and each frame solved by Converge from its input (bench/blender_bench.py `convergence`)."""
    baked = rows.find("blender", case, "Tegument: convergence error, worst baked frame")
    converge = rows.find("blender", case, "Tegument Converge: convergence error, worst frame")
    iterations = re.search(r"(\d+) it\.", converge["note"])
    return (f"{100 * baked['value']:.1f} % at the defaults, {100 * converge['value']:.1f} % with Converge from each frame's input"
            + (f" (at most {iterations.group(1)} it.)" if iterations else ""))


# The phases of a bake frame as BakeJob records them (addon/deform/bake.py, PhaseClock).
FRAME_PHASES = ("evaluate", "read", "solve", "write")


def scaling_lines(rows: Rows) -> list[Line]:
    """The bake loop from 100k to 5M vertices (bench/bake_scaling.py): per size, the armature alone,
    Corrective Smooth and Tegument's whole bake frame, with bind time, bind memory and the frame's
    phases; the largest size's time per vertex against the smallest's."""
    comparison = "bake loop at scale (whole frames, default iterations)"
    cases = sorted({row["case"] for row in rows.rows if row["benchmark"] == "scaling"},
                   key=lambda case: rows.value("scaling", re.escape(case), "vertices"))
    if not cases:
        raise MissingFigure("the run has no scaling rows (bench/bake_scaling.py)")
    per_vertex = {case: rows.value("scaling", re.escape(case), "Tegument frame per vertex") for case in cases}
    lines = []
    for case in cases:
        value = lambda metric: rows.value("scaling", re.escape(case), metric)  # noqa: E731
        phases = ", ".join(f"{phase} {value(f'Tegument frame: {phase}'):.1f}" for phase in FRAME_PHASES)
        rest = value("Tegument (default it.): frame") - sum(value(f"Tegument frame: {phase}") for phase in FRAME_PHASES)
        growth = "" if case == cases[0] else f" ({per_vertex[case] / per_vertex[cases[0]]:.2f}× at {cases[0].split(', ')[-1]})"
        lines += [
            Line(comparison, case, "armature only (what both start from)", value("armature only: frame")),
            Line(comparison, case, "Blender Corrective Smooth", value("Corrective Smooth (10 it.): frame")),
            Line(comparison, case, "Tegument Pyramid Deform (bake frame)", value("Tegument (default it.): frame"),
                 peak_mib=value("bind: peak memory"),
                 note=f"{value('Tegument frame / Corrective Smooth frame'):.2f}× Corrective Smooth's frame; "
                      f"{value('Tegument frame per vertex'):.0f} ns per vertex{growth}; ms: {phases}, rest {rest:.1f}; "
                      f"bind {value('bind'):.2f} s, peak memory {value('bind: peak memory per vertex'):.0f} B per vertex"),
        ]
    return lines


def number(value: float | None, digits: int = 1) -> str:
    if value is None:
        return ""
    if abs(value) >= 1000:
        return f"{value:,.0f}".replace(",", " ")
    if abs(value) >= 100 or float(value).is_integer():
        return f"{value:.0f}"
    return f"{value:.{digits}f}" if abs(value) >= 1 else f"{value:.{digits + 1}f}"


def markdown(lines: list[Line], rows: list[dict], machine: str, run: dict, plot: str | None) -> str:
    out = [
        "<!-- generated by `make bench` (bench/run_all.py → bench/collect.py); do not edit -->",
        "# Benchmark table",
        "",
        f"One `make bench` run, started {run.get('started', '?')} (UTC), {number(run.get('seconds', 0) / 60, 1)} min. "
        f"Machine: {machine}.",
        "",
        "The machine is shared with another engineer's builds and tests, so every step records the load"
        " (`uptime` before and after) and how many cores other processes kept busy meanwhile:",
        "",
        "| step | wall time | `uptime` before | `uptime` after | cores used by other processes |",
        "|---|---:|---|---|---:|",
    ]
    for step in run.get("steps", []):
        load = lambda text: text.split("load average:")[-1].strip()  # noqa: E731
        out.append(f"| {step['step']} | {number(step['seconds'])} s | {load(step['uptime_before'])} | {load(step['uptime_after'])} "
                   f"| {step['other_processes_cores']} |")
    out += [
        "",
        "Every comparison below was measured in this run, on the same mesh or grid for the methods it"
        " compares. *Vertices inside* and *edges crossing* are `tegument.audit` totals over all frames"
        " (skin edges through the collider plus collider edges through the skin). *× bandwidth* is the"
        " loop's time over a streaming pass through the same number of bytes with the same threads,"
        " measured in the same run (`rust/core/benches/common`).",
        "",
        "| comparison | mesh / grid | method | ms per frame | vertices inside | edges crossing | peak memory (MiB) | × bandwidth | note |",
        "|---|---|---|---:|---:|---:|---:|---:|---|",
    ]
    for line in lines:
        out.append(f"| {line.comparison} | {line.case} | {line.method} | {number(line.ms_per_frame, 2)} | "
                   f"{number(line.vertices_inside)} | {number(line.edges_crossing)} | {number(line.peak_mib)} | "
                   f"{number(line.times_bandwidth, 2)} | {line.note} |")
    if plot:
        out += ["", f"![The comparisons of this run]({plot})"]
    out += [
        "",
        "<details><summary>Every row of the run (bench/results.json)</summary>",
        "",
        "| benchmark | case | metric | value | unit | threads | note |",
        "|---|---|---|---:|---|---:|---|",
    ]
    for row in rows:
        value = row["value"]
        shown = "—" if value is None else f"{value:.3f}" if abs(value) < 100 else f"{value:.1f}"
        out.append(f"| {row['benchmark']} | {row['case']} | {row['metric'].strip()} | {shown} | {row['unit']} | {row['threads']} | {row['note']} |")
    out += ["", "</details>", ""]
    return "\n".join(out)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--results", type=pathlib.Path, required=True)
    parser.add_argument("--json", type=pathlib.Path, required=True)
    parser.add_argument("--markdown", type=pathlib.Path, required=True)
    parser.add_argument("--plot", help="path of the plot relative to the Markdown file, to show under the table")
    args = parser.parse_args()
    rows = []
    for name in ("pyramid", "collide", "flesh", "flesh_converge", "self_collision", "warp", "warp_convergence", "blender", "scaling"):
        path = args.results / f"{name}.json"
        if not path.exists():
            raise SystemExit(f"error: {path} is missing: the {name} benchmark did not run")
        rows.extend(json.loads(path.read_text()))
    rows = [row for row in rows if row["case"] != "machine"]  # the machine goes in the header
    machine_file = args.results / "machine.txt"
    machine = machine_file.read_text().strip().replace("\n", "; ") if machine_file.exists() else "unknown machine"
    run_file = args.results / "run.json"
    run = json.loads(run_file.read_text()) if run_file.exists() else {}
    try:
        lines = summary(Rows(rows))
    except MissingFigure as error:
        raise SystemExit(f"error: {error}: bench/collect.py must be matched to the benchmark that changed") from None
    args.json.write_text(json.dumps({"machine": machine, "run": run, "comparison": [asdict(line) for line in lines],
                                     "rows": rows}, indent=1, ensure_ascii=False) + "\n")
    args.markdown.write_text(markdown(lines, rows, machine, run, args.plot))
    print(f"wrote {args.json} and {args.markdown} ({len(lines)} comparison lines, {len(rows)} rows)")


if __name__ == "__main__":
    main()
