"""A manifest entry with `build_with:`: its log and the others built into one map
(`mfmap build A B ...`) and scored per building floor against the logs' merged ground truth
(mfmap.eval.sessions)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from mfmap.config import MfmapConfig
from pipelines.regress.manifest import Simulate
from pipelines.regress.model import LogJob


def multilog_job(job: LogJob, log: Path, gt: dict[str, str | None], config: MfmapConfig,
                 step: Callable[[str], None]) -> dict[str, float]:
    """Simulate the other logs (if needed), build all into one map, score; `step` hears each
    step's name. A simulated entry's ground truth is the merge of every log's (the reference
    cloud left out: each log's covers its own floors); a log file's is the manifest's."""
    from mfmap.eval import evaluate
    from mfmap.eval.sessions import merge_sessions
    from mfmap.multilog import build_logs
    from pipelines.regress.runner import SIM_LOG_NAME, ensure_simulated, flatten_metrics

    step("simulate")
    sims = [Simulate.model_validate(s) for s in job.build_with]
    folders = [ensure_simulated(Path(job.sim_cache or "."), sim) for sim in sims]
    out = Path(job.out_dir)
    step("build")
    build_logs([log, *[f / SIM_LOG_NAME[s.fmt] for f, s in zip(folders, sims, strict=True)]],
               out / "build", config, force=True)
    step("eval")
    if job.simulate is not None:
        truth = merge_sessions([log.parent, *folders], out / "truth")
        merged = {"points": truth.points, "trajectory": truth.trajectory, "floors": truth.floors}
        gt = {k: (str(merged[k]) if v is not None and k in merged else None) for k, v in gt.items()}
    paths = {k: Path(v) if v else None for k, v in gt.items()}
    result = evaluate(out / "build", points=paths.get("points"), cloud=paths.get("cloud"),
                      trajectory=paths.get("trajectory"), floors=paths.get("floors"),
                      align="none", config=config.eval)
    result.write_json(out / "eval.json")
    return flatten_metrics(result.metrics)
