"""The stages import one way: ingest -> floors -> mapping -> graph -> export.

A stage may import the stages before it, never one after it, so each can be read, tested and
replaced knowing only what comes before. `eval` and `sim` stand beside the stages: nothing in a
stage imports them (the simulator's own rule, that it shares nothing with the estimator, is
tests/sim/test_import_rule.py). Read from the source with `ast`, so a lazy import inside a
function counts as much as one at the top of a module.
"""

from __future__ import annotations

import ast
from pathlib import Path

STAGES = ["ingest", "floors", "mapping", "graph", "export"]
BESIDE = ["eval", "sim"]
ROOT = Path(__file__).resolve().parents[1] / "mfmap"


def _imports(path: Path) -> set[str]:
    """The mfmap packages `path` imports (second component of each mfmap.* module)."""
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        names: list[str] = []
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = [node.module]
        elif isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        for name in names:
            parts = name.split(".")
            if parts[0] == "mfmap" and len(parts) > 1:
                found.add(parts[1])
    return found


def _stage_edges() -> dict[tuple[str, str], list[str]]:
    edges: dict[tuple[str, str], list[str]] = {}
    for package in STAGES + BESIDE:
        for path in sorted((ROOT / package).rglob("*.py")):
            for target in _imports(path) - {package}:
                edges.setdefault((package, target), []).append(str(path.relative_to(ROOT.parent)))
    return edges


def test_no_stage_imports_a_later_stage_or_eval_or_sim() -> None:
    wrong = []
    for (source, target), files in _stage_edges().items():
        if source in STAGES and target in STAGES and STAGES.index(target) > STAGES.index(source):
            wrong.append(f"{source} -> {target} ({', '.join(files)})")
        if source in STAGES and target in BESIDE:
            wrong.append(f"{source} -> {target} ({', '.join(files)})")
    assert not wrong, "imports against the stages' order:\n" + "\n".join(wrong)


def test_the_check_sees_a_lazy_import(tmp_path: Path) -> None:
    module = tmp_path / "m.py"
    module.write_text("def f():\n    import mfmap.export.mapdata\n    from mfmap.eval.io import read_tum\n")
    assert _imports(module) == {"export", "eval"}
