"""Builds the Blender extension zip with Blender's own extension builder.

Copies the built wheel into ``addon/wheels``, checks that the manifest lists
exactly that file, and runs ``blender_ext.py build --split-platforms`` from
the installed ``bpy`` package (no Blender executable needed).
"""

from __future__ import annotations

import argparse
import pathlib
import shutil
import subprocess
import sys
import sysconfig
import tomllib


def blender_ext_script() -> pathlib.Path:
    # The PyPI bpy package ships Blender's scripts in site-packages/bpy/<version>/.
    root = pathlib.Path(sysconfig.get_paths()["purelib"]) / "bpy"
    scripts = sorted(root.glob("*/scripts/addons_core/bl_pkg/cli/blender_ext.py"))
    if not scripts:
        sys.exit(f"error: blender_ext.py not found under {root}")
    return scripts[-1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--wheels", type=pathlib.Path, required=True)
    parser.add_argument("--addon", type=pathlib.Path, required=True)
    parser.add_argument("--out", type=pathlib.Path, required=True)
    args = parser.parse_args()

    wheels = sorted(args.wheels.glob("tegument-*-cp311-abi3-manylinux_*_x86_64.whl"))
    if len(wheels) != 1:
        sys.exit(f"error: expected one abi3 manylinux wheel in {args.wheels}, found {[w.name for w in wheels]}")
    wheel = wheels[0]

    manifest = tomllib.loads((args.addon / "blender_manifest.toml").read_text())
    listed = manifest.get("wheels", [])
    if listed != [f"./wheels/{wheel.name}"]:
        sys.exit(
            f"error: blender_manifest.toml lists wheels {listed}, but the build produced {wheel.name}; "
            "update the manifest (version and platform tag come from Cargo.toml and pyproject.toml)"
        )

    target = args.addon / "wheels"
    shutil.rmtree(target, ignore_errors=True)
    target.mkdir(parents=True)
    shutil.copy2(wheel, target / wheel.name)

    args.out.mkdir(parents=True, exist_ok=True)
    command = [
        sys.executable, str(blender_ext_script()), "build",
        "--source-dir", str(args.addon), "--output-dir", str(args.out), "--split-platforms",
    ]
    subprocess.run(command, check=True)
    zip_name = f"{manifest['id']}-{manifest['version']}-linux_x64.zip"
    if not (args.out / zip_name).is_file():
        sys.exit(f"error: the extension builder did not write {args.out / zip_name}")
    print(f"extension: {args.out / zip_name}")


if __name__ == "__main__":
    main()
