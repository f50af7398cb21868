"""The mapping stage's figures for the report: a mapper's counters, and the stats made of them."""

from __future__ import annotations

from dataclasses import dataclass

from mfmap.mapping.cabin import CabinFilter
from mfmap.mapping.loops import LoopCloser
from mfmap.mapping.odometry import ScanMatcher
from mfmap.mapping.scan2d import Scan2DMatcher
from mfmap.mapping.wheelscale import RunScale
from mfmap.types import Keyframe, PoseEdge


@dataclass
class ScanCounts:
    """What a mapper did with its scans."""

    registered: int = 0
    in_cabin_scans: int = 0
    tipping_scans: int = 0  # stair-walk scans posed by the motion prior while the base tipped
    held_scans: int = 0  # stand-still scans that took the last registration's pose
    turn_held: int = 0  # registrations turning in place that kept the stand-still's x, y
    max_map_points: int = 0


# The loop search's counters in the report: name -> LoopStats attribute.
LOOP_COUNTERS = {"loop_candidates": "candidates", "loop_rejected_fitness": "rejected_fitness",
                 "loop_rejected_ambiguous": "rejected_ambiguous",
                 "loop_rejected_degenerate": "rejected_degenerate",
                 "loop_rejected_implausible": "rejected_implausible",
                 "loop_rejected_one_way": "rejected_one_way"}


def loop_counters(loops: LoopCloser) -> dict[str, float]:
    return {name: float(getattr(loops.stats, attr)) for name, attr in LOOP_COUNTERS.items()}


# Counters the merge of chunks takes the maximum of (the others it sums).
MAX_COUNTERS = ("max_local_map_points", "climb_spread_max_m")


def mapper_counters(matcher: ScanMatcher | Scan2DMatcher, cabin: CabinFilter | None,
                    loops: LoopCloser, counts: ScanCounts, wheels: RunScale,
                    climbs: list[list[float]]) -> dict[str, float]:
    """One mapper's counters, summed (or their maximum taken, `MAX_COUNTERS`) over chunks by
    the merge. `climbs`: per stair walk, its registrations' climbs (mfmap.mapping.climb)."""
    return {
        "climbs_averaged": float(len(climbs)),
        "climb_spread_max_m": max((max(c) - min(c) for c in climbs), default=0.0),
        "gyro_overruled": float(getattr(matcher, "overruled", 0)),
        "heading_blended": float(getattr(matcher, "blended", 0)),
        "registrations_refined": float(matcher.refined),
        "registered": float(counts.registered),
        "registration_failures": float(matcher.failures),
        "registrations_off_prior": float(getattr(matcher, "jumps", 0)),
        "in_cabin_scans": float(counts.in_cabin_scans),
        "tipping_scans": float(counts.tipping_scans),
        "held_scans": float(counts.held_scans),
        "turn_held": float(counts.turn_held),
        "cabin_points_dropped": float(cabin.dropped if cabin else 0),
        "max_local_map_points": float(counts.max_map_points),
        "wheel_scale_dot": wheels.dot,
        "wheel_scale_norm": wheels.norm,
        **loop_counters(loops),
    }


def stats(counters: dict[str, float], scans: int, keyframes: list[Keyframe],
          edges: list[PoseEdge]) -> dict[str, float]:
    """The stage's figures for the report, from one mapper's counters or the chunks' summed."""
    return {
        "scans": float(scans),
        "registered": counters.get("registered", 0.0),
        "registration_failures": counters.get("registration_failures", 0.0),
        "registrations_off_prior": counters.get("registrations_off_prior", 0.0),
        "gyro_overruled": counters.get("gyro_overruled", 0.0),
        "heading_blended": counters.get("heading_blended", 0.0),
        "registrations_refined": counters.get("registrations_refined", 0.0),
        "held_scans": counters.get("held_scans", 0.0),
        "turn_held": counters.get("turn_held", 0.0),
        "keyframes": float(len(keyframes)),
        "odometry_edges": float(sum(e.kind == "odometry" for e in edges)),
        "loop_edges": float(sum(e.kind == "loop" for e in edges)),
        **{name: counters.get(name, 0.0) for name in LOOP_COUNTERS},
        "max_local_map_points": counters.get("max_local_map_points", 0.0),
        # stair walks whose climb is the median of several registrations, and their widest spread
        "climbs_averaged": counters.get("climbs_averaged", 0.0),
        "climb_spread_max_m": counters.get("climb_spread_max_m", 0.0),
        "in_cabin_scans": counters.get("in_cabin_scans", 0.0),
        "tipping_scans": counters.get("tipping_scans", 0.0),
        "cabin_points_dropped": counters.get("cabin_points_dropped", 0.0),
        # lidar ~ scale * wheels between keyframes (0: no wheel odometry or no travel)
        "wheel_odometry_scale": (counters.get("wheel_scale_dot", 0.0) / norm
                                 if (norm := counters.get("wheel_scale_norm", 0.0)) > 0 else 0.0),
    }
