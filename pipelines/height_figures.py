"""The height figures of docs/heights.md from regression runs, as markdown tables.

    python -m pipelines.height_figures RUN [RUN ...] [--ablation RUN [RUN ...]]

RUN is a folder written by `python -m pipelines.regression MANIFEST --out RUN` (its
results.json, and each log's build/report.json and eval.json under logs/<log>/). Prints:

1. per log: floors found against the truth, the time on the right floor, each upper floor's
   height above the start floor and its elevation error against its bar (2 cm or 0.5 % of that
   height, whichever is larger), the checkpoint RMSE on the start floor and the others (bars 16
   and 25 mm), and whether every bar is met;
2. per elevator ride and stair walk: the true height change (the ground truth's transition that
   overlaps it in time), the graph's (the optimised floors' elevations), the IMU's or the lidar
   odometry's own and the barometer's own (in its metres at the floors stage's temperature),
   with the count of rides and walks whose graph height is within 1 cm;
3. with --ablation (the same manifest built with `--config` barometer-only heights, e.g.
   graph.ablation.imu_ride_height and walk_height false): the upper floors' elevation errors,
   RMS and max, per log and over all, fused against barometer-only.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

# The bars of issue 29 (docs/heights.md, "Measured").
ELEVATION_BAR_M = 0.02
ELEVATION_BAR_SHARE = 0.005
TIME_BAR = 0.99
CHECKPOINT_BAR_START_M = 0.016
CHECKPOINT_BAR_OTHERS_M = 0.025
RIDE_BAR_M = 0.01
# A build's transition and the truth's are the same when they overlap, or else when their
# middles are this close.
MATCH_S = 30.0


@dataclass(frozen=True)
class LogHeights:
    """What one log's build, score and ground truth say about heights."""

    name: str
    metrics: dict[str, float]
    floors: list[dict[str, Any]]  # eval.json's floor rows: id, gt_elevation_m, error_m
    rides: list[dict[str, Any]]  # report.json's graph.rides
    truth: dict[str, Any]  # gt_floors.json

    @property
    def start_floor(self) -> int:
        """The true floor the log starts on: the one visited first."""
        first = {f["id"]: min(v[0] for v in f["visits"]) for f in self.truth["floors"] if f["visits"]}
        return min(first, key=lambda k: first[k])

    def elevation_of(self, floor_id: int) -> float:
        return float(next(f["elevation_m"] for f in self.truth["floors"] if f["id"] == floor_id))

    def upper_floors(self) -> list[tuple[int, float, float | None]]:
        """(true floor, height above the start floor, signed elevation error or None)."""
        base = self.elevation_of(self.start_floor)
        return [(int(row["id"]), float(row["gt_elevation_m"]) - base, row.get("error_m"))
                for row in self.floors if row["id"] != self.start_floor]


def load_run(folder: Path) -> list[LogHeights]:
    """The logs of one regression run that were built and scored (others are left out)."""
    results = json.loads((folder / "results.json").read_text())
    logs = []
    for entry in results["logs"]:
        out = Path(entry["out_dir"])
        if not out.is_dir():
            out = folder / "logs" / entry["name"]
        score, report = out / "eval.json", out / "build" / "report.json"
        if entry.get("error") or not score.is_file() or not report.is_file():
            continue
        ev = json.loads(score.read_text())
        truth = json.loads(Path(ev["inputs"]["floors"]).read_text())
        rides = json.loads(report.read_text()).get("graph", {}).get("rides", [])
        logs.append(LogHeights(entry["name"], ev["metrics"], ev.get("tables", {}).get("floors", {}).get("floors", []),
                               rides, truth))
    return logs


def elevation_bar_m(height_m: float) -> float:
    return max(ELEVATION_BAR_M, ELEVATION_BAR_SHARE * abs(height_m))


def _bold(text: str, ok: bool) -> str:
    return text if ok else f"**{text}**"


def _cm(x_m: float) -> str:
    return f"{100 * x_m:+.1f}"


def log_row(log: LogHeights) -> str:
    """One row of the per-log table, failing figures in bold."""
    m = log.metrics
    count_ok = m.get("floors.count_correct") == 1.0
    share = m.get("floors.time_correct_share", float("nan"))
    oks = [count_ok, share >= TIME_BAR]
    floors = []
    for fid, height, err in log.upper_floors():
        bar = elevation_bar_m(height)
        ok = err is not None and abs(err) <= bar
        oks.append(ok)
        shown = "unmatched" if err is None else f"{_cm(err)} cm"
        floors.append(f"{fid}: {height:.2f} m, {_bold(shown, ok)} ({100 * bar:.1f})")
    rmse = []
    for row in log.floors:
        value = m.get(f"points.floor{row['id']}.rmse_m")
        if value is None:
            continue
        bar = CHECKPOINT_BAR_START_M if row["id"] == log.start_floor else CHECKPOINT_BAR_OTHERS_M
        oks.append(value <= bar)
        rmse.append((row["id"] != log.start_floor, _bold(f"{1000 * value:.1f}", value <= bar)))
    start = [t for other, t in rmse if not other] or ["-"]
    others = ", ".join(t for other, t in rmse if other) or "-"
    counts = _bold(f"{m.get('floors.count_est', 0):.0f}/{m.get('floors.count_gt', 0):.0f}", count_ok)
    return (f"| {log.name} | {counts} | {_bold(f'{100 * share:.2f} %', share >= TIME_BAR)} | "
            f"{'; '.join(floors) or '-'} | {start[0]} / {others} | {'yes' if all(oks) else 'no'} |")


def log_table(logs: list[LogHeights]) -> str:
    head = ("| log | floors est/gt | time on right floor | floor: height above start, error (bar, cm) "
            "| checkpoint RMSE start / others (mm) | all bars |\n|---|---|---|---|---|---|\n")
    return head + "\n".join(log_row(log) for log in logs) + "\n"


def true_transition(log: LogHeights, ride: dict[str, Any]) -> dict[str, Any] | None:
    """The truth's transition of the same kind that overlaps the build's most in time, or the
    nearest within MATCH_S; None when there is none."""
    best, best_key = None, (-math.inf, -math.inf)
    for tr in log.truth["transitions"]:
        if tr["kind"] != ride["kind"]:
            continue
        overlap = min(tr["t_end"], ride["end_s"]) - max(tr["t_start"], ride["start_s"])
        apart = abs((tr["t_start"] + tr["t_end"]) - (ride["start_s"] + ride["end_s"])) / 2
        key = (overlap, -apart) if overlap > 0 else (-math.inf, -apart)
        if (overlap > 0 or apart <= MATCH_S) and key > best_key:
            best, best_key = tr, key
    return best


@dataclass(frozen=True)
class TransitionFigures:
    """One ride's or walk's heights against the truth (None where a source gave none)."""

    log: str
    kind: str
    floors: str
    true_m: float | None
    graph_m: float | None
    own_m: float | None  # the IMU's (rides) or the lidar odometry's (walks)
    baro_m: float | None
    left_out: tuple[str, ...] = ()  # "own", "baro": measured, but not used by the graph

    def error(self, value: float | None) -> float | None:
        return None if value is None or self.true_m is None else value - self.true_m

    def row(self) -> str:
        def cell(value: float | None, bar: bool = False, used: bool = True) -> str:
            err = self.error(value)
            if value is None:
                return "-"
            text = f"{value:+.3f} m" if err is None else f"{value:+.3f} m, {100 * err:+.2f} cm"
            if bar and err is not None and abs(err) > RIDE_BAR_M:
                text = f"**{text}**"
            return text if used else f"{text} (left out)"

        true = "no match" if self.true_m is None else f"{self.true_m:+.2f} m"
        return (f"| {self.log} | {self.kind} {self.floors} | {true} | {cell(self.graph_m, bar=True)} | "
                f"{cell(self.own_m, used='own' not in self.left_out)} | "
                f"{cell(self.baro_m, used='baro' not in self.left_out)} |")


def transitions(log: LogHeights) -> list[TransitionFigures]:
    out = []
    for ride in log.rides:
        tr = true_transition(log, ride)
        sensor = "imu" if ride["kind"] == "elevator" else "lidar"
        used = ride.get("heights_used", [sensor, "barometer"])
        left_out = tuple(k for k, source in (("own", sensor), ("baro", "barometer")) if source not in used)
        out.append(TransitionFigures(log.name, ride["kind"], f"{ride['from_floor']} -> {ride['to_floor']}",
                                     None if tr is None else float(tr["height_change_m"]),
                                     ride.get("graph_height_change_m"), ride.get(f"{sensor}_height_change_m"),
                                     ride.get("baro_height_change_m"), left_out))
    return out


def _within(items: list[TransitionFigures], value: str) -> str:
    errors = [it.error(getattr(it, value)) for it in items]
    good = sum(e is not None and abs(e) <= RIDE_BAR_M for e in errors)
    return f"{good} of {len(items)}"


def transition_table(logs: list[LogHeights]) -> str:
    items = [t for log in logs for t in transitions(log)]
    head = ("| log | transition (build's floors) | true change | graph (error) | IMU / lidar own (error) "
            "| barometer own (error) |\n|---|---|---|---|---|---|\n")
    lines = [head + "\n".join(t.row() for t in items) + "\n"]
    for kind, word in (("elevator", "rides"), ("stairs", "walks")):
        some = [t for t in items if t.kind == kind]
        if some:
            lines.append(f"Within 1 cm, {word}: graph {_within(some, 'graph_m')}, "
                         f"{'IMU' if kind == 'elevator' else 'lidar'} alone {_within(some, 'own_m')}, "
                         f"barometer alone {_within(some, 'baro_m')}.\n")
    return "\n".join(lines)


def _rms_max(errors: list[float]) -> str:
    if not errors:
        return "- | -"
    rms = math.sqrt(sum(e * e for e in errors) / len(errors))
    return f"{100 * rms:.1f} | {100 * max(abs(e) for e in errors):.1f}"


def ablation_table(fused: list[LogHeights], baro_only: list[LogHeights]) -> str:
    """Upper floors' elevation errors (cm), fused heights against barometer-only, by log name."""
    other = {log.name: log for log in baro_only}
    head = ("| log | upper floors | fused RMS | fused max | barometer-only RMS | barometer-only max |\n"
            "|---|---|---|---|---|---|\n")
    rows, all_f, all_b = [], [], []
    for log in fused:
        if log.name not in other:
            continue
        f = [float(e) for _, _, e in log.upper_floors() if e is not None]
        b = [float(e) for _, _, e in other[log.name].upper_floors() if e is not None]
        all_f += f
        all_b += b
        rows.append(f"| {log.name} | {len(log.upper_floors())} | {_rms_max(f)} | {_rms_max(b)} |")
    rows.append(f"| all | {len(all_f)} | {_rms_max(all_f)} | {_rms_max(all_b)} |")
    return head + "\n".join(rows) + "\n"


def figures(runs: list[Path], ablation: list[Path]) -> str:
    """The markdown of the three tables (the third with `ablation` runs only)."""
    logs = [log for run in runs for log in load_run(run)]
    parts = ["## Per log\n", log_table(logs), "## Per elevator ride and stair walk\n", transition_table(logs)]
    if ablation:
        baro = [log for run in ablation for log in load_run(run)]
        parts += ["## Barometer-only heights against the fused (upper floors' elevation error, cm)\n",
                  ablation_table(logs, baro)]
    return "\n".join(parts)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m pipelines.height_figures", description=__doc__.split("\n")[0])
    parser.add_argument("runs", nargs="+", type=Path, help="regression output folders (results.json)")
    parser.add_argument("--ablation", nargs="+", type=Path, default=[], metavar="RUN",
                        help="the same logs built with barometer-only heights")
    args = parser.parse_args(argv)
    for run in [*args.runs, *args.ablation]:
        if not (run / "results.json").is_file():
            parser.error(f"{run}: no results.json (not a regression output folder)")
    sys.stdout.write(figures(args.runs, args.ablation))
    return 0


if __name__ == "__main__":
    sys.exit(main())
