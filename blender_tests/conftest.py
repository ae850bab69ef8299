"""Real Blender (the PyPI ``bpy`` module) with the *built* Tegument extension.

The extension zip is installed exactly as a user's Blender would install it
(``extensions.package_install_files``), into a user folder that exists only
for this test session: ``BLENDER_USER_RESOURCES`` must point there before
``bpy`` is imported, which is why it is set at the top of this file.
"""

from __future__ import annotations

import atexit
import os
import pathlib
import shutil
import tempfile

ROOT = pathlib.Path(__file__).resolve().parent.parent
SHARED_DATA = ROOT.parent / "shared" / "data"

_user_resources = tempfile.mkdtemp(prefix="tegument-blender-user-")
os.environ["BLENDER_USER_RESOURCES"] = _user_resources
atexit.register(shutil.rmtree, _user_resources, ignore_errors=True)

import sys  # noqa: E402

import bpy  # noqa: E402  (must follow BLENDER_USER_RESOURCES)
import pytest  # noqa: E402

sys.path.insert(0, str(ROOT / "demo"))  # the procedural scenes are shared with the demo
sys.path.insert(0, str(ROOT / "testkit"))  # the independent penetration checker

import extension  # noqa: E402  (demo/extension.py)

ADDON_MODULE = extension.ADDON_MODULE


def pytest_configure(config):
    # As in the wheel's tests: the add-on and these tests use the current API;
    # a deprecated spelling fails here instead of warning.
    config.addinivalue_line("filterwarnings", "error:.*is deprecated and goes away:DeprecationWarning")


def _extension_zip() -> pathlib.Path:
    given = os.environ.get("TEGUMENT_EXTENSION_ZIP")
    candidates = [pathlib.Path(given)] if given else sorted((ROOT / "dist").glob("tegument-*-linux_x64.zip"))
    if not candidates or not candidates[-1].is_file():
        pytest.exit("no built extension zip: run `make extension` (or `make test`, which builds it)", returncode=2)
    return candidates[-1].resolve()


@pytest.fixture(scope="session", autouse=True)
def installed_extension() -> str:
    """Installs the built zip once per session and returns the add-on module name."""
    zip_path = _extension_zip()
    module = extension.install(zip_path, _user_resources)
    installed = pathlib.Path(_user_resources, "extensions", "user_default", "tegument")
    assert (installed / "blender_manifest.toml").is_file(), f"not installed into the isolated user folder {installed}"
    # The test runner's own environment may have the wheel installed too (the
    # wheel's tests need it); Blender must use the copy the extension bundles.
    import tegument

    bundled = extension.bundled_site_packages(_user_resources)
    assert pathlib.Path(tegument.__file__).is_relative_to(bundled), f"tegument imported from {tegument.__file__}"
    return module


@pytest.fixture(autouse=True)
def factory_scene(installed_extension):
    """Every test starts from factory settings, with the extension enabled."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    result = bpy.ops.preferences.addon_enable(module=installed_extension)
    assert result == {"FINISHED"}
    yield bpy.context.scene


def shared_data(*parts: str) -> pathlib.Path:
    """A path under ``../shared/data``; skips the test where it is absent, fails under CI."""
    path = SHARED_DATA.joinpath(*parts)
    if not path.exists():
        message = f"{path} is absent: the shared test data sits beside the checkout in ../shared/data"
        if os.environ.get("CI") == "true":
            pytest.fail(message + " (required under CI)")
        pytest.skip(message)
    return path


def solver_switch(settings) -> None:
    """Lets a contact test run with either solver, whatever the default: ``TEGUMENT_TEST_CONVERGE=1``
    bakes with Converge (at its iteration limit), ``0`` with plain iterations (their count); unset,
    the add-on's defaults stand. A switch of the tests, not a setting of the add-on."""
    import tegument

    switch = os.environ.get("TEGUMENT_TEST_CONVERGE")
    if switch in ("0", "1"):
        settings.converge = switch == "1"
        settings.iterations = tegument.DEFAULTS.accelerated_iterations if settings.converge else tegument.DEFAULTS.iterations


def wheel_bake(deformer, inputs, settings) -> list:
    """What a plain bake (no colliders, dynamics or strain limits) writes, from the wheel: the frames
    ``inputs`` (world space, in bake order) solved at the add-on's settings ``settings``
    (``obj.tegument``). With Converge (the default) the solver is accelerated, stops at the add-on's
    tolerance, and every frame after the first starts from the one before (a warm solve)."""
    import tegument

    deformer.accelerated = settings.converge
    deformer.tolerance = tegument.DEFAULTS.tolerance if settings.converge else None
    deformer.reset()
    return [deformer.solve(x, iterations=settings.iterations, closeness=settings.closeness, warm=settings.converge)
            for x in inputs]
