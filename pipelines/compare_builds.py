"""Are two regression runs' builds the same bytes? For a change meant to alter no output.

    python -m pipelines.compare_builds BEFORE AFTER

BEFORE and AFTER are `python -m pipelines.regression MANIFEST --out DIR` folders of the same
manifest, built by two versions of the code on one machine. Every file of every log's build
must be byte-identical, except what records the run rather than the map:
- report.json: compared without its timings, peak memory and input paths (RUN_RECORDS);
- report.html: compared with every number masked (it shows the same timings);
- config.yaml: not compared (the user's configuration, written in the keys of the version that
  built; a change of the configuration's layout changes it and nothing else).
Prints each file that differs and exits 1 if any does.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import re
import sys
from pathlib import Path
from typing import Any

# What a report (a build's or a localisation's) records of the run rather than of the map: left
# out wherever it appears in the report.
RUN_RECORDS = {"timings_s", "cpu_timings_s", "log", "map", "build_s", "elapsed_s", "cpu_s",
               "realtime_factor", "cpu_realtime_factor", "peak_rss_mb", "scans_per_s", "seconds"}
NOT_BUILDS = {"eval.json", "summary.md", "junit.xml", "results.json"}


def _without_run_records(doc: Any) -> Any:
    if isinstance(doc, dict):
        return {k: _without_run_records(v) for k, v in doc.items() if k not in RUN_RECORDS}
    if isinstance(doc, list):
        return [_without_run_records(v) for v in doc]
    return doc


def _report(path: Path) -> Any:
    return _without_run_records(json.loads(path.read_text(encoding="utf-8")))


def _masked(path: Path) -> str:
    return re.sub(r"\d+(\.\d+)?", "#", path.read_text(encoding="utf-8"))


def same(a: Path, b: Path) -> bool:
    """Whether two files of a build hold the same map (see the module docstring)."""
    if a.name == "report.json":
        return bool(_report(a) == _report(b))
    if a.name == "report.html":
        return _masked(a) == _masked(b)
    return hashlib.sha256(a.read_bytes()).digest() == hashlib.sha256(b.read_bytes()).digest()


def compare(before: Path, after: Path) -> list[str]:
    """One line per file that differs, is missing after or is new after."""
    problems: list[str] = []
    files = sorted(p for p in before.rglob("*") if p.is_file())
    for a in files:
        rel = a.relative_to(before)
        if rel.name in NOT_BUILDS or rel.suffix == ".log" or rel.name == "config.yaml":
            continue
        b = after / rel
        if not b.exists():
            problems.append(f"missing after: {rel}")
        elif not same(a, b):
            problems.append(f"differs: {rel}")
    problems += [f"only after: {p.relative_to(after)}" for p in sorted(after.rglob("*"))
                 if p.is_file() and not (before / p.relative_to(after)).exists()]
    return problems


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m pipelines.compare_builds",
                                     description="Compare two regression runs' builds file by file.")
    parser.add_argument("before", type=Path)
    parser.add_argument("after", type=Path)
    args = parser.parse_args(argv)
    problems = compare(args.before, args.after)
    for line in problems:
        print(line)
    checked = sum(1 for p in args.before.rglob("*") if p.is_file())
    print(f"{len(problems)} of {checked} files differ" if problems else
          f"identical: every build file of {args.before} and {args.after}")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
