"""The `mfmap` command line: parse, load config, call one library function, print its result.

Heavy libraries (open3d, gtsam) are imported inside the commands so `mfmap --help` is instant.
Every MfmapError becomes one red line on stderr and exit code 1 (tracebacks only with --debug).
"""

from __future__ import annotations

import json
import os
import signal
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from enum import Enum
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.console import Console
from rich.markup import escape

from mfmap import __version__
from mfmap.errors import MfmapError
from mfmap.threads import limit_threads

if TYPE_CHECKING:
    from mfmap.config import MfmapConfig
    from mfmap.progress import StageProgress

app = typer.Typer(
    name="mfmap",
    help="Multi-floor building maps from robot logs (MCAP, ROS 1 bag, ROS 2 bag).",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,
)
# Tables stay readable when output goes to a file or CI log (rich assumes 80 columns there).
_WIDTH = None if sys.stdout.isatty() or "COLUMNS" in os.environ else 140
console = Console(width=_WIDTH)
err_console = Console(stderr=True)

# Exit codes: 1 user error (bad input, bad config), 3 a --fail-above threshold was exceeded.
EXIT_THRESHOLD = 3

_state: dict[str, bool] = {"debug": False}


class LogFormat(str, Enum):
    mcap = "mcap"
    ros1 = "ros1"
    ros2 = "ros2"


class Alignment(str, Enum):
    none = "none"
    se3 = "se3"
    yaw = "4dof"


def _version(value: bool) -> None:
    if value:
        console.print(f"mfmap {__version__}")
        raise typer.Exit()


@app.callback()
def _main(
    version: Annotated[
        bool,
        typer.Option("--version", callback=_version, is_eager=True, help="Show the version."),
    ] = False,
    debug: Annotated[bool, typer.Option("--debug", help="Show tracebacks for errors.")] = False,
) -> None:
    _state["debug"] = debug


class RichProgress:
    """Progress bars on stderr; silent when stderr is not a terminal."""

    def __init__(self) -> None:
        self.enabled = err_console.is_terminal

    @contextmanager
    def stage(self, name: str, total: float | None = None) -> Iterator[StageProgress]:
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TextColumn,
            TimeElapsedColumn,
        )

        with Progress(
            TextColumn("{task.description:<10}"),
            BarColumn(),
            MofNCompleteColumn(),
            TimeElapsedColumn(),
            console=err_console,
            disable=not self.enabled,
            transient=False,
        ) as bar:
            task = bar.add_task(name, total=total)

            class _Stage:
                def advance(self, n: float = 1) -> None:
                    bar.advance(task, n)

                def set_total(self, total: float | None) -> None:
                    bar.update(task, total=total)

            yield _Stage()


def _parse_topics(items: list[str] | None) -> dict[str, str]:
    from mfmap.types import Role

    out: dict[str, str] = {}
    for item in items or []:
        role, sep, topic = item.partition("=")
        if not sep or not topic:
            raise MfmapError(f"--topic expects ROLE=TOPIC, got '{item}'")
        if role not in {r.value for r in Role}:
            roles = ", ".join(r.value for r in Role)
            raise MfmapError(f"--topic: unknown role '{role}' (roles: {roles})")
        out[role] = topic
    return out


def _load(config: Path | None, topics: list[str] | None = None,
          assume_identity_extrinsics: bool = False) -> MfmapConfig:
    from mfmap.config import load_config

    overrides: dict[str, Any] = {}
    parsed = _parse_topics(topics)
    if parsed:
        overrides["ingest"] = {"topics": parsed}
    if assume_identity_extrinsics:
        overrides.setdefault("ingest", {})["assume_identity_extrinsics"] = True
    return load_config(config, overrides)


ConfigOpt = Annotated[
    Path | None, typer.Option("--config", "-c", help="YAML configuration file.")
]
TopicOpt = Annotated[
    list[str] | None,
    typer.Option("--topic", "-t", help="Override a role's topic: ROLE=TOPIC (repeatable)."),
]
AssumeIdentityOpt = Annotated[
    bool,
    typer.Option("--assume-identity-extrinsics",
                 help="Place a sensor frame that no transform connects to the base at the base, "
                 "unrotated (a warning), instead of stopping."),
]


@app.command()
def info(
    log: Annotated[Path, typer.Argument(help="MCAP file, ROS 1 bag or ROS 2 bag folder.")],
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON instead of a table.")] = False,
    check: Annotated[
        bool,
        typer.Option("--check", help="Also read what needs the whole log (barometer unit, 2D "
                     "beam order) and exit 1 when a build would stop or be wrong."),
    ] = False,
    assume_identity: AssumeIdentityOpt = False,
    topic: TopicOpt = None,
    config: ConfigOpt = None,
) -> None:
    """Topics, message types, roles, counts, rates and duration of a log; per sensor its
    fields, how its per-point time reads, its frame and whether its transform is known."""
    cfg = _load(config, topic, assume_identity)
    from mfmap.ingest import describe_log
    from mfmap.ingest.report import render_info

    summary = describe_log(log, cfg.ingest, check=check)
    from mfmap.ingest.camera_info import describe_cameras, render_cameras

    cameras, camera_warnings = describe_cameras(log, cfg.ingest, cfg.camera)
    if as_json:
        console.print_json(json.dumps({**summary.to_json(), **({"cameras": cameras} if cameras else {})}))
    else:
        console.print(render_info(summary))
        if cameras:
            console.print(render_cameras(cameras))
    for warning in [*summary.warnings, *camera_warnings]:
        err_console.print(f"[yellow]warning:[/yellow] {escape(warning)}")
    for problem in summary.problems:
        label = "[red]problem:[/red]" if check else "[yellow]problem:[/yellow]"
        err_console.print(f"{label} {escape(problem)}", highlight=False, soft_wrap=True)
    if check and summary.problems:
        raise typer.Exit(1)


@app.command("config")
def config_cmd(
    config: ConfigOpt = None,
) -> None:
    """Print the configuration as YAML (the defaults, or a file's resolved values), each key's
    description as a comment above it."""
    from mfmap.config import dump_config

    sys.stdout.write(dump_config(_load(config), comments=True))


@app.command()
def simulate(
    scenario: Annotated[str, typer.Argument(help="Scenario name (see --list).")] = "two-floor",
    out: Annotated[Path, typer.Option("--out", "-o", help="Output folder.")] = Path("sim"),
    fmt: Annotated[LogFormat, typer.Option("--format", help="Log format.")] = LogFormat.mcap,
    seed: Annotated[int, typer.Option("--seed", help="Random seed.")] = 0,
    plot: Annotated[bool, typer.Option("--plot", help="Also write floor-plan and pressure PNGs.")] = False,
    duration_scale: Annotated[
        float, typer.Option("--duration-scale", help="Repeat the route to lengthen the log.")
    ] = 1.0,
    list_scenarios: Annotated[bool, typer.Option("--list", help="List scenarios and exit.")] = False,
) -> None:
    """Write a synthetic building log with its ground truth."""
    from mfmap.sim import SCENARIOS
    from mfmap.sim import simulate as run_simulation
    from mfmap.sim.report import render_simulation

    if list_scenarios:
        for name, spec in SCENARIOS.items():
            console.print(f"{name:<22} {spec.description}")
        return
    result = run_simulation(
        scenario,
        out,
        fmt=fmt.value,
        seed=seed,
        plot=plot,
        duration_scale=duration_scale,
        progress=RichProgress(),
    )
    console.print(render_simulation(result))


@app.command()
def floors(
    log: Annotated[Path, typer.Argument(help="Log, or a CSV of t,pressure.")],
    plot: Annotated[Path | None, typer.Option("--plot", help="Write a PNG of the trace.")] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print floors.json to stdout.")] = False,
    topic: TopicOpt = None,
    config: ConfigOpt = None,
) -> None:
    """Floor segmentation from the barometer: floors, transitions, revisits."""
    from mfmap.floors import segment_path
    from mfmap.floors.io import segmentation_to_json
    from mfmap.floors.report import render_floors

    cfg = _load(config, topic)
    seg = segment_path(log, cfg)
    if plot is not None:
        from mfmap.floors.plot import plot_segmentation

        plot_segmentation(seg, plot, title=log.name)
    if as_json:
        sys.stdout.write(json.dumps(segmentation_to_json(seg), indent=2) + "\n")
    else:
        console.print(render_floors(seg))
    for warning in seg.warnings:
        err_console.print(f"[yellow]warning:[/yellow] {escape(warning)}")


@app.command()
def build(
    logs: Annotated[list[Path], typer.Argument(help="MCAP file, ROS 1 bag or ROS 2 bag folder; "
                                               "several logs of one building give one map.")],
    out: Annotated[Path, typer.Option("--out", "-o", help="Output folder.")],
    extend: Annotated[Path | None, typer.Option(
        "--extend", help="A build to add the logs to (read, not changed; its logs are built "
        "again with them into OUT).")] = None,
    force: Annotated[bool, typer.Option("--force", help="Replace an existing output folder.")] = False,
    threads: Annotated[
        int,
        typer.Option(
            "--threads",
            min=1,
            help="CPU threads for the numeric libraries. 1 (default) gives bit-identical "
            "output run to run; more lets open3d and GTSAM sum in parallel, and runs then differ "
            "(by centimetres on some logs: the odometry amplifies the last bits).",
        ),
    ] = 1,
    assume_identity: AssumeIdentityOpt = False,
    topic: TopicOpt = None,
    config: ConfigOpt = None,
) -> None:
    """The whole pipeline: floors, per-floor mapping, building graph, exports."""
    cfg = _load(config, topic, assume_identity)
    limit_threads(threads)
    from mfmap.report import render_summary

    inputs = [config] if config is not None else []
    if len(logs) == 1 and extend is None:
        from mfmap.pipeline import build as run_build

        result = run_build(logs[0], out, cfg, force=force, progress=RichProgress(), inputs=inputs)
    else:
        from mfmap.multilog import build_logs

        result = build_logs(logs, out, cfg, force=force, progress=RichProgress(), inputs=inputs,
                            extend=extend)
    console.print(render_summary(result))
    for warning in result.warnings:
        err_console.print(f"[yellow]warning:[/yellow] {escape(warning)}")


@app.command()
def localize(
    log: Annotated[Path, typer.Argument(help="The new log: MCAP file, ROS 1 bag or ROS 2 bag folder.")],
    map_dir: Annotated[Path, typer.Option("--map", "-m", help="Output folder of mfmap build.")],
    out: Annotated[Path, typer.Option("--out", "-o", help="Output folder.")],
    initial_pose: Annotated[
        tuple[float, float, float] | None,
        typer.Option("--initial-pose", help="A hint: X Y YAW_DEG of the start in the map's frame."),
    ] = None,
    floor: Annotated[
        int | None, typer.Option("--floor", help="A hint: the map floor the log starts on.")
    ] = None,
    force: Annotated[bool, typer.Option("--force", help="Replace an existing output folder.")] = False,
    threads: Annotated[
        int, typer.Option("--threads", min=1, help="CPU threads (1 gives bit-identical output).")
    ] = 1,
    topic: TopicOpt = None,
    config: ConfigOpt = None,
) -> None:
    """Place a new log of a mapped building in the map's frame: floor and pose at every scan."""
    cfg = _load(config, topic)
    limit_threads(threads)
    from mfmap.localize import Hint, render_summary
    from mfmap.localize import localize as run_localize

    hint = None
    if initial_pose is not None or floor is not None:
        x, y, yaw = initial_pose if initial_pose is not None else (None, None, None)
        hint = Hint(floor=floor, x_m=x, y_m=y, yaw_deg=yaw)
    result = run_localize(log, map_dir, out, cfg, hint=hint, force=force, progress=RichProgress())
    console.print(render_summary(result))
    for warning in result.warnings:
        err_console.print(f"[yellow]warning:[/yellow] {warning}")


@app.command("eval")
def eval_cmd(
    out: Annotated[Path, typer.Argument(help="A build's output folder.")],
    points: Annotated[Path | None, typer.Option("--points", help="Checkpoints CSV.")] = None,
    cloud: Annotated[Path | None, typer.Option("--cloud", help="Reference cloud (PLY/PCD).")] = None,
    trajectory: Annotated[
        Path | None, typer.Option("--trajectory", help="Ground-truth TUM trajectory.")
    ] = None,
    floors_gt: Annotated[
        Path | None, typer.Option("--floors", help="Ground-truth floors JSON.")
    ] = None,
    align: Annotated[
        Alignment, typer.Option("--align", help="Extra aligned trajectory errors.")
    ] = Alignment.none,
    json_out: Annotated[
        Path | None, typer.Option("--json", help="Where to write eval.json (default OUT/eval.json).")
    ] = None,
    fail_above: Annotated[
        list[str] | None,
        typer.Option("--fail-above", help="METRIC=VALUE: exit 3 when the metric is above VALUE."),
    ] = None,
    truth: Annotated[list[Path] | None, typer.Option("--truth", help="A simulated log's folder: "
                     "its gt_* files; repeated, several logs' truth merged (OUT/truth/).")] = None,
    config: ConfigOpt = None,
) -> None:
    """Score a build against ground truth: points, cloud, trajectory, floors."""
    from mfmap.eval import evaluate, parse_thresholds
    from mfmap.eval.report import render_eval

    if truth:
        from mfmap.eval.sessions import merge_sessions

        given = merge_sessions(truth, out / "truth")
        points, trajectory, floors_gt = given.points, given.trajectory, given.floors
    cfg = _load(config)
    thresholds = parse_thresholds(fail_above or [])
    result = evaluate(
        out,
        points=points,
        cloud=cloud,
        trajectory=trajectory,
        floors=floors_gt,
        align=align.value,
        config=cfg.eval,
    )
    target = json_out if json_out is not None else out / "eval.json"
    result.write_json(target)
    console.print(render_eval(result))
    console.print(f"eval.json: {target}")
    failures = result.check_thresholds(thresholds)
    for failure in failures:
        err_console.print(f"[red]regression:[/red] {failure}")
    if failures:
        raise typer.Exit(EXIT_THRESHOLD)


class Interrupted(BaseException):
    """SIGINT or SIGTERM: unwinds the command like Ctrl-C (partial outputs removed, workers
    stopped). A BaseException of its own, so typer does not turn it into 'Aborted!'."""

    def __init__(self, signum: int) -> None:
        self.signum = signum
        super().__init__(signal.Signals(signum).name)


def _interrupt(signum: int, _frame: object) -> None:
    # Once: a second signal must not cut the clean-up short.
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, signal.SIG_IGN)
    raise Interrupted(signum)


# How long the clean-up may take before the process stops without it.
STOP_GRACE_S = 1.5


class _SignalWatch:
    """Stops the process soon after SIGINT or SIGTERM even when its main thread cannot unwind.

    Python runs a signal handler only between bytecodes: a main thread inside one long call of a
    library (a factor-graph optimisation, an import) would keep the process, and its workers,
    alive until the call returns. The C-level handler writes each signal to a wakeup pipe at
    once; this thread reads it, gives the main thread STOP_GRACE_S to unwind and clean up, and
    otherwise kills the workers and exits (what the build had begun is left marked, and the next
    build removes it).
    """

    def __init__(self) -> None:
        self.done = threading.Event()
        read_fd, write_fd = os.pipe()
        os.set_blocking(write_fd, False)
        signal.set_wakeup_fd(write_fd, warn_on_full_buffer=False)
        self._read_fd = read_fd
        threading.Thread(target=self._watch, name="mfmap-signal-watch", daemon=True).start()

    def _watch(self) -> None:
        try:
            data = os.read(self._read_fd, 1)
        except OSError:
            return
        if self.done.wait(STOP_GRACE_S):
            return
        import multiprocessing

        for child in multiprocessing.active_children():
            child.kill()
        signum = data[0] if data else int(signal.SIGTERM)
        try:
            name = signal.Signals(signum).name
        except ValueError:
            name = str(signum)
        os.write(2, f"mfmap: interrupted ({name}) inside a long computation: stopped at once; "
                    "the next build removes what this one had begun\n".encode())
        os._exit(128 + signum)


def main() -> None:
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, _interrupt)
    watch = _SignalWatch()
    try:
        app()
    except MfmapError as err:
        if _state["debug"]:
            raise
        # A message may hold brackets ([x, y, z]) that rich would take for markup.
        err_console.print(f"[red]mfmap: error:[/red] {escape(str(err))}", highlight=False,
                          soft_wrap=True)
        sys.exit(err.exit_code)
    except Interrupted as stop:
        watch.done.set()
        err_console.print(f"[red]mfmap: interrupted[/red] ({stop}): nothing was left half-written",
                          highlight=False)
        # The clean-up is done; the interpreter's own (unloading open3d, GTSAM, TBB) took 3 to
        # 10 s on a loaded machine. Only multiprocessing's finalizers run, which release the
        # queues' semaphores (else the resource tracker warns of leaked ones).
        if "multiprocessing" in sys.modules:
            import multiprocessing.util

            finalize = getattr(multiprocessing.util, "_exit_function", None)
            if finalize is not None:
                finalize()
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(128 + stop.signum)


if __name__ == "__main__":
    main()
