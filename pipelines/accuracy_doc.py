"""Write docs/accuracy.md from regression figures: a baseline file or a run's results.json.

    python -m pipelines.accuracy_doc                       # the sim_full and sim_seeds baselines
    python -m pipelines.accuracy_doc work/regression/sim_full/results.json -o -   # to stdout
    python -m pipelines.accuracy_doc --headline            # the README's table alone

Per log (scenario and seed): checkpoint RMSE per floor against the bars of the elevator paper's
Table I (16 mm on the floor the robot starts on, 25 mm on the others), floor count and time
share, floor elevation errors, the floors' offsets across each ride (dx, dy, dyaw, dz) and the
trajectory's APE. Every figure is the file's own number, rounded; nothing is typed by hand.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from mfmap.atomic import write_text_atomic

ROOT = Path(__file__).resolve().parent.parent
DEFAULT_SOURCES = [
    ROOT / "pipelines" / "baselines" / "sim_full.json",
    ROOT / "pipelines" / "baselines" / "sim_seeds.json",
]
DEFAULT_OUT = ROOT / "docs" / "accuracy.md"
MANIFESTS = ROOT / "pipelines" / "manifests"

# Checkpoint RMSE reached by the elevator paper's robot (Table I): start floor, other floors.
BAR_START_M = 0.016
BAR_OTHER_M = 0.025

_PAIR = re.compile(r"^floors\.inter(\d+)_(\d+)\.dx_m$")
_FLOOR_POINTS = re.compile(r"^points\.floor(\d+)\.rmse_m$")
_FLOOR_APE = re.compile(r"^trajectory\.floor(\d+)\.ape_rmse_m$")


class SourceError(ValueError):
    """A file that is neither a regression baseline nor a run's results.json."""


@dataclass(frozen=True)
class LogFigures:
    name: str
    scenario: str
    seed: int
    variant: str  # the log format or a note from the manifest ("" for the plain log)
    metrics: dict[str, float]
    machine: str | None
    source: str


def _manifest_logs(manifest: str | None) -> dict[str, dict[str, Any]]:
    """Log name -> its `simulate` block, from pipelines/manifests/<manifest>.yaml if present."""
    if not manifest:
        return {}
    path = MANIFESTS / f"{manifest}.yaml"
    if not path.is_file():
        return {}
    data = yaml.safe_load(path.read_text()) or {}
    out: dict[str, dict[str, Any]] = {}
    for log in data.get("logs") or []:
        if isinstance(log, dict) and isinstance(log.get("simulate"), dict):
            out[str(log.get("name"))] = log["simulate"]
    return out


def _identity(name: str, sim: dict[str, Any] | None) -> tuple[str, int, str]:
    if sim is not None:
        fmt = str(sim.get("fmt", "mcap"))
        return str(sim["scenario"]), int(sim.get("seed", 0)), "" if fmt == "mcap" else fmt
    match = re.match(r"^(.*)-s(\d+)$", name)
    if match:
        return match.group(1), int(match.group(2)), ""
    return name, 0, ""


def read_source(path: Path) -> list[LogFigures]:
    """The logs of a baseline ({"logs": {name: {metrics, machine}}}) or a results.json
    ({"logs": [{name, metrics, machine}]})."""
    try:
        data = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise SourceError(f"{path}: not readable JSON ({err.__class__.__name__})") from err
    logs = data.get("logs") if isinstance(data, dict) else None
    if isinstance(logs, dict):
        entries = [(name, entry) for name, entry in logs.items()]
    elif isinstance(logs, list):
        entries = [(str(e.get("name")), e) for e in logs if isinstance(e, dict)]
    else:
        raise SourceError(f"{path}: no 'logs' (expected a regression baseline or results.json)")
    sims = _manifest_logs(data.get("manifest"))
    out = []
    for name, entry in entries:
        metrics = entry.get("metrics") if isinstance(entry, dict) else None
        if not isinstance(metrics, dict) or not metrics:
            continue  # a failed build has no figures
        scenario, seed, variant = _identity(name, sims.get(name))
        clean = {k: float(v) for k, v in metrics.items() if isinstance(v, (int, float))}
        out.append(LogFigures(name, scenario, seed, variant, clean, entry.get("machine"), path.name))
    return out


def _floors(m: dict[str, float]) -> list[int]:
    return sorted(int(g.group(1)) for k in m if (g := _FLOOR_POINTS.match(k)))


def start_floor(m: dict[str, float]) -> int | None:
    """The floor the robot started on: elevations are relative to it, so its error is 0."""
    zero = [k for k in _floors(m) if m.get(f"floors.floor{k}.elevation_error_m") == 0.0]
    return zero[0] if len(zero) == 1 else None


def _num(value: float | None, scale: float, digits: int) -> str:
    return "-" if value is None else f"{value * scale:.{digits}f}"


def _row(cells: list[str]) -> str:
    return "| " + " | ".join(cells) + " |"


def _table(header: list[str], rows: list[list[str]]) -> list[str]:
    return [_row(header), _row(["---"] * len(header)), *(_row(r) for r in rows)]


def _label(log: LogFigures) -> list[str]:
    scenario = log.scenario + (f" ({log.variant})" if log.variant else "")
    return [scenario, str(log.seed)]


def checkpoint_rows(logs: list[LogFigures]) -> list[list[str]]:
    rows = []
    for log in logs:
        m, floors = log.metrics, _floors(log.metrics)
        if not floors:
            continue
        start = start_floor(m)
        cells, misses = [], []
        for k in floors:
            rmse = m[f"points.floor{k}.rmse_m"]
            bar = BAR_START_M if k == start else BAR_OTHER_M
            text = _num(rmse, 1000, 1)
            cells.append(f"**{text}**" if k == start else text)
            if rmse > bar:
                misses.append(f"floor {k}")
        verdict = "yes" if not misses else "no: " + ", ".join(misses)
        hilti = _num(m.get("points.hilti_score"), 1, 1)
        rows.append([*_label(log), " / ".join(cells), verdict, _num(m.get("points.rmse_m"), 1000, 1), hilti])
    return rows


def floor_rows(logs: list[LogFigures]) -> list[list[str]]:
    rows = []
    for log in logs:
        m = log.metrics
        if "floors.count_gt" not in m:
            continue
        count = f"{m['floors.count_est']:.0f} / {m['floors.count_gt']:.0f}"
        elevations = " / ".join(
            _num(m.get(f"floors.floor{k}.elevation_error_m"), 100, 1) for k in _floors(m)
        ) or "-"
        rows.append([
            *_label(log), count,
            _num(m.get("floors.time_correct_share"), 100, 2),
            f"{m.get('floors.transitions_missed', 0):.0f} / {m.get('floors.transitions_extra', 0):.0f}",
            elevations,
            _num(m.get("floors.elevation_error_max_m"), 100, 1),
        ])
    return rows


def interfloor_rows(logs: list[LogFigures]) -> list[list[str]]:
    rows = []
    for log in logs:
        m = log.metrics
        pairs = sorted((int(g.group(1)), int(g.group(2))) for k in m if (g := _PAIR.match(k)))
        for a, b in pairs:
            p = f"floors.inter{a}_{b}."
            rows.append([
                *_label(log), f"{a}-{b}",
                _num(m.get(p + "dx_m"), 100, 1), _num(m.get(p + "dy_m"), 100, 1),
                _num(m.get(p + "dyaw_deg"), 1, 3), _num(m.get(p + "dz_m"), 100, 1),
                _num(m.get(p + "dz_pct"), 1, 2),
            ])
    return rows


def trajectory_rows(logs: list[LogFigures]) -> list[list[str]]:
    rows = []
    for log in logs:
        m = log.metrics
        if "trajectory.ape_rmse_m" not in m:
            continue
        floors = sorted(int(g.group(1)) for key in m if (g := _FLOOR_APE.match(key)))
        per_floor = " / ".join(_num(m[f"trajectory.floor{k}.ape_rmse_m"], 100, 1) for k in floors)
        rows.append([
            *_label(log), _num(m["trajectory.ape_rmse_m"], 100, 1), per_floor or "-",
            _num(m.get("trajectory.z_rmse_m"), 100, 1), _num(m.get("trajectory.rot_rmse_deg"), 1, 2),
            _num(m.get("trajectory.tilt_rmse_deg"), 1, 2),
        ])
    return rows


def render(logs: list[LogFigures], sources: list[str], command: str) -> str:
    logs = sorted(logs, key=lambda g: (g.scenario, g.variant, g.seed))
    machines = sorted({g.machine for g in logs if g.machine})
    lines = [
        "# Accuracy",
        "",
        "<!-- Generated by pipelines/accuracy_doc.py; edit that script, not this file. -->",
        "",
        f"Generated by `{command}` from {', '.join(f'`{s}`' for s in sources)}: "
        "each log built by `mfmap build` with the default configuration and scored by "
        "`mfmap eval` against the simulator's ground truth. Metric names are those of "
        "[formats.md](formats.md#metrics).",
        "",
    ]
    if machines:
        lines += ["Measured on: " + "; ".join(f"`{m}`" for m in machines) + ".", ""]
    lines += [
        "Builds are bit-identical run to run on one machine but not across CPUs: on another "
        "machine expect these figures to move by a few millimetres (more on the stairs logs).",
        "",
        "## Checkpoints",
        "",
        "RMSE of the 3D error at the checkpoints where the robot stood (`points.floor<k>.rmse_m`), "
        "per floor from the lowest up, in mm; the floor the robot started on in bold. The bars "
        "are Table I of the paper on multi-floor mapping through elevators with LeGO-LOAM and a "
        f"barometer: {BAR_START_M * 1000:.0f} mm on the start floor, "
        f"{BAR_OTHER_M * 1000:.0f} mm on the others. Hilti is the Hilti 2023 score (0-100).",
        "",
        *_table(["scenario", "seed", "per floor (mm)", "within the bars", "all (mm)", "Hilti"],
                checkpoint_rows(logs)),
        "",
        "## Floors",
        "",
        "Floor count (build / truth), share of the ground-truth time assigned to the right floor "
        "(%), transitions missed / extra, and each floor's elevation error (cm, relative to the "
        "start floor, lowest floor first).",
        "",
        *_table(["scenario", "seed", "floors", "time right (%)", "missed / extra",
                 "elevation error (cm)", "worst (cm)"], floor_rows(logs)),
        "",
        "## Across the rides",
        "",
        "How floor b sits on floor a where the robot rode or climbed between them "
        "(`floors.inter<a>_<b>.*`, the measure of Table 1 and 2 of \"3D Multi-floor Precision "
        "Mapping and Localization for Indoor Autonomous Robots\"): x, y error (cm), yaw error "
        "(deg), error of the height difference (cm and % of the floor height).",
        "",
        *_table(["scenario", "seed", "floors", "dx (cm)", "dy (cm)", "dyaw (deg)", "dz (cm)",
                 "dz (%)"], interfloor_rows(logs)),
        "",
        "## Trajectory",
        "",
        "Absolute pose error of `trajectory.tum` against the ground truth, no alignment "
        "(`trajectory.ape_rmse_m`; per floor `trajectory.floor<k>.ape_rmse_m`), in cm; rotation "
        "and tilt (roll and pitch) RMSE in degrees.",
        "",
        *_table(["scenario", "seed", "APE RMSE (cm)", "per floor (cm)", "z RMSE (cm)",
                 "rotation (deg)", "tilt (deg)"], trajectory_rows(logs)),
        "",
        "## Regenerate",
        "",
        "- the figures: `python -m pipelines.regression pipelines/manifests/sim_full.yaml` and "
        "`pipelines/manifests/sim_seeds.yaml` (add `--update-baseline` to make them the "
        "baselines), then `python -m pipelines.accuracy_doc`, or pass the runs' `results.json`;",
        "- what each factor of the graph is worth: `python pipelines/bench_build.py two-floor "
        "three-floor-revisit stairs --ablations` prints the same checkpoint table with each "
        "factor kind switched off in turn (`graph.ablation.barometer_factors`, `transition_height`, "
        "`elevator_continuity`, `inter_floor_registration`, `imu_ride_height`).",
        "",
    ]
    return "\n".join(lines)


def headline(logs: list[LogFigures]) -> str:
    """The README's table: checkpoint RMSE per floor (mm) of each scenario built at several
    seeds, one column per seed."""
    plain = [g for g in logs if not g.variant and _floors(g.metrics)]
    seeds_of: dict[str, dict[int, LogFigures]] = {}
    for log in plain:
        seeds_of.setdefault(log.scenario, {})[log.seed] = log
    several = {name: by_seed for name, by_seed in seeds_of.items() if len(by_seed) > 1}
    seeds = sorted({seed for by_seed in several.values() for seed in by_seed})
    rows = []
    for name in sorted(several):
        cells = []
        for seed in seeds:
            found = several[name].get(seed)
            m = found.metrics if found is not None else {}
            cells.append(" / ".join(_num(m[f"points.floor{k}.rmse_m"], 1000, 1) for k in _floors(m))
                         or "-")
        rows.append([name, *cells])
    return "\n".join(_table(["scenario", *(f"seed {s}" for s in seeds)], rows)) + "\n"


def collect(paths: list[Path]) -> list[LogFigures]:
    """Every log of the sources, the first source's figures where a name repeats."""
    seen: dict[str, LogFigures] = {}
    for path in paths:
        for log in read_source(path):
            seen.setdefault(log.name, log)
    return list(seen.values())


def _display(path: Path) -> str:
    try:
        return str(path.resolve().relative_to(ROOT))
    except ValueError:
        return str(path)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("sources", nargs="*", type=Path,
                        help="baseline files or results.json (default: sim_full and sim_seeds baselines)")
    parser.add_argument("-o", "--out", default=str(DEFAULT_OUT),
                        help="markdown file to write, '-' for stdout (default docs/accuracy.md)")
    parser.add_argument("--headline", action="store_true",
                        help="print only the README's table (checkpoints per floor, one column per seed)")
    args = parser.parse_args(argv)
    paths = args.sources or DEFAULT_SOURCES
    shown = [_display(p) for p in paths]
    command = "python -m pipelines.accuracy_doc" + (
        "" if not args.sources else " " + " ".join(shown)
    )
    try:
        logs = collect(paths)
    except SourceError as err:
        print(f"accuracy_doc: error: {err}", file=sys.stderr)
        return 2
    if args.headline:
        sys.stdout.write(headline(logs))
        return 0
    text = render(logs, shown, command)
    if args.out == "-":
        sys.stdout.write(text)
    else:
        write_text_atomic(Path(args.out), text)
        print(f"wrote {args.out} ({len(logs)} logs)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
