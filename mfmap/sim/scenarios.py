"""Named scenarios: a building, a route through it, and the sensors on the robot."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from mfmap.sim.building import Building
from mfmap.sim.camera import RgbdSpec
from mfmap.sim.layout import FamilySpec, generate_building
from mfmap.sim.route import RouteBuilder
from mfmap.sim.sensors import BaroSpec, LaserSpec, LidarSpec
from mfmap.sim.sessions import SESSION_LIDAR, SESSION_PLANS, Session
from mfmap.sim.spec import BuildingSpec, corridor_block, office_block
from mfmap.sim.world import WorldSpec

# Checkpoints of the LeGO-LOAM elevator paper's manual-driving experiment (Table I), world frame.
P1, P2, P3, P4 = (0.0, 0.0), (6.0, -2.0), (6.0, -12.0), (0.7, -12.0)
W_NORTH, W_SOUTH = (-2.75, -1.0), (-2.75, -12.0)
C1, C2 = (1.5, 0.0), (11.5, 0.0)  # the ends of the walk along the corridor building's corridor

Route = Callable[[RouteBuilder, int], None]


@dataclass(frozen=True)
class ScenarioSpec:
    name: str
    description: str
    n_floors: int  # the office block's storeys (and their height) when `building` is None
    floor_height_m: float
    route: Route
    start_floor: int = 0
    lidar: LidarSpec | None = field(default_factory=LidarSpec)
    laser: LaserSpec | None = None
    baro: BaroSpec = field(default_factory=BaroSpec)
    # The building's air (stack effect, doors, cabin, weather, temperature); the default is calm,
    # `world=WorldSpec.harsh()` makes it a real building's.
    world: WorldSpec = field(default_factory=WorldSpec)
    v_max: float = 0.8
    gt_spacing_m: float = 0.05
    # The building for a seed; None: the office block with n_floors storeys of floor_height_m.
    building: Callable[[int], BuildingSpec] | None = None
    camera: RgbdSpec | None = None  # an RGB-D camera beside the range sensor
    # One of several logs of one building (mfmap.sim.sessions): its day, start pose and frame.
    session: Session | None = None


def building_for(spec: ScenarioSpec, seed: int) -> Building:
    """The scenario's building at this seed (its rooms and furniture are the seed's too)."""
    plan = spec.building(seed) if spec.building is not None else office_block(spec.n_floors, spec.floor_height_m)
    frame_floor = spec.session.frame_floor if spec.session is not None else spec.start_floor
    return Building(plan, frame_floor, seed)


def checkpoint_tour(b: RouteBuilder, stop_s: float = 5.0) -> None:
    """P1 -> P2 -> P3 -> P4 and back to P1 round the west corridor: a loop of ~40 m."""
    b.drive(P1)
    b.checkpoint("P1", stop_s)
    b.drive(P2)
    b.checkpoint("P2", stop_s)
    b.drive(P3)
    b.checkpoint("P3", stop_s)
    b.drive(P4)
    b.checkpoint("P4", stop_s)
    b.drive(W_SOUTH, W_NORTH, (0.0, -1.0), P1)


def east_tour(b: RouteBuilder) -> None:
    """Corridor N to the east, down corridor E, along corridor F and back: out and back."""
    b.drive((10.0, -1.0), (14.25, -1.0), (14.25, -11.0), (24.0, -11.0), v_max=0.9)
    b.drive((14.25, -11.0), (14.25, -1.5), (3.0, -1.5), v_max=0.9)


def _tiny(b: RouteBuilder, reps: int) -> None:
    for _ in range(reps):
        b.checkpoint("P1", 3.0)
        b.drive(P2)
        b.checkpoint("P2", 3.0)
    b.elevator(1)
    for _ in range(reps):
        b.drive(P2)
        b.checkpoint("P2", 3.0)
        if reps > 1:
            b.drive(P1)


def _two_floor(b: RouteBuilder, reps: int) -> None:
    for _ in range(reps):
        checkpoint_tour(b)
    b.elevator(1)
    for _ in range(reps):
        checkpoint_tour(b)
    b.checkpoint("P1", 3.0)


def _three_floor(b: RouteBuilder, reps: int) -> None:
    for _ in range(reps):
        checkpoint_tour(b, 4.0)
    b.elevator(1)
    for _ in range(reps):
        checkpoint_tour(b, 4.0)
    b.elevator(2)
    for _ in range(reps):
        checkpoint_tour(b, 4.0)
    b.elevator(0)
    for _ in range(reps):
        b.drive(P2)
        b.checkpoint("P2", 4.0)
        b.drive(P1)
        b.checkpoint("P1", 4.0)


def _stairs(b: RouteBuilder, reps: int) -> None:
    b.checkpoint("P1", 4.0)
    for _ in range(reps):
        b.drive(P2)
        b.checkpoint("P2", 4.0)
        b.drive((14.25, -1.5), (14.25, -11.0))
    b.stairs_up()
    for _ in range(reps):
        b.drive((20.0, -11.0))
        b.checkpoint("S1", 4.0)
    b.stairs_up()
    for _ in range(reps):
        b.drive((20.0, -11.0))
        b.checkpoint("S1", 4.0)
        b.drive((14.25, -11.0), (14.25, -1.5), (8.0, -1.5))
        b.checkpoint("P2", 4.0)


def _single(b: RouteBuilder, reps: int) -> None:
    for _ in range(reps):
        checkpoint_tour(b)
        east_tour(b)
    b.drive(P1)
    b.checkpoint("P1", 3.0)


def _long(b: RouteBuilder, reps: int) -> None:
    def visit() -> None:
        for _ in range(reps):
            checkpoint_tour(b, 4.0)
            east_tour(b)
            checkpoint_tour(b, 4.0)

    visit()
    b.elevator(2)
    visit()
    b.elevator(3)
    visit()
    b.drive(P2, (14.25, -1.5), (14.25, -11.0))
    b.stairs_up()
    b.drive((14.25, -11.0), (14.25, -1.5))
    visit()
    b.elevator(0)
    visit()
    b.elevator(1)
    for _ in range(reps):
        checkpoint_tour(b, 4.0)


def _office_switchback(b: RouteBuilder, reps: int) -> None:
    """A 5.5 m lobby under 3.5 m offices: up two storeys by the switch-back stairs without
    stopping on the first floor, down by elevator stopping on it, then up to it by elevator and
    down the stairs to the lobby."""
    pauses = {"landing_pause_s": (5.0, 30.0), "mid_flight_pause_s": (3.0, 12.0), "mid_flight_pause_share": 0.4}
    to_stairs = (P2, (14.25, -1.5), (14.25, -11.0))
    for _ in range(reps):
        b.checkpoint("P1", 4.0)
        b.drive(P2)
        b.checkpoint("P2", 4.0)
    b.drive(*to_stairs)
    b.stairs(2, **pauses)  # type: ignore[arg-type]
    for _ in range(reps):
        b.drive((20.0, -11.0))
        b.checkpoint("S1", 4.0)
        b.drive((14.25, -11.0), (14.25, -1.5), P2)
        b.checkpoint("P2", 4.0)
        b.drive(P1)
        b.checkpoint("P1", 4.0)
    b.elevator(0, stops=(1,))
    b.drive(P1)
    b.checkpoint("P1", 3.0)
    b.elevator(1)
    for _ in range(reps):
        b.drive(P1)
        b.checkpoint("P1", 4.0)
        b.drive(P2)
        b.checkpoint("P2", 4.0)
    b.drive(*to_stairs[1:])
    b.stairs(0, **pauses)  # type: ignore[arg-type]
    b.drive((14.25, -11.0), (14.25, -1.5), P2)
    b.checkpoint("P2", 4.0)


# -- generated buildings: a different one per seed ------------------------------------------
_STAIR_PAUSES = {"landing_pause_s": (3.0, 30.0), "mid_flight_pause_s": (2.0, 10.0), "mid_flight_pause_share": 0.3}


def _visit(b: RouteBuilder, labels: str, stop_s: float = 4.0) -> None:
    """Stand at the building's checkpoints named by their numbers ("123": C1, C2, C3)."""
    points = {name: (x, y) for name, x, y in b.building.spec.checkpoints}
    for k in labels:
        b.goto(points[f"C{k}"])
        b.checkpoint(f"C{k}", stop_s)


def _lift(b: RouteBuilder, to_floor: int, stops: tuple[int, ...] = ()) -> None:
    b.goto(b.building.spec.shaft.front)
    b.elevator(to_floor, stops=stops, stop_s=float(b.rng.uniform(3.0, 8.0)))


def _walk(b: RouteBuilder, to_floor: int) -> None:
    st = b.building.spec.stairwell
    b.goto((sum(st.doors_x[0]) / 2, st.door_wall_y + st.outward * st.approach_m))
    b.stairs(to_floor, **_STAIR_PAUSES)  # type: ignore[arg-type]


def _gen_elevator(b: RouteBuilder, reps: int) -> None:
    """Lobby, the top floor by elevator with a stop on a floor nobody visits, (a lower floor,)
    back down to the lobby."""
    top = b.building.n_floors - 1
    for _ in range(reps):
        _visit(b, "123")
    _lift(b, top, stops=(top - 1,))
    for _ in range(reps):
        _visit(b, "12")
    if top >= 3:
        _lift(b, 1, stops=(2,))
        for _ in range(reps):
            _visit(b, "1")
        _lift(b, 0)
    else:
        _lift(b, 0, stops=(1,))
    _visit(b, "1")


def _gen_stairs(b: RouteBuilder, reps: int) -> None:
    """Up two storeys by the switch-back stairs without stopping on the floor between, down one,
    the elevator back to the lobby."""
    for _ in range(reps):
        _visit(b, "12")
    _walk(b, 2)
    for _ in range(reps):
        _visit(b, "12")
    _walk(b, 1)
    for _ in range(reps):
        _visit(b, "1")
    _lift(b, 0)


def _gen_mixed(b: RouteBuilder, reps: int) -> None:
    """The top floor by elevator stopping on floor 1, down two storeys by the stairs through the
    floor between, (down to the lobby by elevator)."""
    top = b.building.n_floors - 1
    for _ in range(reps):
        _visit(b, "12")
    _lift(b, top, stops=(1,))
    for _ in range(reps):
        _visit(b, "12")
    _walk(b, top - 2)
    if top - 2 > 0:
        for _ in range(reps):
            _visit(b, "1")
        _lift(b, 0)
    _visit(b, "1")


def _gen_tiny(b: RouteBuilder, reps: int) -> None:
    for _ in range(reps):
        _visit(b, "12", 3.0)
    _lift(b, 1)
    for _ in range(reps):
        _visit(b, "1", 3.0)


def _corridor(b: RouteBuilder, reps: int) -> None:
    """Each floor: along the 2 m corridor past the tables and shelves and back, then up."""
    for floor in range(4):
        if floor:
            b.elevator(floor)
        for _ in range(reps):
            b.drive(C1)
            b.checkpoint("C1", 3.0)
            b.drive(C2)
            b.checkpoint("C2", 3.0)
            b.drive(C1)


def _family(**kwargs: object) -> Callable[[int], BuildingSpec]:
    fam = FamilySpec(**kwargs)  # type: ignore[arg-type]
    return lambda seed: generate_building(seed, fam)


_GEN_LIDAR = LidarSpec(beams=16, columns=512)
_GEN = {"world": WorldSpec.harsh(), "lidar": _GEN_LIDAR, "gt_spacing_m": 0.08, "v_max": 0.8}


_DRIFT = BaroSpec(drift_pa_per_h=200.0, transient_floors=(0, 1, 2), transient_every_s=30.0)

SCENARIOS: dict[str, ScenarioSpec] = {
    s.name: s
    for s in (
        ScenarioSpec(
            "tiny",
            "86 s, two floors 3.5 m apart, elevator, 16x512 lidar (for tests)",
            2,
            3.5,
            _tiny,
            lidar=LidarSpec(beams=16, columns=512),
        ),
        ScenarioSpec(
            "tiny-rgbd",
            "tiny with an RGB-D camera (80 x 60, 2 Hz, jpeg colour) on a mast beside the 16x512 "
            "lidar, whose points its colour images paint (for tests)",
            2,
            3.5,
            _tiny,
            lidar=LidarSpec(beams=16, columns=512),
            camera=RgbdSpec(rate_hz=2),
        ),
        ScenarioSpec(
            "tiny-harsh",
            "tiny in a real building's air: temperature 0-40 C, stack effect, doors, cabin lag, "
            "weather, the barometer's temperature topic",
            2,
            3.5,
            _tiny,
            lidar=LidarSpec(beams=16, columns=512),
            world=WorldSpec.harsh(),
        ),
        ScenarioSpec(
            "tiny-2d",
            "tiny with a 2D LaserScan (360 deg, 15 Hz) instead of the 3D lidar",
            2,
            3.5,
            _tiny,
            lidar=None,
            laser=LaserSpec(),
        ),
        ScenarioSpec(
            "two-floor",
            "the LeGO-LOAM elevator paper's experiment: P1..P4 on two floors 4.7 m apart, "
            "elevator, ~4 min",
            2,
            4.7,
            _two_floor,
        ),
        ScenarioSpec(
            "two-floor-2d",
            "two-floor with a 2D LaserScan (360 deg, 15 Hz, as Fan et al.'s) instead of the 3D lidar",
            2,
            4.7,
            _two_floor,
            lidar=None,
            laser=LaserSpec(),
        ),
        ScenarioSpec(
            "three-floor-revisit",
            "up to the third floor by elevator and back down to the first, 4.0 m floors, ~7 min",
            3,
            4.0,
            _three_floor,
        ),
        ScenarioSpec(
            "three-floor-drift",
            "three-floor-revisit with 200 Pa/h weather drift and frequent door/HVAC steps",
            3,
            4.0,
            _three_floor,
            baro=_DRIFT,
        ),
        ScenarioSpec(
            "stairs",
            "carried up two flights of stairs (3.5 m floors, pitch on the steps), ~4 min",
            3,
            3.5,
            _stairs,
            v_max=0.7,
        ),
        ScenarioSpec(
            "office-switchback",
            "the office block with a 5.5 m lobby under 3.5 m storeys and switch-back stairs: "
            "landings, pauses, a floor passed through, an elevator stop, in a harsh world, ~11 min",
            3,
            3.5,
            _office_switchback,
            world=WorldSpec.harsh(),
            v_max=0.7,
            lidar=LidarSpec(beams=16, columns=512),
            building=lambda seed: office_block(3, 3.5, (5.5, 3.5, 3.5), switchback=True),
        ),
        ScenarioSpec(
            "gen-tiny",
            "a generated building per seed (two storeys of their own heights), one elevator "
            "ride, ~1.5 min, harsh world (for tests)",
            0,
            0.0,
            _gen_tiny,
            building=_family(storeys="mixed", n_floors=(2, 2)),
            world=WorldSpec.harsh(),
            lidar=_GEN_LIDAR,
        ),
        ScenarioSpec(
            "gen-elevator",
            "a generated building per seed, a 4.5-6 m lobby under equal storeys, elevator rides "
            "stopping at floors nobody visits, harsh world, 16x512 lidar",
            0,
            0.0,
            _gen_elevator,
            building=_family(storeys="lobby"),
            **_GEN,  # type: ignore[arg-type]
        ),
        ScenarioSpec(
            "gen-stairs",
            "a generated building per seed, storeys of 2.6-6 m, switch-back stairs up two storeys "
            "through a floor (landings, pauses), down one, harsh world, 16x512 lidar",
            0,
            0.0,
            _gen_stairs,
            building=_family(storeys="mixed"),
            **_GEN,  # type: ignore[arg-type]
        ),
        ScenarioSpec(
            "gen-mixed",
            "a generated building per seed, storeys of 2.6-6 m, elevator to the top stopping on "
            "floor 1, stairs down two storeys through a floor, harsh world, 16x512 lidar",
            0,
            0.0,
            _gen_mixed,
            building=_family(storeys="mixed", n_floors=(3, 4)),
            **_GEN,  # type: ignore[arg-type]
        ),
        ScenarioSpec(
            "gen-mixed-2d",
            "gen-mixed with a 2D LaserScan (360 deg, 15 Hz) instead of the 3D lidar",
            0,
            0.0,
            _gen_mixed,
            building=_family(storeys="mixed", n_floors=(3, 4)),
            world=WorldSpec.harsh(),
            lidar=None,
            laser=LaserSpec(),
            gt_spacing_m=0.08,
        ),
        ScenarioSpec(
            "corridor-rgbd",
            "as Fan et al.'s experiment: four 3.5 m floors of a building with a 30 x 2 m corridor, "
            "elevator, a 2D LaserScan (10 Hz), an RGB-D camera (80 x 60, 2 Hz, jpeg colour), tables and "
            "wall cabinets the scan passes under or over, ~5 min",
            4,
            3.5,
            _corridor,
            lidar=None,
            laser=LaserSpec(samples=360, rate_hz=10),
            building=lambda seed: corridor_block(4, 3.5),
            camera=RgbdSpec(rate_hz=2),
        ),
        ScenarioSpec(
            "single-floor",
            "one floor: checkpoint loop and an east tour, ~3 min",
            1,
            4.0,
            _single,
        ),
        ScenarioSpec(
            "long",
            "~30 min over five 4.0 m floors (basement included), elevator and stairs, 16x512 lidar",
            5,
            4.0,
            _long,
            start_floor=1,
            # Ouster's 512x10 mode: keeps 30 min of log near 2.5 GB and its generation < 5 min.
            lidar=LidarSpec(beams=16, columns=512),
            baro=BaroSpec(drift_pa_per_h=60.0, transient_floors=(0, 2, 4)),
            gt_spacing_m=0.08,
        ),
    )
}
# Several logs of one building on different days.


def _session_scenarios() -> list[ScenarioSpec]:
    """The sessions of mfmap.sim.sessions as scenarios: the office block of n_floors storeys
    (building None), as the single-log scenarios' own."""
    return [
        ScenarioSpec(p.name, p.description, p.n_floors, p.floor_height_m, p.route,
                     start_floor=p.start_floor, lidar=SESSION_LIDAR, world=WorldSpec.harsh(),
                     gt_spacing_m=0.08, session=p.session)
        for p in SESSION_PLANS
    ]


SCENARIOS.update({s.name: s for s in _session_scenarios()})
