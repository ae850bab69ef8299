"""`make bench`: every benchmark in one run, then one table.

Steps, in order, each as a child process: build the Rust benchmarks; the pyramid solver, collision,
flesh (dynamics, strain limits, compliant colliders), UV warp and UV warp convergence benchmarks (``rust/core/benches``, rows in ``bench/results/<name>.json``); the Blender
benchmark (``bench/blender_bench.py``: collisions against Cloth and Shrinkwrap + Corrective Smooth,
the MakeHuman character with Converge on and off, in real Blender with the built extension); the bake loop at scale
(``bench/bake_scaling.py``: Pyramid Deform against Corrective Smooth from 100k to 5M vertices). Then
``bench/collect.py`` merges the rows into ``bench/results.json`` and ``docs/performance-table.md``
and ``bench/plot_bench.py`` draws ``docs/images/benchmark.png``, ``bench/plot_warp_convergence.py``
``docs/images/uv-warp-convergence.png``.

The machine may be shared, so each step records its wall time, ``uptime`` before and after, and
how many cores *other* processes kept busy meanwhile (all CPU time the kernel counted, minus this
run's own), into ``bench/results/run.json``; the table's header shows them.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import pathlib
import resource
import subprocess
import sys
import time

HERE = pathlib.Path(__file__).resolve().parent
ROOT = HERE.parent


def busy_cpu_seconds() -> float:
    """CPU seconds every process on the machine has used since boot (busy states of /proc/stat)."""
    fields = pathlib.Path("/proc/stat").read_text().splitlines()[0].split()[1:]
    user, nice, system, _idle, _iowait, irq, softirq, steal = (int(x) for x in fields[:8])
    return (user + nice + system + irq + softirq + steal) / os.sysconf("SC_CLK_TCK")


def own_cpu_seconds() -> float:
    """CPU seconds of this process and of every child it has waited for (the benchmarks)."""
    total = 0.0
    for who in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN):
        usage = resource.getrusage(who)
        total += usage.ru_utime + usage.ru_stime
    return total


def uptime() -> str:
    try:
        return subprocess.run(["uptime"], capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "load average: " + ", ".join(f"{x:.2f}" for x in os.getloadavg())


def run_step(name: str, command: list[str], env: dict[str, str]) -> dict:
    print(f"[bench] {name}: {' '.join(command)}", flush=True)
    record = {"step": name, "command": " ".join(command), "uptime_before": uptime()}
    busy, own, started = busy_cpu_seconds(), own_cpu_seconds(), time.perf_counter()
    result = subprocess.run(command, cwd=ROOT, env={**os.environ, **env})
    wall = time.perf_counter() - started
    others = (busy_cpu_seconds() - busy) - (own_cpu_seconds() - own)
    record.update(
        seconds=round(wall, 1), uptime_after=uptime(), exit_code=result.returncode,
        # Clock ticks are 10 ms and the two counters are read at slightly different times: a
        # small negative remainder means "nothing else ran".
        other_processes_cores=round(max(others, 0.0) / wall, 2) if wall > 0 else None,
    )
    print(f"[bench] {name}: {wall:.0f} s, other processes kept {record['other_processes_cores']} cores busy", flush=True)
    return record


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--zip", type=pathlib.Path, default=os.environ.get("TEGUMENT_EXTENSION_ZIP"),
                        help="the built extension (the Makefile passes it)")
    parser.add_argument("--results", type=pathlib.Path, default=HERE / "results")
    parser.add_argument("--json", type=pathlib.Path, default=HERE / "results.json")
    parser.add_argument("--markdown", type=pathlib.Path, default=ROOT / "docs" / "performance-table.md")
    parser.add_argument("--plot", type=pathlib.Path, default=ROOT / "docs" / "images" / "benchmark.png")
    args = parser.parse_args()
    if not args.zip or not args.zip.is_file():
        sys.exit("error: no extension zip: run `make bench`, which builds it (or pass --zip)")
    args.results.mkdir(parents=True, exist_ok=True)
    python = sys.executable
    results_env = {"TEGUMENT_BENCH_DIR": str(args.results.resolve())}
    cargo = ["cargo", "bench", "-p", "tegument-core"]
    steps = [
        # Compiled first, so no benchmark is timed while its successors compile.
        ("build", cargo + ["--no-run", "--bench", "pyramid", "--bench", "convergence", "--bench", "collide", "--bench", "flesh",
                           "--bench", "warp", "--bench", "warp_convergence", "--bench", "self_collision"], {}),
        ("pyramid", cargo + ["--bench", "pyramid"], results_env),
        ("convergence", cargo + ["--bench", "convergence"], results_env),
        ("collide", cargo + ["--bench", "collide"], results_env),
        ("flesh", cargo + ["--bench", "flesh"], results_env),
        # Issue 29: the same rows at the add-on's default solver (Converge), where the strain rounds
        # and compliant recessions run in the iterations that close the solve.
        ("flesh_converge", cargo + ["--bench", "flesh"], {**results_env, "TEGUMENT_BENCH_FLESH_SOLVER": "converge"}),
        ("self_collision", cargo + ["--bench", "self_collision"], results_env),
        ("warp", cargo + ["--bench", "warp"], {**results_env, "TEGUMENT_WARP_SIZES": "1024,2048,4096"}),
        # Issue 28: the old and the new UV warp solver, cold and warm, in one run (long: the
        # fold sweep solves 4096² from the identity 64 times).
        ("warp_convergence", cargo + ["--bench", "warp_convergence"], results_env),
        # Issue 28: the character baked with Converge on and off, each against Corrective Smooth in
        # the same minutes, so the table shows what the solver setting costs on a real character.
        ("blender", [python, str(HERE / "blender_bench.py"), "--out", str(args.results), "--zip", str(args.zip),
                     "--character-both"], {}),
        ("scaling", [python, str(HERE / "bake_scaling.py"), "--out", str(args.results), "--zip", str(args.zip)], {}),
    ]
    run = {"started": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"), "steps": []}
    started = time.perf_counter()
    for name, command, env in steps:
        record = run_step(name, command, env)
        run["steps"].append(record)
        (args.results / "run.json").write_text(json.dumps(run, indent=1))
        if record["exit_code"] != 0:
            print(f"error: benchmark step {name} failed (exit code {record['exit_code']}); nothing was collected",
                  file=sys.stderr)
            return 1
    run["seconds"] = round(time.perf_counter() - started, 1)
    (args.results / "run.json").write_text(json.dumps(run, indent=1))
    for command in (
        [python, str(HERE / "collect.py"), "--results", str(args.results), "--json", str(args.json), "--markdown", str(args.markdown),
         "--plot", os.path.relpath(args.plot, args.markdown.parent)],
        [python, str(HERE / "plot_bench.py"), "--results", str(args.json), "--out", str(args.plot)],
        [python, str(HERE / "plot_convergence.py"), "--results", str(args.results / "convergence.json"),
         "--out", str(args.plot.parent / "pyramid-convergence.png")],
        [python, str(HERE / "plot_warp_convergence.py"), "--results", str(args.results / "warp_convergence_curves.json"),
         "--out", str(args.plot.parent / "uv-warp-convergence.png")],
    ):
        if subprocess.run(command, cwd=ROOT).returncode != 0:
            return 1
    print(f"[bench] done in {run['seconds'] / 60:.1f} min: {args.json}, {args.markdown}, {args.plot}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
