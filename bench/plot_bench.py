"""Draws the comparisons of one `make bench` run (``bench/results.json``) as ``docs/images/benchmark.png``.

Four panels, the same figures as the table in ``docs/performance-table.md``: the deformer against
Corrective Smooth, collisions against Cloth and Shrinkwrap + Corrective Smooth (time per frame,
with the audit counts written on the bars), the UV warp per grid size against the seed's published
GPU figures, and each hot loop as a multiple of the bandwidth reference.

    .venv/bin/python bench/plot_bench.py [--results bench/results.json] [--out docs/images/benchmark.png]
"""

from __future__ import annotations

import argparse
import io
import json
import pathlib

import matplotlib
from PIL import Image  # matplotlib's own dependency

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

ROOT = pathlib.Path(__file__).resolve().parents[1]
TEGUMENT, BLENDER, PUBLISHED = "tab:orange", "tab:blue", "tab:gray"


def colour(method: str) -> str:
    if method.startswith("Tegument"):
        return TEGUMENT
    return PUBLISHED if method.startswith("seed") or method.startswith("armature") else BLENDER


def short(method: str) -> str:
    """A method's name on two short lines, for a bar label."""
    return (method.replace("Blender ", "").replace("Tegument Pyramid Deform", "Pyramid Deform")
            .replace(" pinned to the animation, collision quality 5", "\n(pinned, quality 5)")
            .replace(" + Corrective Smooth", "\n+ Corrective Smooth").replace(" + collisions", "\n+ collisions")
            .replace(" (what both start from)", "").replace(" (10 it.)", ""))


def loop_label(line: dict) -> str:
    """``<loop> · <size>`` in a few words: the hot-loop panel has many bars."""
    method, case = line["method"], line["case"]
    size = case.split(" (")[0].replace("sphere ", "") if case.startswith("sphere") else case.split(" grid")[0]
    if case.startswith("skin"):
        size = f"{int(case.split()[1]) // 1000}k"
    threads = "2 thr" if "2 threads" in method else "1 thr" if "1 thread" in method else ""
    name = ("pyramid iteration" if method.startswith("pyramid") else "collision in-loop pass" if "in-loop" in method
            else "collision pass 1" if "pass 1" in method else "warp finest level" if "finest" in method
            else "warp inversion" if "inversion" in method else method)
    return " · ".join(part for part in (name, threads, size) if part)


def seconds_or_ms(ms: float) -> str:
    return f"{ms / 1000:.1f} s" if ms >= 1000 else f"{ms:.0f} ms"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--results", type=pathlib.Path, default=ROOT / "bench" / "results.json")
    parser.add_argument("--out", type=pathlib.Path, default=ROOT / "docs" / "images" / "benchmark.png")
    args = parser.parse_args()
    data = json.loads(args.results.read_text())
    lines = data["comparison"]
    group = lambda prefix: [line for line in lines if line["comparison"].startswith(prefix)]  # noqa: E731

    fig, axes = plt.subplots(2, 2, figsize=(11, 7.6), layout="constrained")
    (deform, collide), (warp, loops) = axes

    rows = group("deformer")
    deform.barh([short(r["method"]) for r in rows], [r["ms_per_frame"] for r in rows], color=[colour(r["method"]) for r in rows])
    for k, r in enumerate(rows):
        deform.annotate(f"{r['ms_per_frame']:.1f} ms", (r["ms_per_frame"], k), xytext=(3, 0), textcoords="offset points", va="center", fontsize=8)
    deform.invert_yaxis()
    deform.set_xlabel("ms per frame")
    deform.set_title(f"Deformer, 10 iterations: {rows[0]['case']}", fontsize=9)

    rows = group("collisions")
    collide.barh([short(r["method"]) for r in rows], [r["ms_per_frame"] for r in rows], color=[colour(r["method"]) for r in rows])
    for k, r in enumerate(rows):
        collide.annotate(f"{seconds_or_ms(r['ms_per_frame'])}\n{r['vertices_inside']:.0f} inside, {r['edges_crossing']:.0f} crossing",
                         (r["ms_per_frame"], k), xytext=(3, 0), textcoords="offset points", va="center", fontsize=8)
    collide.invert_yaxis()
    collide.set_xlim(0, 1.6 * max(r["ms_per_frame"] for r in rows))
    collide.set_xlabel("ms per frame; audit counts over all frames")
    collide.set_title(f"Collisions: {rows[0]['case']}", fontsize=9)

    rows = group("UV warp")
    for method, style in (("Tegument", "o-"), ("seed", "s--")):
        points = [r for r in rows if r["method"].startswith(method)]
        sizes = [int(r["case"].split("x")[0].split("²")[0]) for r in points]
        label = "Tegument, CPU (this run)" if method == "Tegument" else "seed paper, GTX Titan (published)"
        warp.plot(sizes, [r["ms_per_frame"] for r in points], style, color=colour(points[0]["method"]), label=label)
        for n, r in zip(sizes, points):
            text = f"{r['ms_per_frame']:.0f} ms" + (f", {r['peak_mib']:.0f} MiB" if r["peak_mib"] else "")
            warp.annotate(text, (n, r["ms_per_frame"]), xytext=(4, -10 if method == "seed" else 4), textcoords="offset points", fontsize=8)
    warp.set_xscale("log", base=2)
    warp.set_yscale("log")
    warp.set_xticks([1024, 2048, 4096], ["1024²", "2048²", "4096²"])
    warp.set_xlim(800, 7000)
    top = max(r["ms_per_frame"] for r in rows)
    warp.set_ylim(min(r["ms_per_frame"] for r in rows) / 2, top * 4)
    warp.set_ylabel("ms per frame")
    warp.set_title("UV warp per frame (warm), peak memory", fontsize=9)
    warp.legend(fontsize=8, loc="upper left")
    warp.grid(True, which="both", alpha=0.3)

    rows = group("hot loops")
    labels = [loop_label(r) for r in rows]
    loops.barh(labels, [r["times_bandwidth"] for r in rows], color=TEGUMENT)
    loops.axvline(1.0, color="black", linewidth=0.8)
    loops.set_xscale("log")
    loops.invert_yaxis()
    loops.tick_params(axis="y", labelsize=7)
    loops.set_xlabel("time ÷ bandwidth reference (1 = one streaming pass over its data)")
    loops.set_title("Hot loops ÷ bandwidth reference of the same run", fontsize=9)

    fig.suptitle(f"make bench, {data['run'].get('started', '')[:16].replace('T', ' ')} UTC — {data['machine']}", fontsize=9)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    # A flat-coloured chart needs few colours: a palette PNG is a third of the size (docs/images stays small).
    buffer = io.BytesIO()
    fig.savefig(buffer, dpi=80, bbox_inches="tight")
    buffer.seek(0)
    Image.open(buffer).convert("RGB").quantize(colors=64).save(args.out, optimize=True)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
