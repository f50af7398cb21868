"""The simulator and the estimator share no code that models the world.

A simulator that converts height to pressure with the estimator's own formula and constants can
never show the estimator a world it does not expect (STYLE.md, habit 18). Every import in
mfmap/sim/ is read with ast: only the simulator's own modules and the plumbing that models
nothing (errors, progress, atomic writes, the shared record types) are allowed; and no estimator
package imports the simulator.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parents[2] / "mfmap"
SIM_MAY_IMPORT = ("mfmap.sim", "mfmap.errors", "mfmap.progress", "mfmap.atomic", "mfmap.types")
ESTIMATOR = ("floors", "mapping", "graph", "ingest", "export", "eval", "baro.py", "config.py", "pipeline.py")


def imported_modules(path: Path, package: str) -> list[tuple[int, str]]:
    """(line, absolute module name) of every import in a file, relative ones resolved."""
    tree = ast.parse(path.read_text(), filename=str(path))
    out: list[tuple[int, str]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                module = ".".join([*base, node.module] if node.module else base)
            else:
                module = node.module or ""
            # `from mfmap import baro` imports the module mfmap.baro.
            names = [f"{module}.{a.name}" for a in node.names] if module == "mfmap" else [module]
            out += [(node.lineno, m) for m in names]
    return out


def _is_under(module: str, prefix: str) -> bool:
    return module == prefix or module.startswith(prefix + ".")


def sim_violations(sim_dir: Path) -> list[str]:
    bad = []
    for path in sorted(sim_dir.rglob("*.py")):
        for line, module in imported_modules(path, "mfmap.sim"):
            if _is_under(module, "mfmap") and not any(_is_under(module, p) for p in SIM_MAY_IMPORT):
                bad.append(f"{path.name}:{line} imports {module}")
    return bad


def test_the_simulator_imports_nothing_of_the_estimator() -> None:
    assert sim_violations(PKG / "sim") == []


def test_the_estimator_imports_nothing_of_the_simulator() -> None:
    bad = []
    for name in ESTIMATOR:
        root = PKG / name
        for path in sorted(root.rglob("*.py") if root.is_dir() else [root]):
            package = "mfmap." + ".".join(path.relative_to(PKG).with_suffix("").parts[:-1])
            for line, module in imported_modules(path, package.rstrip(".")):
                if _is_under(module, "mfmap.sim"):
                    bad.append(f"{path.relative_to(PKG)}:{line} imports {module}")
    assert bad == []


@pytest.mark.parametrize(
    "line",
    [
        "from mfmap.baro import pressure_from_height",
        "import mfmap.floors.segment",
        "from mfmap import config",
        "from ..graph.barometer import GRAVITY_M_S2",
        "    from mfmap.mapping.config import MappingConfig",
    ],
)
def test_the_check_sees_every_form_of_import(tmp_path: Path, line: str) -> None:
    sim = tmp_path / "sim"
    sim.mkdir()
    body = "def f() -> None:\n" + line + "\n" if line.startswith(" ") else line + "\n"
    (sim / "bad.py").write_text("from mfmap.sim.atmosphere import CALM_AIR\n" + body)
    assert len(sim_violations(sim)) == 1
