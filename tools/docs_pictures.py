"""Copies the pictures of a `make demo` run into docs/images, small enough to keep in the repository.

Renders become palette PNGs (a few dozen kilobytes each instead of a few hundred): the pictures in
docs/ are the demo's own output, not retouched, only stored with fewer colours. Run after the demo::

    make docs-pictures        # = make demo, then this script on out/demo
"""

from __future__ import annotations

import argparse
import pathlib
import sys

from PIL import Image  # comes with matplotlib (requirements-dev.txt)

ROOT = pathlib.Path(__file__).resolve().parent.parent

# demo output → (docs picture, colours). The heat map is a smooth ramp: fewer colours suffice.
PICTURES = {
    "pyramid_deform_before_after.png": ("pyramid_deform_before_after.png", 128),
    "collisions_before_after.png": ("collisions_before_after.png", 128),
    "uv_warp_before_after.png": ("uv_warp_demo_before_after.png", 128),
    "uv_warp_heat_map.png": ("uv_warp_heat_map.png", 64),
    # matplotlib plots: flat colours and anti-aliased lines; the strain picture's colour map needs more.
    "flesh_dynamics.png": ("flesh_dynamics.png", 64),
    "flesh_compliance.png": ("flesh_compliance.png", 64),
    "flesh_strain.png": ("flesh_strain.png", 128),
    # The MakeHuman character (demo/character_demo.py): renders in matplotlib frames, and the heat map.
    "character_before_after.png": ("character_before_after.png", 128),
    "character_spike_heat_map.png": ("character_spike_heat_map.png", 128),
    # The tube bent 150°, cut open: skinning, Pyramid Deform without and with Self Collision.
    "self_collision_before_after.png": ("self_collision_before_after.png", 128),
}


def shrink(source: pathlib.Path, target: pathlib.Path, colours: int) -> int:
    """Writes `source` as an optimised palette PNG of at most `colours` colours; returns its size."""
    with Image.open(source) as image:
        image.convert("RGB").quantize(colors=colours, dither=Image.Dither.FLOYDSTEINBERG).save(target, optimize=True)
    return target.stat().st_size


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--demo", type=pathlib.Path, default=ROOT / "out" / "demo")
    parser.add_argument("--out", type=pathlib.Path, default=ROOT / "docs" / "images")
    args = parser.parse_args(argv)
    missing = [name for name in PICTURES if not (args.demo / name).is_file()]
    if missing:
        print(f"error: {args.demo} lacks {', '.join(missing)}: run `make demo` first", file=sys.stderr)
        return 1
    args.out.mkdir(parents=True, exist_ok=True)
    for name, (target, colours) in PICTURES.items():
        size = shrink(args.demo / name, args.out / target, colours)
        print(f"{args.out / target}: {size / 1024:.0f} KiB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
