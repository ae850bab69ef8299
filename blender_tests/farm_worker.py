"""A Flamenco worker's Blender, played by the PyPI ``bpy`` module: runs one command line in a fresh process.

    BLENDER_USER_RESOURCES=DIR python farm_worker.py [-b] [-y] FILE.blend --command tegument ARGS…

takes the command line a worker gives Blender for a ``blender-render`` command (``{blender}
{blenderArgs} argsBefore… blendfile args…``) and does what Blender does with it: opens FILE.blend,
then runs the ``tegument`` command with ARGS, and exits with its code. The extension must be
installed in ``BLENDER_USER_RESOURCES`` already (the test session's folder, where conftest
installed the built zip); this process only enables it, as a worker's Blender would on start-up.

``TEGUMENT_TEST_KILL_AFTER=N`` (a test hook standing in for a worker that dies) makes the process
kill itself with SIGKILL when the bake's N-th progress line is printed: no clean-up runs at all.
"""

from __future__ import annotations

import os
import pathlib
import signal
import sys

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "demo"))

import bpy  # noqa: E402  (BLENDER_USER_RESOURCES is read when bpy starts)

import extension  # noqa: E402  (demo/extension.py)

FLAGS = {"-b", "--background", "-y", "--enable-autoexec"}


def parse(argv: list[str]) -> tuple[str, list[str]]:
    """``(blend file, the tegument command's arguments)`` from Blender's command line."""
    args = list(argv)
    while args and args[0] in FLAGS:
        args.pop(0)
    if not args or args[0].startswith("-"):
        sys.exit(f"farm_worker: no .blend file on the command line: {argv}")
    blendfile = args.pop(0)
    if args[:2] != ["--command", "tegument"]:
        sys.exit(f"farm_worker: expected `--command tegument …` after the .blend, got {args}")
    return blendfile, args[2:]


def kill_after(count: int) -> None:
    """Dies (SIGKILL) at the ``count``-th progress line of a bake, like a worker losing power."""
    real = sys.stdout

    class Counting:
        seen = 0

        def write(self, text):
            written = real.write(text)
            if " frame " in text and "ETA" in text:
                Counting.seen += 1
                if Counting.seen >= count:
                    real.flush()
                    os.kill(os.getpid(), signal.SIGKILL)
            return written

        def __getattr__(self, name):
            return getattr(real, name)

    sys.stdout = Counting()


def main() -> int:
    blendfile, command = parse(sys.argv[1:])
    user_resources = os.environ.get("BLENDER_USER_RESOURCES")
    if not user_resources:
        sys.exit("farm_worker: BLENDER_USER_RESOURCES is not set: it names the folder the extension is installed in")
    # What Blender does on start-up for an installed extension: its wheels first on sys.path, then enable it.
    sys.path.insert(0, str(extension.bundled_site_packages(user_resources)))
    bpy.ops.preferences.addon_enable(module=extension.ADDON_MODULE)
    if not os.path.isfile(blendfile):
        print(f"Error: Cannot read file \"{os.path.abspath(blendfile)}\": No such file or directory", file=sys.stderr)
        return 1
    bpy.ops.wm.open_mainfile(filepath=blendfile)
    if os.environ.get("TEGUMENT_TEST_KILL_AFTER"):
        kill_after(int(os.environ["TEGUMENT_TEST_KILL_AFTER"]))
    import importlib

    cli = importlib.import_module(f"{extension.ADDON_MODULE}.cli")
    return cli.main(command)


if __name__ == "__main__":
    code = main()
    sys.stdout.flush()
    sys.exit(code)
