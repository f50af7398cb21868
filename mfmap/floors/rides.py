"""Floors from scale-true transitions alone, for a log without a barometer.

Each ride the accelerometer feels (stand-still to stand-still, integrated twice: the graph's
`find_rides`) and each stair walk the lidar odometry climbs (`mfmap.floors.climbs`) is a
transition with a scale-true height change, and the visits between them are clustered into
floors as the barometer's are. What is lost is the barometer's absolute level: a floor is
recognised on a revisit only by chaining the transitions' heights, a centimetre or a few of
error each, so many of them weaken floor identity (the warning says so).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from mfmap.floors.config import FloorsConfig
from mfmap.floors.segment import cluster_visits, ids_by_elevation, solve_elevations
from mfmap.types import Floor, FloorSegmentation, Transition, TransitionKind

# The height trace handed to the mapping stage (its z during a ride) is sampled this often (s).
TRACE_DT_S = 0.1


def segment_transitions(rides: Sequence[tuple[int, int, float, TransitionKind]], start_ns: int,
                        end_ns: int, cfg: FloorsConfig) -> FloorSegmentation:
    """Floors and transitions from changes given as (start_ns, end_ns, height change m, kind)
    in time order, within a log from start_ns to end_ns. The floors' pressure is not measured."""
    changes = [dz for _, _, dz, _ in rides]
    labels = cluster_visits(changes, cfg.cluster_tolerance_m)
    elevations = solve_elevations(labels, changes)
    id_of_label = ids_by_elevation(elevations)
    order = np.argsort(id_of_label)  # labels lowest first
    edges = [start_ns] + [t for a, b, _, _ in rides for t in (a, b)] + [end_ns]
    visits = [(edges[2 * k], edges[2 * k + 1]) for k in range(len(rides) + 1)]
    transitions = tuple(
        Transition(kind, int(id_of_label[labels[k]]), int(id_of_label[labels[k + 1]]),
                   a, b, float(elevations[labels[k + 1]] - elevations[labels[k]]))
        for k, (a, b, _, kind) in enumerate(rides)
    )
    floors = tuple(
        Floor(int(id_of_label[lab]), float(elevations[lab]), math.nan,
              tuple(v for v_lab, v in zip(labels, visits, strict=True) if v_lab == lab))
        for lab in order
    )
    # The trace: each floor's elevation on its visits, a straight line across each ride.
    stamp_ns = np.arange(start_ns, end_ns + 1, int(TRACE_DT_S * 1e9), dtype=np.int64)
    knots_t = np.array(edges, dtype=np.float64)
    knots_z = np.repeat([elevations[lab] for lab in labels], 2)
    height = np.interp(stamp_ns.astype(np.float64), knots_t, knots_z)
    floor_of_sample = np.full(stamp_ns.shape[0], -1, dtype=np.int32)
    for lab, (a, b) in zip(labels, visits, strict=True):
        floor_of_sample[(stamp_ns >= a) & (stamp_ns <= b)] = id_of_label[lab]
    return FloorSegmentation(floors, transitions, stamp_ns, height, height.copy(), floor_of_sample)
