"""sim stage: synthetic buildings and their logs, with ground truth (`mfmap simulate`).

    from mfmap.sim import simulate, SCENARIOS
    result = simulate("two-floor", "work/sim", fmt="mcap", seed=0)
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from mfmap.sim.run import SimResult, simulate
    from mfmap.sim.scenarios import SCENARIOS, ScenarioSpec

__all__ = ["SCENARIOS", "ScenarioSpec", "SimResult", "simulate", "source_digest"]


def source_digest() -> str:
    """Short hash of the simulator's source: a cache key that changes whenever the simulated
    output may change (the simulator imports nothing of the estimator's that could change it)."""
    import hashlib
    from pathlib import Path

    here = Path(__file__).parent
    h = hashlib.sha256()
    for path in sorted(here.glob("*.py")):
        h.update(path.name.encode())
        h.update(path.read_bytes())
    return h.hexdigest()[:10]


def __getattr__(name: str) -> Any:
    # open3d and the writers load on first use, not on `import mfmap.sim`.
    if name in ("SimResult", "simulate"):
        from mfmap.sim import run

        return getattr(run, name)
    if name in ("SCENARIOS", "ScenarioSpec"):
        from mfmap.sim import scenarios

        return getattr(scenarios, name)
    raise AttributeError(name)
