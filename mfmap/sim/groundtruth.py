"""Ground-truth files: gt_trajectory.tum, gt_points.csv, gt_floors.json, gt_cloud.ply.

Formats as in DESIGN.md. Times are epoch seconds (the .tum and .csv carry all nine nanosecond
digits). Besides the shared schema, gt_floors.json has:
- floor ids are ranks among the floors the robot visits (0 = the lowest), as a build numbers
  them: a floor only passed through on the stairs or stopped at in the cabin has none; each
  floor's "building_floor" is its index in the building (0 = the building's lowest);
- per transition: "connector" (0 = elevator, 1 = stairs), "height_change_m";
- "sim": scenario, seed, start_ns (stamp of the first lidar scan = world-frame origin),
  building (its name), floor_height_m (null when the storeys differ), storey_heights_m and
  elevations_m of every floor of the building (visited or not, by building floor),
  stairwell (straight or switchback),
  reference_pressure_pa (at world z = 0, t = 0), temperature_k (the air
  column's virtual temperature at world z = 0), temperature_gradient_k_per_m, gravity_m_s2
  (pressure at height h: mfmap.sim.atmosphere.AirColumn), baro_height_above_base_m, drift_pa_per_h (signed), pressure_transients [[t0, t1, dPa]],
  door_open [[t_open, t_close, building floor]] (elevator doors open: the cabin is
  visible), world (the
  building's air as drawn: mfmap.sim.world.World.document; floor_offsets_pa are each floor's
  pressure relative to the shaft's air column), door_pulses [[t, dPa]].
Each floor's pressure_pa is at the barometer's height on it, at the start's weather, with the
floor's offset.
gt_cloud.ply samples the static surfaces (closed landing doors included, the cabin not) with an
int `floor` per point: the floor whose space holds the point (its floor surface, walls, furniture
and its ceiling, i.e. the underside of the slab above).
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from mfmap.atomic import atomic_open, write_bytes_atomic
from mfmap.sim.building import Building
from mfmap.sim.sensors import BARO_MOUNT, Barometer
from mfmap.sim.trajectory import Trajectory, quaternions

if TYPE_CHECKING:
    from mfmap.sim.scenarios import ScenarioSpec


def epoch_text(start_ns: int, t_s: float) -> str:
    """Epoch seconds with nanosecond digits, computed in integers so no float rounding shows."""
    ns = start_ns + round(t_s * 1e9)
    return f"{ns // 1_000_000_000}.{ns % 1_000_000_000:09d}"


def epoch_s(start_ns: int, t_s: float) -> float:
    return (start_ns + round(t_s * 1e9)) / 1e9


def _atomic_write(path: Path, data: bytes) -> Path:
    write_bytes_atomic(path, data)
    return path


def write_all(
    out: Path,
    spec: ScenarioSpec,
    building: Building,
    traj: Trajectory,
    baro: Barometer,
    start_ns: int,
    scan_times: npt.NDArray[np.float64],
    seed: int,
) -> dict[str, Path]:
    return {
        "trajectory": write_trajectory(out / "gt_trajectory.tum", traj, start_ns, scan_times),
        "points": write_points(out / "gt_points.csv", traj, start_ns),
        "floors": write_floors(out / "gt_floors.json", spec, building, traj, baro, start_ns, seed),
        "cloud": write_cloud(out / "gt_cloud.ply", building, spec.gt_spacing_m, seed),
    }


def write_trajectory(path: Path, traj: Trajectory, start_ns: int, scan_times: npt.NDArray[np.float64]) -> Path:
    """Base pose at every scan stamp: `t x y z qx qy qz qw`."""
    xyz, rpy = traj.interp(scan_times)
    q = quaternions(rpy)
    lines = [
        f"{epoch_text(start_ns, float(t))} {p[0]:.6f} {p[1]:.6f} {p[2]:.6f} "
        f"{qq[0]:.9f} {qq[1]:.9f} {qq[2]:.9f} {qq[3]:.9f}"
        for t, p, qq in zip(scan_times, xyz, q, strict=True)
    ]
    return _atomic_write(path, ("\n".join(lines) + "\n").encode())


def floor_ids(traj: Trajectory) -> dict[int, int]:
    """The building's floor index -> the ground truth's floor id: the rank among the floors the
    robot visits (0 = the lowest), as a build numbers them; a floor only passed through on the
    stairs or stopped at in the cabin is not among them."""
    return {k: i for i, k in enumerate(sorted({f for f, _, _ in traj.floor_visits}))}


def write_points(path: Path, traj: Trajectory, start_ns: int) -> Path:
    ids = floor_ids(traj)
    lines = ["label,floor,x,y,z,t_start,t_end"]
    for c in traj.checkpoints:
        lines.append(
            f"{c.label},{ids[c.floor]},{c.x:.4f},{c.y:.4f},{c.z:.4f},"
            f"{epoch_text(start_ns, c.t_start_s)},{epoch_text(start_ns, c.t_end_s)}"
        )
    return _atomic_write(path, ("\n".join(lines) + "\n").encode())


def floors_document(
    spec: ScenarioSpec, building: Building, traj: Trajectory, baro: Barometer, start_ns: int, seed: int
) -> dict[str, Any]:
    ids = floor_ids(traj)
    visited = sorted(ids)
    gt_ids = [ids[k] for k in visited]
    sx0, sx1, sy0, sy1 = building.stair_rect
    stair_xy = ((sx0 + sx1) / 2, (sy0 + sy1) / 2)
    shaft_xy = building.shaft_center
    connectors = [
        {"id": 0, "kind": "elevator", "x": shaft_xy[0], "y": shaft_xy[1], "floors": gt_ids},
        {"id": 1, "kind": "stairs", "x": stair_xy[0], "y": stair_xy[1], "floors": gt_ids},
    ]
    world = baro.world
    offsets = world.floor_offsets_pa if world is not None else [0.0] * building.n_floors
    floors = []
    for k in visited:
        elev = building.elevation(k)
        floors.append(
            {
                "id": ids[k],
                "building_floor": k,
                "elevation_m": round(elev, 6),
                # Pressure at the barometer's height on this floor, at the start's weather.
                "pressure_pa": round(baro.air.pressure_pa(elev + BARO_MOUNT.xyz[2], baro.p0_pa) + offsets[k], 3),
                "visits": [
                    [epoch_s(start_ns, t0), epoch_s(start_ns, t1)] for f, t0, t1 in traj.floor_visits if f == k
                ],
                "connectors": [0, 1],
            }
        )
    return {
        "floors": floors,
        "transitions": _transitions(traj, ids, start_ns),
        "connectors": connectors,
        "sim": _sim_section(spec, building, traj, baro, start_ns, seed),
    }


def _transitions(traj: Trajectory, ids: dict[int, int], start_ns: int) -> list[dict[str, Any]]:
    """gt_floors.json's transitions: floor ids, epoch times, where they start and end."""
    return [
        {
            "kind": tr.kind,
            "from": ids[tr.from_floor],
            "to": ids[tr.to_floor],
            "t_start": epoch_s(start_ns, tr.t_start_s),
            "t_end": epoch_s(start_ns, tr.t_end_s),
            "height_change_m": round(tr.height_change_m, 6),
            "x": round(tr.x, 6),
            "y": round(tr.y, 6),
            "x_end": round(tr.x_end, 6),
            "y_end": round(tr.y_end, 6),
            "connector": 0 if tr.kind == "elevator" else 1,
        }
        for tr in traj.transitions
    ]


def _sim_section(
    spec: ScenarioSpec, building: Building, traj: Trajectory, baro: Barometer, start_ns: int, seed: int
) -> dict[str, Any]:
    """What the simulator knows beyond the floors: the building, the air, the barometer's
    drift and transients, the doors."""
    world = baro.world
    all_floors = list(range(building.n_floors))
    return {
        "scenario": spec.name,
        "seed": seed,
        "start_ns": start_ns,
        "building": building.spec.name,
        "floor_height_m": building.floor_height_m if building.uniform else None,
        "storey_heights_m": list(building.storeys_m),
        "elevations_m": [round(building.elevation(k), 6) for k in all_floors],
        "stairwell": building.spec.stairwell.kind,
        "reference_pressure_pa": round(baro.p0_pa, 3),
        "temperature_k": baro.air.virtual_temperature_k,
        "temperature_gradient_k_per_m": baro.air.gradient_k_per_m,
        "gravity_m_s2": baro.air.gravity_m_s2,
        "baro_height_above_base_m": BARO_MOUNT.xyz[2],
        "drift_pa_per_h": baro.drift_sign * baro.spec.drift_pa_per_h,
        "pressure_transients": [
            [epoch_s(start_ns, t0), epoch_s(start_ns, t1), round(dp, 3)] for t0, t1, dp in baro.transients
        ],
        "door_open": [[epoch_s(start_ns, t0), epoch_s(start_ns, t1), f] for t0, t1, f in traj.door_open],
        "world": None if world is None else world.document(building),
        "door_pulses": []
        if world is None
        else [[epoch_s(start_ns, t0), round(dp, 3)] for t0, dp in world.door_pulses],
    }


def write_floors(
    path: Path, spec: ScenarioSpec, building: Building, traj: Trajectory, baro: Barometer, start_ns: int, seed: int
) -> Path:
    doc = floors_document(spec, building, traj, baro, start_ns, seed)
    return _atomic_write(path, (json.dumps(doc, indent=2) + "\n").encode())


_PLY_DTYPE = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("floor", "<i4")])


def write_ply(
    path: Path, total: int, chunks: Iterable[tuple[npt.NDArray[np.float32], npt.NDArray[np.int32]]]
) -> Path:
    """Binary little-endian PLY with float x, y, z and int floor, streamed chunk by chunk."""
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        f"element vertex {total}\n"
        "property float x\nproperty float y\nproperty float z\nproperty int floor\nend_header\n"
    )
    written = 0
    with atomic_open(path, "wb") as f:
        f.write(header.encode())
        for xyz, floor in chunks:
            rec = np.empty(len(xyz), dtype=_PLY_DTYPE)
            rec["x"], rec["y"], rec["z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
            rec["floor"] = floor
            f.write(rec.tobytes())
            written += len(rec)
        if written != total:
            raise AssertionError(f"PLY header says {total} points, wrote {written}")
    return path


def read_ply(path: Path) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.int32]]:
    """Reads what write_ply wrote (for tests and plots)."""
    data = path.read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    rec = np.frombuffer(data[end:], dtype=_PLY_DTYPE)
    return np.column_stack([rec["x"], rec["y"], rec["z"]]), rec["floor"].copy()


def write_cloud(path: Path, building: Building, spacing_m: float, seed: int) -> Path:
    total, chunks = building.surface_samples(spacing_m, seed)
    return write_ply(path, total, chunks)
