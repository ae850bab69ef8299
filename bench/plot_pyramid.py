"""Residual against wall time of the two pyramid-constraint formulations.

Reads the rows `cargo bench -p tegument-core --bench pyramid` wrote to
bench/results/pyramid.json ("<formulation>: curve k=<iterations>", value =
mean residual in rest edge lengths, note = "<ms> ms" with 2 threads) and draws
docs/images/pyramid-solver-residual.png for docs/design/pyramid-solver.md.

    .venv/bin/python bench/plot_pyramid.py [--results bench/results/pyramid.json] [--out docs/images/pyramid-solver-residual.png]
"""

from __future__ import annotations

import argparse
import json
import pathlib
import re
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

ROOT = pathlib.Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--results", default=ROOT / "bench" / "results" / "pyramid.json", type=pathlib.Path)
    parser.add_argument("--out", default=ROOT / "docs" / "images" / "pyramid-solver-residual.png", type=pathlib.Path)
    args = parser.parse_args()
    rows = json.loads(args.results.read_text())

    curves: dict[tuple[str, str], list[tuple[float, float, int]]] = {}
    start: dict[str, float] = {}
    for row in rows:
        if row["metric"] == "residual of the LBS input":
            start[row["case"]] = row["value"]
        match = re.fullmatch(r"(\w+): curve k=(\d+)", row["metric"])
        if match:
            ms = float(row["note"].split()[0])
            curves.setdefault((row["case"], match[1]), []).append((ms, row["value"], int(match[2])))

    cases = sorted({case for case, _ in curves}, key=lambda c: int(re.search(r"\((\d+) v\)", c)[1]))
    fig, axes = plt.subplots(1, len(cases), figsize=(5.5 * len(cases), 4.2), squeeze=False)
    styles = {"targets": ("tab:blue", "o", "per-vertex targets (Jacobi)"), "laplacian": ("tab:red", "s", "linearised Laplacian rows (Cholesky)")}
    for ax, case in zip(axes[0], cases):
        for formulation, (color, marker, label) in styles.items():
            points = sorted(curves.get((case, formulation), []), key=lambda p: p[2])
            if not points:
                continue
            ax.plot([p[0] for p in points], [p[1] for p in points], marker=marker, color=color, label=label)
            for ms, residual, k in points:
                ax.annotate(str(k), (ms, residual), textcoords="offset points", xytext=(3, 4), fontsize=7, color=color)
        if case in start:
            ax.axhline(start[case], color="gray", linestyle="--", linewidth=1, label="LBS input")
        ax.set_xscale("log")
        ax.set_xlabel("wall time per solve, ms (2 threads; labels = iterations)")
        ax.set_ylabel("mean pyramid residual / mean rest edge")
        ax.set_title(case)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle("Pyramid constraint: residual against wall time, closeness 0.1")
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=110)
    sys.path.insert(0, str(ROOT / "tools"))
    from docs_pictures import shrink  # a palette PNG: docs/images stays small

    shrink(args.out, args.out, 64)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
