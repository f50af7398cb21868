"""A manifest entry with `localize:`: its log localised in a map (built here unless given) and
scored against its ground truth (mfmap.localize.score)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from mfmap.config import MfmapConfig
from pipelines.regress.manifest import Localize
from pipelines.regress.model import LogJob


def localize_job(job: LogJob, log: Path, gt: dict[str, str | None], config: MfmapConfig,
                 step: Callable[[str], None]) -> dict[str, float]:
    """Build the map (if needed), localise the log in it, score; `step` hears each step's name."""
    from mfmap.localize import localize
    from mfmap.localize.score import score_localization
    from pipelines.regress.runner import SIM_LOG_NAME, ensure_simulated

    assert job.localize is not None
    spec = Localize.model_validate(job.localize)
    out = Path(job.out_dir)
    map_dir = spec.map_dir
    if map_dir is None:
        step("simulate")
        map_log = spec.map_log
        if map_log is None:
            assert spec.map_simulate is not None
            folder = ensure_simulated(Path(job.sim_cache or "."), spec.map_simulate)
            map_log = folder / SIM_LOG_NAME[spec.map_simulate.fmt]
        step("build")
        from mfmap.pipeline import build

        map_dir = out / "map"
        build(map_log, map_dir, config, force=True)
    step("localize")
    located = out / "localize"
    localize(log, map_dir, located, config, force=True)
    step("eval")
    trajectory, floors = gt.get("trajectory"), gt.get("floors")
    return score_localization(located, Path(trajectory) if trajectory else None,
                              Path(floors) if floors else None, foreign=spec.foreign,
                              config=config.eval)
