"""Convergence error against wall time of the Pyramid Deform solve, plain against accelerated (issue 28).

Reads the rows `cargo bench -p tegument-core --bench convergence` wrote to
bench/results/convergence.json ("<solver>: curve k=<iterations>", value = convergence error, note =
"<ms> ms" with 2 threads), and the add-on's Converge ("Converge: convergence error", note
"<ms> ms, <k> iterations": where its stopping rule ended), and draws one panel per case (cold and
warm) into docs/images/pyramid-convergence.png.

    .venv/bin/python bench/plot_convergence.py [--results bench/results/convergence.json] [--out docs/images/pyramid-convergence.png]
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
    parser.add_argument("--results", default=ROOT / "bench" / "results" / "convergence.json", type=pathlib.Path)
    parser.add_argument("--out", default=ROOT / "docs" / "images" / "pyramid-convergence.png", type=pathlib.Path)
    args = parser.parse_args()
    rows = json.loads(args.results.read_text())
    curves: dict[tuple[str, str], list[tuple[float, float, int]]] = {}
    defaults: dict[str, tuple[float, float, int]] = {}
    for row in rows:
        if row["metric"] == "Converge: convergence error" and row["value"] is not None:
            ms, iterations = re.fullmatch(r"([\d.]+) ms, (\d+) iterations", row["note"]).groups()
            defaults[row["case"]] = (float(ms), row["value"], int(iterations))
        match = re.fullmatch(r"(\w+): curve k=(\d+)", row["metric"])
        if match and row["value"] is not None:
            curves.setdefault((row["case"], match[1]), []).append((float(row["note"].split()[0]), row["value"], int(match[2])))
    cases = list(dict.fromkeys(case for case, _ in curves))
    columns = 2
    lines = (len(cases) + columns - 1) // columns
    fig, axes = plt.subplots(lines, columns, figsize=(5.5 * columns, 3.8 * lines), squeeze=False)
    styles = {"plain": ("tab:blue", "o", "plain iterations (the default)"),
              "accelerated": ("tab:red", "s", "accelerated: multilevel + Chebyshev, fixed count")}
    for ax, case in zip(axes.flat, cases):
        for solver, (color, marker, label) in styles.items():
            points = sorted(curves.get((case, solver), []), key=lambda p: p[2])
            if not points:
                continue
            ax.plot([p[0] for p in points], [max(p[1], 1e-5) for p in points], marker=marker, color=color, label=label)
            for ms, error, k in points:
                ax.annotate(str(k), (ms, max(error, 1e-5)), textcoords="offset points", xytext=(3, 4), fontsize=7, color=color)
        if case in defaults:
            ms, error, k = defaults[case]
            ax.plot([ms], [max(error, 1e-5)], marker="*", markersize=13, color="black", linestyle="none",
                    label="Converge (add-on): stopped at its tolerance")
            ax.annotate(f"{k} it.", (ms, max(error, 1e-5)), textcoords="offset points", xytext=(6, -10), fontsize=7)
        ax.axhline(0.05, color="gray", linestyle="--", linewidth=1, label="5% target")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("wall time per solve, ms (2 threads, shared machine; labels = iterations)")
        ax.set_ylabel("convergence error")
        ax.set_title(case, fontsize=9)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    for ax in list(axes.flat)[len(cases):]:
        ax.set_visible(False)
    fig.suptitle("Pyramid Deform: convergence error against time")
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=100)
    sys.path.insert(0, str(ROOT / "tools"))
    from docs_pictures import shrink  # a palette PNG: docs/images stays small

    shrink(args.out, args.out, 64)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
