"""Plain records the regression pipeline passes around (picklable, for workers and Ray)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import Enum
from typing import Any


class Verdict(str, Enum):
    """What a log's row says; every verdict but PASS, NEW and UPDATED fails the run."""

    ERROR = "error"  # build or eval failed
    REGRESSED = "regressed"  # a metric worse than the baseline beyond tolerance
    NO_BASELINE = "no-baseline"  # nothing to compare with (run --update-baseline)
    PASS = "pass"
    UPDATED = "updated"  # --update-baseline wrote this log's metrics

    @property
    def failed(self) -> bool:
        return self in (Verdict.ERROR, Verdict.REGRESSED, Verdict.NO_BASELINE)


class CheckStatus(str, Enum):
    OK = "ok"
    IMPROVED = "improved"
    REGRESSED = "regressed"
    MISSING = "missing"  # in the baseline, absent or NaN now: counted as a regression
    NEW = "new"  # not in the baseline: reported, not compared


@dataclass(frozen=True)
class LogJob:
    """Everything one worker needs to build and score one log (plain values only)."""

    name: str
    out_dir: str
    config: dict[str, Any]  # the resolved MfmapConfig as a dict
    log: str | None = None
    simulate: dict[str, Any] | None = None  # Simulate fields
    sim_cache: str | None = None
    ground_truth: dict[str, str | None] = field(default_factory=dict)
    skip_ground_truth: tuple[str, ...] = ()
    localize: dict[str, Any] | None = None  # Localize fields: localise in a map, not build
    build_with: tuple[dict[str, Any], ...] = ()  # Simulate fields of logs built with this one
    num_cpus: float = 1.0
    memory_gb: float = 2.0


@dataclass(frozen=True)
class LogOutcome:
    """What building and scoring one log produced."""

    name: str
    ok: bool
    metrics: dict[str, float]
    wall_s: float
    out_dir: str
    log: str | None = None
    error: str | None = None  # one line, when not ok
    stage: str | None = None  # which step failed: simulate, build, eval
    machine: str = ""  # where it ran (`machine.machine_fingerprint`)


@dataclass(frozen=True)
class MetricCheck:
    """One metric compared with its baseline."""

    metric: str
    baseline: float | None
    value: float | None
    higher_better: bool
    allowed: float
    status: CheckStatus

    @property
    def worsening(self) -> float | None:
        """How much worse than the baseline (negative when better), in the metric's unit."""
        if not _finite(self.baseline) or not _finite(self.value):
            return None
        assert self.baseline is not None and self.value is not None
        delta = self.value - self.baseline
        return -delta if self.higher_better else delta

    @property
    def severity(self) -> float:
        """Worsening relative to the baseline's size; orders the rows, worst first."""
        if self.status is CheckStatus.MISSING:
            return math.inf
        worse = self.worsening
        if worse is None or self.baseline is None:
            return 0.0
        return worse / (abs(self.baseline) + self.allowed + 1e-12)

    def describe(self) -> str:
        """One line for the summary and JUnit: `points.rmse_m 0.031 -> 0.412 (+0.381 > 0.005)`."""
        if self.status is CheckStatus.MISSING:
            return f"{self.metric} {_fmt(self.baseline)} -> missing"
        worse = self.worsening
        sign = "+" if worse is not None and worse >= 0 else ""
        rel = ">" if self.status is CheckStatus.REGRESSED else "<="
        direction = "higher is better" if self.higher_better else "lower is better"
        return (
            f"{self.metric} {_fmt(self.baseline)} -> {_fmt(self.value)} "
            f"(worse by {sign}{_fmt(worse)} {rel} allowed {_fmt(self.allowed)}; {direction})"
        )

    def to_json(self) -> dict[str, Any]:
        return {
            "metric": self.metric,
            "baseline": _json_num(self.baseline),
            "value": _json_num(self.value),
            "worsening": _json_num(self.worsening),
            "allowed": self.allowed,
            "higher_better": self.higher_better,
            "status": self.status.value,
        }


@dataclass(frozen=True)
class LogResult:
    """One row of the summary: the outcome, its checks and the verdict."""

    outcome: LogOutcome
    checks: list[MetricCheck]
    verdict: Verdict
    baseline_machine: str | None = None  # where the baseline was made, if it says

    @property
    def other_machine(self) -> bool:
        """The baseline was made on another machine (or does not say where): figures can
        differ with no change to the code."""
        return bool(self.checks) and self.baseline_machine != self.outcome.machine

    @property
    def name(self) -> str:
        return self.outcome.name

    @property
    def regressions(self) -> list[MetricCheck]:
        bad = (CheckStatus.REGRESSED, CheckStatus.MISSING)
        found = [c for c in self.checks if c.status in bad]
        return sorted(found, key=lambda c: (-c.severity, c.metric))

    @property
    def severity(self) -> float:
        """Orders the rows: errors, then the worst regression, then the rest."""
        if self.verdict is Verdict.ERROR:
            return math.inf
        return max((c.severity for c in self.checks), default=0.0)

    def to_json(self) -> dict[str, Any]:
        o = self.outcome
        return {
            "name": o.name,
            "verdict": self.verdict.value,
            "log": o.log,
            "out_dir": o.out_dir,
            "wall_s": round(o.wall_s, 3),
            "error": o.error,
            "failed_stage": o.stage,
            "machine": o.machine,
            "baseline_machine": self.baseline_machine,
            "regressed_metrics": [c.metric for c in self.regressions],
            "metrics": {k: _json_num(v) for k, v in sorted(o.metrics.items())},
            "checks": [c.to_json() for c in self.checks],
        }


def _finite(x: float | None) -> bool:
    return x is not None and math.isfinite(x)


def _json_num(x: float | None) -> float | None:
    # JSON has no NaN; null says "no value" to every reader.
    return x if _finite(x) else None


def _fmt(x: float | None) -> str:
    if x is None or not math.isfinite(x):
        return "nan"
    return f"{x:.4g}"


@dataclass(frozen=True)
class RunResult:
    """A whole regression run: every log's row (worst first) and how it ran."""

    manifest: str
    backend: str  # "local[N]" or "ray[ADDRESS]"
    wall_s: float
    results: list[LogResult]
    baseline_updated: bool = False

    @property
    def failed(self) -> list[LogResult]:
        return [r for r in self.results if r.verdict.failed]

    @property
    def exit_code(self) -> int:
        """0 when every log passed (or its baseline was updated), 1 otherwise."""
        return 1 if self.failed else 0
