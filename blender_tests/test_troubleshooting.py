"""docs/troubleshooting.md lists every message a user can see.

The messages are read from the code: in the add-on, what is raised, reported as an error or a
warning, shown in a panel with the error or warning icon, printed on standard error or added to
a bake's warnings; in the Rust core and bindings,
the error messages the wheel can raise. Each must appear in the page by the start of its longest
fixed part (the text between placeholders; the page may shorten a long tail to "…"). A message added to the code without a line in the page fails
here, naming it. Pure Python (no Blender); it sits here because `make test` runs this folder.
"""

from __future__ import annotations

import ast
import pathlib
import re

ROOT = pathlib.Path(__file__).resolve().parent.parent
PAGE = ROOT / "docs" / "troubleshooting.md"
PREFIX = 40  # characters of a message's longest fixed part that the page must quote

# Rust messages no user of the add-on or the wheel can reach: checks of the core's internal
# callers (the solver's constraint rows and the linearised formulation, which the wheel does not
# expose; the benchmarks use them), with the reason each is unreachable.
INTERNAL = {
    "does not belong to this solver": "solver constraints are built by the core itself",
    "vertices given, the solver has": "the solver is driven by the deformer, which checks the counts first",
    "weights given for": "solver constraint weights are built by the core itself",
    "unextrapolated vertices: a mask of": "the deformer builds the solver's mask from its own ring fit",
    "weights must be finite and non-negative": "solver constraint weights are built by the core itself",
    ", but there are": "solver constraint rows are built by the core itself",
    "has a non-finite coefficient": "solver constraint rows are built by the core itself",
    "lists vertex": "solver constraint rows are built by the core itself",
    "symbolic Cholesky analysis of the global matrix failed": "the linearised (Cholesky) formulation is not in the wheel",
    "the Cholesky factor of a": "the linearised (Cholesky) formulation is not in the wheel",
    "rest positions given for a skin of": "self-collision is bound by the sequence from its own skin and rest",
    "self-collision is not prepared for these settings": "the sequence prepares self-collision before every pass",
    "the triangles taking part are of another skin": "the sequence takes the triangles taking part from its own skin",
    "self-collision margins": "the sequence makes the margins for its own skin",
    "self-collision moves": "the sequence measures the last solve's moves on its own skin",
    "vertex flags given for": "the sequence flags the last tangles and pinched vertices of its own skin",
    "positions given for a collider of": "compliant colliders' envelopes are made by the sequence from their own goals",
    "envelope margin is": "compliant colliders' envelopes are made by the sequence with the clearance's radius",
    "envelopes given for": "the sequence gives one envelope slot per collider",
    "a clearance measured against envelopes has no planes": "the sequence measures planes only without envelopes",
    "collider slack is": "the skin's slack as a collider is a constant of the sequence",
    "changed in a BVH over": "partial refits are made by the collider from its own triangles",
    "converge needs the multigrid solver": "UvWarp::converge (benchmarks and tests) is not in the wheel",
    "anchors belong to the skin they were made on": "the sequence keeps the anchors of its own skin; the wheel does not expose them",
}


def fragments(parts: list[str | None]) -> list[str]:
    """The fixed text of a message whose placeholders are None."""
    text = "".join("\0" if part is None else part for part in parts)
    return [piece.strip(" :;,.()\"'") for piece in text.split("\0")]


def template(node: ast.AST) -> list[str | None] | None:
    """A string literal or f-string as text and placeholders; None for anything else."""
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return [node.value]
    if isinstance(node, ast.JoinedStr):
        return [v.value if isinstance(v, ast.Constant) else None for v in node.values]
    if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Add):
        left, right = template(node.left), template(node.right)
        if left is not None:
            return left + (right if right is not None else [None])
    return None


def shown_level(node: ast.AST) -> bool:
    """A `self.report` level set that can be ERROR or WARNING."""
    return any(isinstance(n, ast.Constant) and n.value in ("ERROR", "WARNING") for n in ast.walk(node))


def addon_messages() -> list[tuple[str, list[str | None]]]:
    found = []
    for path in sorted((ROOT / "addon").rglob("*.py")):
        tree = ast.parse(path.read_text())
        where = str(path.relative_to(ROOT))
        for node in ast.walk(tree):
            message = None
            if isinstance(node, ast.Raise) and isinstance(node.exc, ast.Call) and node.exc.args:
                message = node.exc.args[0]
            elif isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute):
                name, args = node.func.attr, node.args
                if name == "report" and len(args) == 2 and shown_level(args[0]):
                    message = args[1]
                elif name == "poll_message_set" and args:
                    message = args[0]
                elif name == "label" and any(k.arg == "icon" and shown_level(k.value) for k in node.keywords):
                    # A panel line that can carry the error or warning icon is a message too.
                    message = next((k.value for k in node.keywords if k.arg == "text"), None)
                elif name == "append" and args and isinstance(node.func.value, (ast.Name, ast.Attribute)):
                    owner = node.func.value.id if isinstance(node.func.value, ast.Name) else node.func.value.attr
                    if owner in ("warnings", "notes"):
                        message = args[0]
            elif isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "print":
                if any(k.arg == "file" and ast.unparse(k.value) == "sys.stderr" for k in node.keywords) and node.args:
                    message = node.args[0]
            if message is not None:
                parts = template(message)
                if parts is not None:
                    found.append((f"{where}:{node.lineno}", parts))
    return found


RUST_ERROR = re.compile(r"(Error::\w+\s*[({]|Error::invalid\s*\(|\binvalid\s*\(|new_err\s*\(|Topology\s*\(|Numerical\s*\(|"
                        r"InvalidInput\s*\(|\bIo\s*\(|TooLarge\s*\{)")
STRING = re.compile(r'"((?:[^"\\]|\\.)*)"')
TEST_MODULE = re.compile(r"#\[cfg\(test\)\]\s*mod\s+\w+\s*\{")


def rust_messages() -> list[tuple[str, list[str | None]]]:
    found = []
    for root in ("rust/core/src", "rust/python/src"):
        for path in sorted((ROOT / root).rglob("*.rs")):
            if "tests" in path.parts or path.name.startswith("tests"):
                continue
            text = path.read_text()
            # Only an inline test module ends the shipped code; `#[cfg(test)] mod tests;` and
            # test-only items elsewhere do not (cutting there hid the rest of the file).
            body = TEST_MODULE.split(text, maxsplit=1)[0]
            for match in RUST_ERROR.finditer(body):
                window = body[match.end(): match.end() + 300]
                literal = STRING.search(window)
                if literal is None or ";" in window[: literal.start()]:
                    continue
                parts = re.split(r"(\{[^{}]*\})", literal.group(1))
                found.append((f"{path.relative_to(ROOT)}:{body[: match.start()].count(chr(10)) + 1}",
                               [None if p.startswith("{") else p.replace('\\"', '"') for p in parts]))
    return found


def undocumented(messages, page: str) -> list[str]:
    missing = []
    for where, parts in messages:
        pieces = [p for p in fragments(parts) if len(p) >= 8]
        if not pieces:
            continue  # only a wrapper around another message ("{name}: {error}"), listed where it comes from
        longest = max(pieces, key=len)
        if any(marker in "".join(p or "{}" for p in parts) for marker in INTERNAL):
            continue
        if longest[:PREFIX] not in page:
            missing.append(f"{where}: {longest!r}")
    return missing


def test_every_add_on_message_is_in_the_troubleshooting_page():
    messages = addon_messages()
    assert len(messages) > 60, "the scan found too few messages: has the code's shape changed?"
    missing = undocumented(messages, PAGE.read_text())
    assert not missing, "docs/troubleshooting.md lacks:\n" + "\n".join(missing)


def test_every_wheel_error_is_in_the_troubleshooting_page():
    messages = rust_messages()
    assert len(messages) > 40, "the scan found too few messages: has the code's shape changed?"
    missing = undocumented(messages, PAGE.read_text())
    assert not missing, "docs/troubleshooting.md lacks:\n" + "\n".join(missing)
