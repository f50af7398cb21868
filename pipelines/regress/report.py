"""The run's three outputs: a Markdown summary, JUnit XML for CI, and results.json."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

from mfmap.atomic import write_text_atomic
from pipelines.regress.model import CheckStatus, LogResult, RunResult, Verdict

# How many regressed metrics a summary row names before "and N more".
ROW_METRICS = 3


def sort_results(results: list[LogResult]) -> list[LogResult]:
    """Worst first: failed builds, then regressions by severity, then the rest by name."""
    return sorted(results, key=lambda r: (not r.verdict.failed, -r.severity, r.name))


def markdown_summary(run: RunResult) -> str:
    """One row per log, worst regressions first; the regressed metrics named in each row."""
    n_fail = len(run.failed)
    head = "PASS" if n_fail == 0 else f"FAIL ({n_fail} of {len(run.results)} logs)"
    lines = [
        f"# Regression `{run.manifest}`: {head}",
        "",
        f"{len(run.results)} logs on {run.backend} in {run.wall_s:.1f} s"
        + ("; baseline updated" if run.baseline_updated else ""),
        "",
        *_machine_note(run),
        "| log | verdict | worst regression | regressed | improved | metrics | build+eval s |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in sort_results(run.results):
        regressions = r.regressions
        if r.verdict is Verdict.ERROR:
            where = f"{r.outcome.stage} failed: " if r.outcome.stage else ""
            worst = _cell(where + (r.outcome.error or "unknown error"))
        elif regressions:
            worst = _cell("; ".join(c.describe() for c in regressions[:ROW_METRICS]))
            if len(regressions) > ROW_METRICS:
                worst += f" (and {len(regressions) - ROW_METRICS} more)"
        elif r.verdict is Verdict.NO_BASELINE:
            worst = "no baseline for this log: run with --update-baseline"
        else:
            worst = ""
        improved = sum(c.status is CheckStatus.IMPROVED for c in r.checks)
        lines.append(
            f"| {_cell(r.name)} | {r.verdict.value} | {worst} | {len(regressions)} | "
            f"{improved} | {len(r.outcome.metrics)} | {r.outcome.wall_s:.1f} |"
        )
    return "\n".join(lines) + "\n"


def _machine_note(run: RunResult) -> list[str]:
    """A paragraph when some baselines were made on another machine than this run's (not when
    the run rewrote them: they are this machine's now)."""
    results = run.results
    other = [r for r in results if r.other_machine]
    if not other or run.baseline_updated:
        return []
    made = sorted({r.baseline_machine for r in other if r.baseline_machine})
    if any(not r.baseline_machine for r in other):
        made.append("a machine the baseline does not record")
    here = sorted({r.outcome.machine for r in other})
    return [
        f"{len(other)} of {len(results)} logs have a baseline made on another machine "
        f"({' and '.join(made)}) than this run ({' and '.join(here)}). A build is bit-identical "
        "only on the same CPU and libraries: there its figures can move with no change to the "
        "code, by centimetres on chaotic logs (README, Limitations). Rebuild the baseline on "
        "this machine (--update-baseline) to compare code with code.",
        "",
    ]


def junit_xml(run: RunResult) -> str:
    """One testcase per log; a regression is a <failure> naming the metrics, a failed build an <error>."""
    suite = ET.Element(
        "testsuite",
        name=f"mfmap-regression.{run.manifest}",
        tests=str(len(run.results)),
        failures=str(sum(r.verdict in (Verdict.REGRESSED, Verdict.NO_BASELINE) for r in run.results)),
        errors=str(sum(r.verdict is Verdict.ERROR for r in run.results)),
        time=f"{run.wall_s:.3f}",
    )
    for r in sort_results(run.results):
        case = ET.SubElement(
            suite,
            "testcase",
            classname=f"regression.{run.manifest}",
            name=r.name,
            time=f"{r.outcome.wall_s:.3f}",
        )
        if r.verdict is Verdict.ERROR:
            el = ET.SubElement(
                case, "error", message=r.outcome.error or "unknown error", type=r.outcome.stage or "error"
            )
            el.text = r.outcome.error
        elif r.verdict is Verdict.REGRESSED:
            names = ", ".join(c.metric for c in r.regressions)
            el = ET.SubElement(case, "failure", message=f"regressed: {names}", type="regression")
            el.text = "\n".join(c.describe() for c in r.regressions)
        elif r.verdict is Verdict.NO_BASELINE:
            ET.SubElement(
                case, "failure", message="no baseline for this log (run --update-baseline)", type="baseline"
            )
        out = ET.SubElement(case, "system-out")
        out.text = "\n".join(
            f"{c.metric} = {c.value!r} (baseline {c.baseline!r}, {c.status.value})" for c in r.checks
        ) or "\n".join(f"{k} = {v!r}" for k, v in sorted(r.outcome.metrics.items()))
    suites = ET.Element("testsuites")
    suites.append(suite)
    ET.indent(suites)
    return ET.tostring(suites, encoding="unicode", xml_declaration=True) + "\n"


def results_json(run: RunResult) -> dict[str, Any]:
    """Everything the run found, for machines."""
    return {
        "manifest": run.manifest,
        "backend": run.backend,
        "wall_s": round(run.wall_s, 3),
        "exit_code": run.exit_code,
        "baseline_updated": run.baseline_updated,
        "failed": [r.name for r in sort_results(run.failed)],
        "logs": [r.to_json() for r in sort_results(run.results)],
    }


def write_reports(run: RunResult, out_dir: Path) -> dict[str, Path]:
    """summary.md, junit.xml and results.json in `out_dir`, each written atomically."""
    paths = {
        "summary": out_dir / "summary.md",
        "junit": out_dir / "junit.xml",
        "results": out_dir / "results.json",
    }
    write_text_atomic(paths["summary"], markdown_summary(run))
    write_text_atomic(paths["junit"], junit_xml(run))
    write_text_atomic(paths["results"], json.dumps(results_json(run), indent=2) + "\n")
    return paths


def _cell(text: str) -> str:
    # A pipe or newline would break the Markdown table row.
    return " ".join(text.split()).replace("|", "\\|")
