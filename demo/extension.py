"""The built extension, installed into the running Blender the way a user's Blender installs it.

Shared by the demo, the benchmarks, the documentation pictures and the Blender tests, which all run
the PyPI ``bpy`` module from the project's virtual environment. That environment may hold a copy of
the ``tegument`` wheel too (the wheel's own tests need it), and its site-packages comes before the
extension's on ``sys.path``: without care, Blender would run that copy instead of the one the
extension bundles.
"""

from __future__ import annotations

import os
import pathlib
import sys
import tempfile

ADDON_MODULE = "bl_ext.user_default.tegument"


def isolated_user_folder(prefix: str) -> str:
    """A new temporary folder made Blender's user folder (``BLENDER_USER_RESOURCES``), so that
    installing the extension leaves the user's own Blender untouched. Blender reads the variable
    when ``bpy`` starts: call this before the first ``import bpy``. The caller removes the folder."""
    if "bpy" in sys.modules:
        raise RuntimeError("bpy was imported before its user folder was set: Blender would use the user's own")
    user = tempfile.mkdtemp(prefix=prefix)
    os.environ["BLENDER_USER_RESOURCES"] = user
    return user


def new_blend(path: str | pathlib.Path) -> None:
    """An empty scene with the add-on enabled, saved as ``path`` first, so that the add-on's ``//``
    paths (its caches) land beside it."""
    import bpy

    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.preferences.addon_enable(module=ADDON_MODULE)
    # Factory settings bring back .blend1 backups; these scripts save their files again at the end.
    bpy.context.preferences.filepaths.save_version = 0
    pathlib.Path(path).parent.mkdir(parents=True, exist_ok=True)
    bpy.ops.wm.save_as_mainfile(filepath=str(path))


def bundled_site_packages(user_resources: str | pathlib.Path) -> pathlib.Path:
    """Where Blender unpacks the wheels of extensions installed into ``user_resources``."""
    return pathlib.Path(user_resources, "extensions", ".local", "lib", "python3.11", "site-packages")


def install(zip_path: str | pathlib.Path, user_resources: str | pathlib.Path) -> str:
    """Installs and enables the extension zip; returns the add-on's module name.

    ``user_resources`` is the folder ``BLENDER_USER_RESOURCES`` named before ``bpy`` was imported.
    Afterwards ``import tegument`` (in the add-on and in the caller) is the wheel the extension
    bundles; a RuntimeError says what went wrong otherwise.
    """
    import bpy

    zip_path = pathlib.Path(zip_path).resolve()
    result = bpy.ops.extensions.package_install_files(filepath=str(zip_path), repo="user_default", enable_on_install=True)
    if result != {"FINISHED"}:
        raise RuntimeError(f"installing {zip_path} failed: {result}")
    if ADDON_MODULE not in bpy.context.preferences.addons:
        raise RuntimeError(f"{zip_path} installed but the add-on {ADDON_MODULE} is not enabled")
    bundled = bundled_site_packages(user_resources)
    if not (bundled / "tegument").is_dir():
        raise RuntimeError(f"the extension's wheel was not unpacked into {bundled}")
    sys.path.insert(0, str(bundled))
    # The add-on imports tegument lazily; forget any copy imported before this point.
    for name in [n for n in sys.modules if n == "tegument" or n.startswith("tegument.")]:
        del sys.modules[name]
    import tegument

    if not pathlib.Path(tegument.__file__).is_relative_to(bundled):
        raise RuntimeError(f"tegument is imported from {tegument.__file__}, not from the extension's {bundled}")
    return ADDON_MODULE
