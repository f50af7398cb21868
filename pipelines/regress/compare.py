"""Metrics against a stored baseline, with per-metric tolerances and directions.

A metric regresses when it is worse than its baseline by more than `abs + rel * |baseline|`
("worse" is larger, or smaller for the manifest's higher-better metrics). A baseline metric that
is now absent or NaN also regresses; a metric the baseline lacks is reported as new.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from mfmap.atomic import write_text_atomic
from pipelines.regress.manifest import Manifest, ManifestError, Tolerances
from pipelines.regress.model import CheckStatus, LogOutcome, LogResult, MetricCheck, Verdict

BASELINE_FORMAT = 1


def flatten_metrics(data: Mapping[str, Any], prefix: str = "") -> dict[str, float]:
    """Nested numbers -> flat `a.b.c` names; bools become 0/1, None NaN, other values dropped."""
    out: dict[str, float] = {}
    for key, value in data.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            out.update(flatten_metrics(value, name + "."))
        elif isinstance(value, bool | int | float):
            out[name] = float(value)
        elif value is None:
            out[name] = math.nan
    return out


def compare_metrics(
    current: Mapping[str, float],
    baseline: Mapping[str, float],
    tolerances: Tolerances,
    higher_better: Callable[[str], bool],
    ignored: Callable[[str], bool] = lambda _: False,
) -> list[MetricCheck]:
    """Every metric of either side, checked; sorted by name."""
    checks: list[MetricCheck] = []
    for name in sorted(set(current) | set(baseline)):
        if ignored(name):
            continue
        base = baseline.get(name)
        value = current.get(name)
        hb = higher_better(name)
        allowed = tolerances.for_metric(name).allowed(base if base is not None and _finite(base) else 0.0)
        checks.append(
            MetricCheck(name, base, value, hb, allowed, _status(name, base, value, hb, allowed, baseline))
        )
    return checks


def _status(
    name: str,
    base: float | None,
    value: float | None,
    higher_better: bool,
    allowed: float,
    baseline: Mapping[str, float],
) -> CheckStatus:
    if name not in baseline:
        return CheckStatus.NEW
    if not _finite(base):
        return CheckStatus.OK  # nothing was measured before, so nothing can get worse
    if not _finite(value):
        return CheckStatus.MISSING
    assert base is not None and value is not None
    worse = (base - value) if higher_better else (value - base)
    # A hair of slack so a tolerance of exactly 0 still accepts a bit-identical rebuild.
    if worse > allowed + 1e-12 * max(1.0, abs(base)):
        return CheckStatus.REGRESSED
    if -worse > allowed and worse < 0:
        return CheckStatus.IMPROVED
    return CheckStatus.OK


def judge(
    outcome: LogOutcome, baseline: Mapping[str, float] | None, manifest: Manifest,
    baseline_machine: str | None = None,
) -> LogResult:
    """The verdict for one log's outcome against its baseline (None: the baseline lacks it),
    made on `baseline_machine` (None: the baseline does not say)."""
    if not outcome.ok:
        return LogResult(outcome, [], Verdict.ERROR)
    if baseline is None:
        return LogResult(outcome, [], Verdict.NO_BASELINE)
    entry = next((e for e in manifest.logs if e.name == outcome.name), None)
    tolerances = manifest.tolerances_for(entry) if entry is not None else manifest.tolerances
    checks = compare_metrics(
        outcome.metrics, baseline, tolerances, manifest.is_higher_better, manifest.is_ignored
    )
    bad = any(c.status in (CheckStatus.REGRESSED, CheckStatus.MISSING) for c in checks)
    return LogResult(outcome, checks, Verdict.REGRESSED if bad else Verdict.PASS, baseline_machine)


def read_baseline(path: Path) -> dict[str, dict[str, float]]:
    """log name -> metrics; an absent file is an empty baseline."""
    return read_baseline_entries(path)[0]


def read_baseline_entries(path: Path) -> tuple[dict[str, dict[str, float]], dict[str, str]]:
    """One read of the baseline: log name -> metrics, and log name -> machine (entries made
    before machines were recorded have none)."""
    if not path.exists():
        return {}, {}
    try:
        data = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise ManifestError(f"baseline is not readable JSON ({err.__class__.__name__})", path) from err
    logs = data.get("logs") if isinstance(data, dict) else None
    if not isinstance(logs, dict):
        raise ManifestError("baseline lacks a 'logs' mapping", path)
    metrics_of: dict[str, dict[str, float]] = {}
    machines: dict[str, str] = {}
    for name, entry in logs.items():
        metrics = entry.get("metrics") if isinstance(entry, dict) else None
        if not isinstance(metrics, dict):
            raise ManifestError(f"baseline entry '{name}' lacks 'metrics'", path)
        metrics_of[name] = flatten_metrics(metrics)
        if isinstance(entry.get("machine"), str):
            machines[name] = entry["machine"]
    return metrics_of, machines


def updated_machines(previous: Mapping[str, str], results: list[LogResult]) -> dict[str, str]:
    """The machines of `updated_baseline`: a rebuilt log's is where it was rebuilt."""
    out = dict(previous)
    for result in results:
        if result.outcome.ok:
            out[result.name] = result.outcome.machine
    return out


def updated_baseline(
    previous: Mapping[str, Mapping[str, float]], results: list[LogResult]
) -> dict[str, dict[str, float]]:
    """The previous baseline with every successfully built log's metrics replaced.

    A log that failed keeps its previous entry: a broken build must not erase the reference.
    """
    out = {name: dict(metrics) for name, metrics in previous.items()}
    for result in results:
        if result.outcome.ok:
            out[result.name] = dict(result.outcome.metrics)
    return out


def write_baseline(
    path: Path, baseline: Mapping[str, Mapping[str, float]], manifest_name: str,
    machines: Mapping[str, str] | None = None,
) -> None:
    """Rewrite the baseline atomically, keys sorted so a diff shows only what changed; each
    entry with the machine it was made on, where `machines` knows it."""
    from mfmap import __version__

    def entry(name: str, metrics: Mapping[str, float]) -> dict[str, Any]:
        out: dict[str, Any] = {}
        if machines and machines.get(name):
            out["machine"] = machines[name]
        out["metrics"] = {k: (v if _finite(v) else None) for k, v in sorted(metrics.items())}
        return out

    data = {
        "format": BASELINE_FORMAT,
        "manifest": manifest_name,
        "mfmap_version": __version__,
        "logs": {name: entry(name, m) for name, m in sorted(baseline.items())},
    }
    write_text_atomic(path, json.dumps(data, indent=2, sort_keys=False) + "\n")


def _finite(x: float | None) -> bool:
    return x is not None and math.isfinite(x)
