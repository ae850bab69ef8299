"""The committed _native.pyi is what tools/stubgen.py makes of the built module."""

from __future__ import annotations

import pathlib
import subprocess
import sys

ROOT = pathlib.Path(__file__).resolve().parents[3]
STUB = ROOT / "rust" / "python" / "python" / "tegument" / "_native.pyi"


def test_stub_matches_the_built_module():
    done = subprocess.run([sys.executable, str(ROOT / "tools" / "stubgen.py"), "--check"], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr


def test_stub_names_every_public_name_with_its_kind():
    import ast

    from tegument import _native

    tree = ast.parse(STUB.read_text())
    stubbed = {node.name: node for node in tree.body if isinstance(node, (ast.ClassDef, ast.FunctionDef))}
    for name, obj in vars(_native).items():
        if name.startswith("__"):
            continue
        assert name in stubbed, f"_native.{name} is missing from the stub"
        assert isinstance(stubbed[name], ast.ClassDef) == isinstance(obj, type), f"_native.{name}: wrong kind in the stub"
