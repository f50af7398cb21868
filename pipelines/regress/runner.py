"""Build and score every log of a manifest: in a local process pool or as Ray tasks.

Each log runs in a fresh process (`max_tasks_per_child=1` locally, `max_calls=1` on Ray) with the
same thread count on both backends, so a log gives bit-identical metrics wherever it runs.
Results stream back as they finish; a task that raises an unexpected error, or whose worker dies,
is retried once; a log that fails is reported with its error and does not stop the others.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import math
import multiprocessing
import os
import shutil
import tempfile
import time
from collections.abc import Callable, Iterator
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import Any

from mfmap.config import merge_dicts, read_yaml_mapping
from mfmap.errors import MfmapError
from pipelines.regress.compare import (
    flatten_metrics,
    judge,
    read_baseline_entries,
    updated_baseline,
    updated_machines,
    write_baseline,
)
from pipelines.regress.machine import machine_fingerprint
from pipelines.regress.manifest import LogEntry, Manifest, ManifestError, Simulate
from pipelines.regress.model import LogJob, LogOutcome, LogResult, RunResult, Verdict
from pipelines.regress.report import sort_results, write_reports

logger = logging.getLogger(__name__)

GIB = 1024**3
# Ground-truth files the simulator writes beside its log, by `mfmap eval` option.
SIM_GROUND_TRUTH = {
    "points": "gt_points.csv",
    "cloud": "gt_cloud.ply",
    "trajectory": "gt_trajectory.tum",
    "floors": "gt_floors.json",
}
SIM_LOG_NAME = {"mcap": "log.mcap", "ros1": "log.bag", "ros2": "log"}

OnResult = Callable[[LogResult], None]


class JobError(Exception):
    """An unexpected failure inside a job, carrying the step it failed in (picklable)."""

    def __init__(self, stage: str, message: str) -> None:
        super().__init__(stage, message)
        self.stage = stage
        self.message = message

    def __str__(self) -> str:
        return self.message


# ---------------------------------------------------------------------------------------------
# Jobs from a manifest


def resolve_config(manifest: Manifest, entry: LogEntry) -> dict[str, Any]:
    """Defaults <- manifest config file <- manifest overrides <- log config file <- log overrides."""
    from mfmap.config import config_from_dict

    data: dict[str, Any] = {}
    if manifest.config is not None:
        data = merge_dicts(data, read_yaml_mapping(manifest.config, ManifestError))
    data = merge_dicts(data, manifest.config_overrides)
    if entry.config is not None:
        data = merge_dicts(data, read_yaml_mapping(entry.config, ManifestError))
    data = merge_dicts(data, entry.config_overrides)
    source = manifest.source if manifest.source is not None else Path("<manifest>")
    try:
        config = config_from_dict(data, f"{source} (logs[{entry.name}])")
    except MfmapError as err:
        raise ManifestError(str(err).split(": ", 1)[-1], f"{source} (logs[{entry.name}])") from err
    # Only what the manifest set: a stage that tells a user's setting from its default (the
    # barometer's Temperature topic sets floors.temperature_k unless the config does) must see
    # the defaults as defaults.
    return config.model_dump(mode="json", exclude_unset=True)


def make_jobs(manifest: Manifest, out_dir: Path) -> list[LogJob]:
    """One job per log; configs are validated here, before anything runs."""
    jobs = []
    for entry in manifest.logs:
        res = manifest.resources_for(entry)
        gt = {k: (str(v) if v is not None else None) for k, v in entry.ground_truth.model_dump().items()}
        jobs.append(
            LogJob(
                name=entry.name,
                out_dir=str((out_dir / "logs" / entry.name).resolve()),
                config=resolve_config(manifest, entry),
                log=str(entry.log) if entry.log is not None else None,
                simulate=entry.simulate.model_dump() if entry.simulate is not None else None,
                sim_cache=str(manifest.sim_cache_dir().resolve()),
                ground_truth=gt,
                skip_ground_truth=tuple(entry.skip_ground_truth),
                localize=entry.localize.model_dump(mode="json") if entry.localize is not None else None,
                build_with=tuple(sim.model_dump() for sim in entry.build_with),
                num_cpus=res.num_cpus,
                memory_gb=res.memory_gb,
            )
        )
    return jobs


# ---------------------------------------------------------------------------------------------
# One log, in a worker process


def sim_folder(cache: Path, sim: Simulate) -> Path:
    """The cache folder of a simulated run; the same name the `sim_run` test fixture uses."""
    extra = f"-duration_scale={sim.duration_scale}" if sim.duration_scale != 1.0 else ""
    return cache / f"{sim.scenario}-{sim.fmt}-{sim.seed}{extra}"


@contextlib.contextmanager
def _file_lock(path: Path) -> Iterator[None]:
    import fcntl

    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def is_simulated(cache: Path, sim: Simulate) -> bool:
    """Whether the cache holds this run, complete and made by the simulator's present source."""
    from mfmap.sim import source_digest

    folder = sim_folder(cache, sim)
    done = folder / ".complete"
    # The marker holds the simulator's source digest.
    return (done.exists() and (folder / SIM_LOG_NAME[sim.fmt]).exists()
            and done.read_text().strip() == source_digest())


def ensure_simulated(cache: Path, sim: Simulate) -> Path:
    """Generate a scenario once into the cache (locked, so parallel workers share one run)."""
    from mfmap.sim import simulate, source_digest

    folder = sim_folder(cache, sim)
    if is_simulated(cache, sim):
        return folder
    with _file_lock(folder.with_name(folder.name + ".lock")):
        if is_simulated(cache, sim):
            return folder

        if folder.exists():  # an interrupted or partly deleted run: start again
            shutil.rmtree(folder)
        kwargs: dict[str, Any] = {}
        if sim.duration_scale != 1.0:
            kwargs["duration_scale"] = sim.duration_scale
        simulate(sim.scenario, folder, fmt=sim.fmt, seed=sim.seed, **kwargs)
        (folder / ".complete").write_text(source_digest() + "\n")
    return folder


def _threads(num_cpus: float) -> int:
    return max(1, math.floor(num_cpus))


def thread_env(num_cpus: float) -> dict[str, str]:
    """Thread-pool sizes for a job's declared CPUs (read by OpenMP and BLAS when they load)."""
    n = str(_threads(num_cpus))
    return {"OMP_NUM_THREADS": n, "OPENBLAS_NUM_THREADS": n, "MKL_NUM_THREADS": n}


# Lock files held for the life of a worker process: which CPUs it has claimed on this node.
_claimed: list[Any] = []


def pin_cpus(n: int, lock_dir: Path | None = None) -> list[int]:
    """Restrict this process to `n` CPUs that no other regression worker on the node holds.

    open3d's and GTSAM's thread pools (OpenMP, TBB) size themselves from the CPUs a process may
    use, and a multi-threaded reduction sums in a different order from run to run: last bits,
    which the odometry can grow to centimetres on some logs (stairs seed 2's top floor gave 20.0
    and 58.3 mm in two multithreaded runs). Pinned to its declared CPU count, with one CPU a build
    is bit-identical wherever it runs. Each CPU is claimed with a lock file, so parallel workers
    (local pool or Ray tasks on one node) spread over the cores instead of piling onto one.
    """
    import fcntl

    cpus = sorted(os.sched_getaffinity(0))
    n = max(1, min(n, len(cpus)))
    folder = lock_dir or Path(tempfile.gettempdir()) / "mfmap-regression-cpus"
    folder.mkdir(parents=True, exist_ok=True)
    chosen: list[int] = []
    for cpu in cpus:
        fh = (folder / f"cpu{cpu}.lock").open("w")
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            fh.close()
            continue
        _claimed.append(fh)
        chosen.append(cpu)
        if len(chosen) == n:
            break
    if len(chosen) < n:  # more workers than CPUs: share, still with n threads each
        chosen = cpus[:n]
    os.sched_setaffinity(0, chosen)
    return chosen


def run_job(job: LogJob, reraise: bool = False) -> LogOutcome:
    """Simulate (if needed), build and evaluate one log; errors become a failed outcome.

    With `reraise`, errors that are not an MfmapError (a bug, a crash) propagate so the
    executor can retry the task once; an MfmapError is the input's fault and is not retried.
    Meant for a fresh worker process: it pins the process to the job's CPUs and sets its
    thread-pool sizes.
    """
    # Same CPUs and threads on every backend, before open3d and GTSAM load in this fresh process.
    for name, value in thread_env(job.num_cpus).items():
        os.environ[name] = value
    pin_cpus(_threads(job.num_cpus))
    start = time.perf_counter()
    stage = "simulate"
    log = job.log
    try:
        gt: dict[str, str | None] = dict(job.ground_truth)
        if job.simulate is not None:
            sim = Simulate.model_validate(job.simulate)
            folder = ensure_simulated(Path(job.sim_cache or "."), sim)
            log = str(folder / SIM_LOG_NAME[sim.fmt])
            for key, name in SIM_GROUND_TRUTH.items():
                if gt.get(key) is None and (folder / name).exists():
                    gt[key] = str(folder / name)
        for key in job.skip_ground_truth:
            gt[key] = None
        assert log is not None
        from mfmap.config import MfmapConfig

        config = MfmapConfig.model_validate(job.config)
        if job.localize is not None or job.build_with:
            from pipelines.regress.localize import localize_job
            from pipelines.regress.multilog import multilog_job

            steps: list[str] = []
            try:
                run = localize_job if job.localize is not None else multilog_job
                metrics = run(job, Path(log), gt, config, steps.append)
            finally:
                stage = steps[-1] if steps else stage
            return LogOutcome(name=job.name, ok=True, metrics=metrics,
                              wall_s=time.perf_counter() - start, out_dir=job.out_dir, log=log,
                              machine=machine_fingerprint())
        out = Path(job.out_dir) / "build"
        stage = "build"
        from mfmap.pipeline import build

        build(Path(log), out, config, force=True)
        stage = "eval"
        from mfmap.eval import evaluate

        result = evaluate(
            out,
            points=_path(gt.get("points")),
            cloud=_path(gt.get("cloud")),
            trajectory=_path(gt.get("trajectory")),
            floors=_path(gt.get("floors")),
            align="none",
            config=config.eval,
        )
        result.write_json(Path(job.out_dir) / "eval.json")
        metrics = flatten_metrics(result.metrics)
    except MfmapError as err:
        return _failed(job, log, stage, str(err), start)
    except Exception as err:
        if reraise:
            raise JobError(stage, f"{type(err).__name__}: {err}") from err
        return _failed(job, log, stage, f"{type(err).__name__}: {err}", start)
    return LogOutcome(
        name=job.name,
        ok=True,
        metrics=metrics,
        wall_s=time.perf_counter() - start,
        out_dir=job.out_dir,
        log=log,
        machine=machine_fingerprint(),
    )


def _describe_error(err: BaseException) -> tuple[str, str]:
    """(failed step, one-line message) of an error that reached the executor."""
    if isinstance(err, JobError):
        return err.stage, err.message
    return "worker", f"{type(err).__name__}: {err}"


def _path(value: str | None) -> Path | None:
    return Path(value) if value else None


def _failed(job: LogJob, log: str | None, stage: str, error: str, start: float) -> LogOutcome:
    line = " ".join(error.split()) or "unknown error"
    return LogOutcome(
        name=job.name,
        ok=False,
        metrics={},
        wall_s=time.perf_counter() - start,
        out_dir=job.out_dir,
        log=log,
        error=line,
        stage=stage,
    )


# ---------------------------------------------------------------------------------------------
# Local process pool


def default_workers(jobs: list[LogJob]) -> int:
    """As many builds at once as the CPUs and the available memory hold."""
    if not jobs:
        return 1
    cpus = len(os.sched_getaffinity(0))
    need_cpus = max(j.num_cpus for j in jobs)
    need_mem = max(j.memory_gb for j in jobs) * GIB
    by_cpu = math.floor(cpus / need_cpus)
    by_mem = math.floor(available_memory_bytes() / need_mem)
    return max(1, min(len(jobs), by_cpu, by_mem))


def available_memory_bytes() -> int:
    """MemAvailable from /proc/meminfo (what can be used without swapping), else free pages."""
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")


def run_local(jobs: list[LogJob], workers: int) -> Iterator[LogOutcome]:
    """Outcomes in the order the builds finish."""
    # spawn + one task per child: a fresh interpreter per log, like a Ray task with max_calls=1.
    ctx = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=workers, mp_context=ctx, max_tasks_per_child=1) as pool:
        pending: dict[Future[LogOutcome], tuple[LogJob, int]] = {
            pool.submit(run_job, job, True): (job, 1) for job in jobs
        }
        while pending:
            done, _ = wait(pending, return_when=FIRST_COMPLETED)
            for fut in done:
                job, attempt = pending.pop(fut)
                try:
                    yield fut.result()
                except BrokenProcessPool as err:
                    # The pool cannot take a resubmission once a worker died; report the log.
                    yield _failed(job, job.log, "worker", f"worker process died ({err})", time.perf_counter())
                except Exception as err:
                    if attempt < 2:
                        logger.warning("%s failed (%s), retrying once", job.name, err)
                        pending[pool.submit(run_job, job, True)] = (job, attempt + 1)
                    else:
                        yield _failed(job, job.log, *_describe_error(err), time.perf_counter())


# ---------------------------------------------------------------------------------------------
# Ray


def _ray_task(job: LogJob) -> LogOutcome:
    return run_job(job, reraise=True)


def init_ray(address: str | None = None, num_cpus: int | None = None) -> None:
    """Connect to a cluster (`address`) or start a local instance; ship this checkout's code."""
    import ray

    if ray.is_initialized():
        return
    import mfmap
    import pipelines

    # The workers import the mfmap and pipelines of this checkout, on any node of the cluster.
    modules = [str(Path(mfmap.__file__).parent), str(Path(pipelines.__file__).parent)]
    runtime_env = {"py_modules": modules, "excludes": ["__pycache__", "*.pyc"]}
    kwargs: dict[str, Any] = {"runtime_env": runtime_env, "log_to_driver": False}
    if address:
        kwargs["address"] = address
    else:
        kwargs["include_dashboard"] = False
        if num_cpus is not None:
            kwargs["num_cpus"] = num_cpus
    ray.init(**kwargs)


def run_ray(jobs: list[LogJob]) -> Iterator[LogOutcome]:
    """One Ray task per log with its CPU and memory needs; outcomes as they finish."""
    import ray

    # A fresh worker process per log (max_calls=1), as the local pool does; Ray only takes
    # max_calls at decoration, the per-log needs go in .options().
    remote = ray.remote(max_calls=1)(_ray_task)
    refs: dict[Any, LogJob] = {}
    for job in jobs:
        task = remote.options(
            num_cpus=job.num_cpus,
            memory=int(job.memory_gb * GIB),
            max_retries=1,  # a lost worker (node died, OOM-killed)
            retry_exceptions=True,  # an unexpected exception (MfmapErrors are returned, not raised)
            # Set when the worker starts, before Ray's own imports load numpy's BLAS.
            runtime_env={"env_vars": thread_env(job.num_cpus)},
            name=f"mfmap-regression:{job.name}",
        )
        refs[task.remote(job)] = job
    waiting = list(refs)
    while waiting:
        ready, waiting = ray.wait(waiting, num_returns=1)
        job = refs[ready[0]]
        try:
            yield ray.get(ready[0])
        except Exception as err:
            # After the retry: the task's own error (RayTaskError.cause), or the worker lost twice.
            cause = getattr(err, "cause", None) or err
            yield _failed(job, job.log, *_describe_error(cause), time.perf_counter())


# ---------------------------------------------------------------------------------------------
# The whole run


def run_regression(
    manifest: Manifest,
    out_dir: Path,
    *,
    use_ray: bool = False,
    ray_address: str | None = None,
    workers: int | None = None,
    update_baseline: bool = False,
    on_result: OnResult | None = None,
) -> RunResult:
    """Build, score and compare every log; write summary.md, junit.xml and results.json."""
    start = time.perf_counter()
    out_dir.mkdir(parents=True, exist_ok=True)
    jobs = make_jobs(manifest, out_dir)
    baseline, machines = read_baseline_entries(manifest.baseline)
    if use_ray:
        init_ray(ray_address)
        import ray

        backend = f"ray[{ray_address or 'local'}, {int(ray.cluster_resources().get('CPU', 0))} CPUs]"
        outcomes = run_ray(jobs)
    else:
        n = workers if workers is not None else default_workers(jobs)
        backend = f"local[{n} workers]"
        outcomes = run_local(jobs, n)

    results: list[LogResult] = []
    for outcome in outcomes:
        result = judge(outcome, baseline.get(outcome.name), manifest, machines.get(outcome.name))
        if update_baseline and result.verdict is not Verdict.ERROR:
            # The checks against the old baseline stay in the reports: what this update changes.
            result = dataclasses.replace(result, verdict=Verdict.UPDATED)
        results.append(result)
        if on_result is not None:
            on_result(result)

    if update_baseline:
        write_baseline(manifest.baseline, updated_baseline(baseline, results), manifest.name,
                       updated_machines(machines, results))
    run = RunResult(
        manifest=manifest.name,
        backend=backend,
        wall_s=time.perf_counter() - start,
        results=sort_results(results),
        baseline_updated=update_baseline,
    )
    write_reports(run, out_dir)
    return run
