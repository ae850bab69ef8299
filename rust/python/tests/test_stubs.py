"""The committed _native.pyi is what tools/stubgen.py makes of the built module."""

from __future__ import annotations

import importlib.util
import pathlib

ROOT = pathlib.Path(__file__).resolve().parents[3]


def _stubgen():
    spec = importlib.util.spec_from_file_location("stubgen", ROOT / "tools" / "stubgen.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_stub_matches_the_built_module():
    stubgen = _stubgen()
    assert stubgen.STUB.read_text() == stubgen.render(), "_native.pyi is stale: run `python tools/stubgen.py`"


def test_stub_names_every_public_name_with_its_kind():
    import ast

    from tegument import _native

    tree = ast.parse(_stubgen().STUB.read_text())
    stubbed = {node.name: node for node in tree.body if isinstance(node, (ast.ClassDef, ast.FunctionDef))}
    for name, obj in vars(_native).items():
        if name.startswith("__"):
            continue
        assert name in stubbed, f"_native.{name} is missing from the stub"
        assert isinstance(stubbed[name], ast.ClassDef) == isinstance(obj, type), f"_native.{name}: wrong kind in the stub"
