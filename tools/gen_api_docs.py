"""Writes docs/python-api.md from the docstrings of the installed ``tegument`` package.

``rust/python/tests/test_api_docs.py`` fails when the page and the package
disagree, so the page cannot drift from the code: after changing a docstring
or adding a public name, run ``make api-docs``.
"""

from __future__ import annotations

import argparse
import dataclasses
import inspect
import pathlib

HEADER = """# The `tegument` Python API

The wheel's numpy-level API, for pipeline tools and scripts. It runs in Blender's Python (the
extension bundles it) and in any CPython ≥ 3.11 with numpy. Long calls release the GIL. Anything
refused raises `TegumentError`, a `ValueError`, whose message names what is wrong and where.

**Arrays.** Positions are `(N, 3)` and indices are in Blender's mesh layout: `corner_verts` is the
vertex of every face corner, polygon after polygon (`mesh.loops[i].vertex_index`), and
`polygon_sizes` the corner count of every polygon (`mesh.polygons[i].loop_total`). Float arrays
may be of any float dtype (float32, float64, float16, longdouble) and index arrays of any integer
dtype (int8 … int64, uint8 … uint64), in any memory layout: float32 and int32 arrays in C order
are read as they are; anything else is converted on the way in (one copy, the cost of
`np.ascontiguousarray(a, dtype=np.float32)`). Converted indices must lie in `[0, 2³¹ − 1]`: a
negative one or one beyond int32 is refused, naming the argument and the element. bool, complex
and object arrays and Python lists are refused. Results are always float32 and int32 arrays.

**Reports.** Calls that report (`PyramidDeformer.last_step`, `audit`, `UvWarp.metrics`,
`Mesh.report`, `Collider.update`) return small frozen classes from `tegument.results` with one
attribute per figure, a readable `repr` and `to_dict()`. In 0.1.0 they were dicts; `report["key"]`,
`.get`, `in` and `keys()` still work for one more release and warn with a `DeprecationWarning`.

**Properties and methods.** A property returns state the object holds, with no arguments and no
work beyond a copy (counts, settings, stored arrays such as `Collider.edges` or `Mesh.report`); a
method takes arguments or computes something (`Mesh.one_ring(i)`, `Mesh.problem_vertices()`,
`UvWarp.redirection(udim)`). `Mesh.edges`, `Mesh.boundary_vertices`, `Mesh.report` and
`Collider.edges` were methods in 0.1.0: calling them still works, with a `DeprecationWarning`.

**Defaults.** `tegument.DEFAULTS` holds the default of every setting as the core defines it; the
keyword defaults shown as `...` below are these values (the add-on's settings start from them too).
After 0.1.0 the default closeness became 0.05 (it was 0.1), and a `Collider` built without settings
keeps 0.005 of thickness with friction 0.3 (kinetic 0.2) (it had none): the add-on's long-standing values.

*This page is generated from the docstrings by `tools/gen_api_docs.py`; a test keeps it in step.*
"""


def _signature(obj) -> str:
    if dataclasses.is_dataclass(obj):
        # A report class: its fields, which are its attributes.
        return "(" + ", ".join(f.name for f in dataclasses.fields(obj)) + ")"
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
        elif name == "DEFAULTS":
            rows = "\n".join(f"| `{key}` | `{value!r}` |" for key, value in obj.to_dict().items())
            parts.append(f"## `DEFAULTS`\n\n{_doc(obj)}\n\n| setting | default |\n|---|---|\n{rows}\n")
    return "\n".join(parts).rstrip() + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--out", type=pathlib.Path, default=pathlib.Path("docs/python-api.md"))
    args = parser.parse_args()
    args.out.write_text(render())
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
