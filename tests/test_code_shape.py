"""The code stays readable in one sitting: short functions, small classes and modules, no cycles.

Limits from the codebases mfmap learns from: a function that does not fit on a screen (60 lines)
is doing two things, a class over 250 lines holds two ideas, a module over 500 lines two topics.
Import cycles between modules make neither readable alone. Read with `ast`, so a lazy import
inside a function counts as much as one at the top of a module; an import under
`if TYPE_CHECKING:` names a type for annotations only (never executed) and does not count.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1] / "mfmap"
MAX_FUNCTION = 60
MAX_CLASS = 250
MAX_MODULE = 500


def _modules() -> dict[str, Path]:
    found = {}
    for path in sorted(ROOT.rglob("*.py")):
        parts = path.relative_to(ROOT.parent).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        found[".".join(parts)] = path
    return found


def _trees() -> dict[str, ast.Module]:
    return {name: ast.parse(path.read_text(encoding="utf-8")) for name, path in _modules().items()}


def _length(node: ast.AST) -> int:
    first = node.lineno  # type: ignore[attr-defined]
    return int(node.end_lineno) - first + 1  # type: ignore[attr-defined]


def test_no_long_functions_classes_or_modules() -> None:
    over = []
    for name, path in _modules().items():
        lines = len(path.read_text(encoding="utf-8").splitlines())
        if lines > MAX_MODULE:
            over.append(f"{name}: module of {lines} lines")
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and _length(node) > MAX_FUNCTION:
                over.append(f"{name}.{node.name}: function of {_length(node)} lines")
            elif isinstance(node, ast.ClassDef) and _length(node) > MAX_CLASS:
                over.append(f"{name}.{node.name}: class of {_length(node)} lines")
    assert not over, "\n".join(over)


def _type_only(tree: ast.Module) -> set[int]:
    """ids of the import nodes under `if TYPE_CHECKING:`."""
    found: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            found |= {id(n) for stmt in node.body for n in ast.walk(stmt)}
    return found


def _imported(name: str, tree: ast.Module, known: set[str]) -> set[str]:
    """The mfmap modules `name` imports, relative imports resolved, packages to their __init__."""
    out: set[str] = set()
    package = name if (ROOT.parent / name.replace(".", "/") / "__init__.py").exists() else name.rpartition(".")[0]
    type_only = _type_only(tree)
    for node in ast.walk(tree):
        if id(node) in type_only:
            continue
        targets: list[str] = []
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")
                anchor = anchor[: len(anchor) - (node.level - 1)]
                base = ".".join([*anchor, base]) if base else ".".join(anchor)
            targets = [base] + [f"{base}.{alias.name}" for alias in node.names]
        for target in targets:
            while target and target not in known:
                target = target.rpartition(".")[0]
            if target and target != name and target.startswith("mfmap."):
                out.add(target)
    return out


def test_no_import_cycles_between_modules() -> None:
    trees = _trees()
    known = set(trees)
    graph = {name: _imported(name, tree, known) for name, tree in trees.items()}
    # A package's __init__ re-exporting its modules is not a cycle of ideas: leave packages out.
    packages = {n for n in known if (ROOT.parent / n.replace(".", "/") / "__init__.py").exists()}
    graph = {n: {m for m in deps if m not in packages} for n, deps in graph.items() if n not in packages}
    cycles: list[list[str]] = []
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(node: str) -> None:
        state[node] = 1
        stack.append(node)
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                cycles.append([*stack[stack.index(nxt):], nxt])
            elif nxt not in state:
                visit(nxt)
        stack.pop()
        state[node] = 2

    for node in sorted(graph):
        if node not in state:
            visit(node)
    assert not cycles, "\n".join(" -> ".join(c) for c in cycles)
