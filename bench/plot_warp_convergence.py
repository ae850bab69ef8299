"""Convergence error against time of cold UV warp solves, old solver against new (issue 28).

Reads bench/results/warp_convergence_curves.json (written by
`cargo bench -p tegument-core --bench warp_convergence`: per grid and solver, the cold solves'
iteration counts, wall times, rigid stretch errors and convergence errors against the converged
warp, the finest level's fixed point) and draws docs/images/uv-warp-convergence.png: convergence
error (left) and rigid stretch error (right) against wall time, log scales, one colour per grid,
old (the cascade: iterations per level) dashed, new (multigrid: cycles) solid, each solver's
default count marked.

    .venv/bin/python bench/plot_warp_convergence.py [--results bench/results/warp_convergence_curves.json] [--out docs/images/uv-warp-convergence.png]
"""

from __future__ import annotations

import argparse
import json
import pathlib

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

ROOT = pathlib.Path(__file__).resolve().parents[1]
COLOURS = {256: "tab:purple", 1024: "tab:blue", 2048: "tab:orange", 4096: "tab:green"}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--results", default=ROOT / "bench" / "results" / "warp_convergence_curves.json", type=pathlib.Path)
    parser.add_argument("--out", default=ROOT / "docs" / "images" / "uv-warp-convergence.png", type=pathlib.Path)
    args = parser.parse_args()
    curves = json.loads(args.results.read_text())
    fig, (left, right) = plt.subplots(1, 2, figsize=(12, 4.8))
    for c in curves:
        colour = COLOURS.get(c["grid"], "black")
        style = "--" if c["solver"] == "old" else "-"
        label = f"{c['grid']}², {c['solver']} solver"
        seconds = [ms / 1e3 for ms in c["ms"]]
        left.plot(seconds, c["convergence_error"], style, marker="o", markersize=3, color=colour, label=label)
        right.plot(seconds, c["rigid_stretch"], style, marker="o", markersize=3, color=colour, label=label)
        right.axhline(c["converged_rigid_stretch"], color=colour, linestyle=style, linewidth=0.6, alpha=0.6)
        at = c["iterations"].index(c.get("default", 4))
        for axis, values in ((left, c["convergence_error"]), (right, c["rigid_stretch"])):
            axis.plot([seconds[at]], [values[at]], marker="s", markersize=8, markerfacecolor="none", color=colour)
        for k, x, y in zip(c["iterations"], seconds, c["convergence_error"]):
            if k in (1, 4, 16, 64):
                left.annotate(str(k), (x, y), textcoords="offset points", xytext=(3, 3), fontsize=7, color=colour)
    left.set(xscale="log", yscale="log", xlabel="cold solve wall time (s, 2 threads, shared machine)",
             ylabel="convergence error  RMS|r_k − r_∞| / RMS|r_∞ − id|",
             title="Convergence error (labels: iterations or cycles; square: default)")
    right.set(xscale="log", xlabel="cold solve wall time (s)", ylabel="rigid stretch error (mean)",
              title="Rigid stretch error; thin lines: the converged warp")
    for axis in (left, right):
        axis.grid(True, which="both", alpha=0.3)
    right.legend(fontsize=8)
    fig.suptitle("UV warp, cold solves of the benchmark cylinder at its strongest bend: cascade (dashed) and multigrid (solid)")
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=110)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
