"""Writes docs/python-api.md from the docstrings of the installed ``tegument`` package.

``rust/python/tests/test_api_docs.py`` fails when the page and the package
disagree, so the page cannot drift from the code: after changing a docstring
or adding a public name, run ``make api-docs``.
"""

from __future__ import annotations

import argparse
import inspect
import pathlib

HEADER = """# The `tegument` Python API

The wheel's numpy-level API, for pipeline tools and scripts. It runs in Blender's Python (the
extension bundles it) and in any CPython ≥ 3.11 with numpy. Arrays are float32 positions of shape
`(N, 3)` and int32 indices in Blender's mesh layout: `corner_verts` is the vertex of every face
corner, polygon after polygon (`mesh.loops[i].vertex_index`), and `polygon_sizes` the corner count
of every polygon (`mesh.polygons[i].loop_total`). Arrays must be C-contiguous; nothing is
converted silently. Long calls release the GIL. Anything refused raises `TegumentError`, a
`ValueError`, whose message names what is wrong and where.

*This page is generated from the docstrings by `tools/gen_api_docs.py`; a test keeps it in step.*
"""


def _signature(obj) -> str:
    text = getattr(obj, "__text_signature__", None)
    if text:
        return text.replace("($self, ", "(").replace("($self)", "()").replace("$cls, ", "")
    try:
        return str(inspect.signature(obj))
    except (TypeError, ValueError):
        return "(...)"


def _doc(obj) -> str:
    return inspect.cleandoc(obj.__doc__ or "").strip()


def render() -> str:
    import tegument

    parts = [HEADER]
    for name in sorted(tegument.__all__, key=lambda n: (not inspect.isclass(getattr(tegument, n)), n.lower())):
        obj = getattr(tegument, name)
        if name.startswith("__"):
            continue
        if inspect.isclass(obj):
            parts.append(f"## `{name}{_signature(obj) if not issubclass(obj, BaseException) else ''}`\n")
            parts.append(_doc(obj) + "\n")
            for member_name, member in sorted(vars(obj).items()):
                if member_name.startswith("_") or not _doc(member):
                    continue
                if isinstance(member, property) or type(member).__name__ == "getset_descriptor":
                    parts.append(f"### `{name}.{member_name}`\n\n{_doc(member)}\n")
                elif callable(member):
                    parts.append(f"### `{name}.{member_name}{_signature(member)}`\n\n{_doc(member)}\n")
        elif callable(obj):
            parts.append(f"## `{name}{_signature(obj)}`\n\n{_doc(obj)}\n")
    return "\n".join(parts).rstrip() + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--out", type=pathlib.Path, default=pathlib.Path("docs/python-api.md"))
    args = parser.parse_args()
    args.out.write_text(render())
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
