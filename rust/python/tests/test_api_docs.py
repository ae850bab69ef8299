"""docs/python-api.md is generated from the docstrings; it must match the package."""

from __future__ import annotations

import importlib.util
import pathlib

import tegument

ROOT = pathlib.Path(__file__).resolve().parents[3]


def _generator():
    spec = importlib.util.spec_from_file_location("gen_api_docs", ROOT / "tools" / "gen_api_docs.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_api_page_is_up_to_date():
    page = (ROOT / "docs" / "python-api.md").read_text()
    assert page == _generator().render(), "docs/python-api.md is stale: run `make api-docs`"


def test_every_public_name_is_documented():
    for name in tegument.__all__:
        if name.startswith("__"):
            continue
        assert getattr(tegument, name).__doc__, f"tegument.{name} has no docstring"
