"""The building's graph over the placed logs (`mfmap.multilog.joint`), built and optimised."""

from __future__ import annotations

from typing import Any

import numpy as np

from mfmap.config import MfmapConfig
from mfmap.graph.factors import X
from mfmap.multilog.joint import InterLogSigmas, JointGraph, key_of
from mfmap.multilog.logs import LogRun
from mfmap.multilog.place import Placement
from mfmap.types import F64


def building_graph(runs: list[LogRun], placement: Placement, cfg: MfmapConfig
                   ) -> tuple[dict[int, dict[int, F64]], dict[str, Any]]:
    """Every log's graph and the factors between the logs, optimised: per log its keyframes'
    building-frame poses, and report.json's `graph`."""
    joint = JointGraph(cfg.graph)
    by_index = {run.index: run for run in runs}
    placed: dict[int, list[tuple[int, int]]] = {}  # building floor -> (log, keyframe)
    for i in placement.order:
        run = by_index[i]
        joint.add_log(run, placement.transforms[i])
        match = placement.matches.get(i)
        for pair in match.pairs if match is not None else ():
            joint.link(run, pair, placed, placement.levels[pair.building_floor],
                       run.graph.floor_z_m[pair.log_floor], InterLogSigmas())
        floors = placement.floors[i]
        for kf in run.graph.keyframes:
            if kf.floor_id in floors:
                placed.setdefault(floors[kf.floor_id], []).append((i, kf.id))
    result, iterations, error_initial, error_final, seconds = joint.optimise(cfg.graph.max_iterations)
    joint.errors(joint.values, final=False)
    joint.errors(result, final=True)
    poses = {run.index: {kf.id: np.asarray(result.atPose3(key_of(run.index, X(kf.id))).matrix(),
                                           dtype=np.float64)
                         for kf in run.graph.keyframes} for run in runs}
    final = placement.renumbered()
    doc: dict[str, Any] = {
        "iterations": iterations,
        "error_initial": round(error_initial, 6),
        "error_final": round(error_final, 6),
        "seconds": round(seconds, 3),
        "factors": {k: v.to_json() for k, v in joint.stats.items()},
        "inter_log": joint.links,
        "logs": [_log_graph(run, final, placement) for run in runs],
    }
    return poses, doc


def _log_graph(run: LogRun, final: dict[int, int], placement: Placement) -> dict[str, Any]:
    """A log's own graph: its iterations and its floors' registrations (building floors)."""
    floors = placement.floors[run.index]
    return {
        "log": str(run.path),
        "iterations": run.graph.iterations,
        "inter_floor": [{"lower": final[floors[m.lower]], "upper": final[floors[m.upper]],
                         "accepted": m.accepted, "reason": m.reason,
                         "fitness": round(m.fitness, 4)} for m in run.graph.matches
                        if m.lower in floors and m.upper in floors],
        "rides": run.graph.rides,
        "heights": run.graph.calibration.to_json(),
    }


__all__ = ["building_graph"]
