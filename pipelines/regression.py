"""CI regression over many logs: build and score each, compare with the baseline.

    python -m pipelines.regression MANIFEST [--ray [ADDRESS]] [--out DIR]
                                            [--update-baseline] [--workers N] [--config FILE]

Writes DIR/summary.md (one row per log, worst first), DIR/junit.xml and DIR/results.json, and
each log's build and eval.json under DIR/logs/<name>/. Exit codes: 0 every log passed (or its
baseline was updated), 1 a metric regressed beyond tolerance, a log has no baseline or a build
failed, 2 the manifest or the command line is wrong.

Examples:
    python -m pipelines.regression pipelines/manifests/sim_quick.yaml
    python -m pipelines.regression pipelines/manifests/sim_full.yaml --ray
    python -m pipelines.regression pipelines/manifests/sim_full.yaml --ray ray://head:10001
    python -m pipelines.regression pipelines/manifests/sim_quick.yaml --update-baseline
    python -m pipelines.regression pipelines/manifests/stress.yaml --config baro_only.yaml --out DIR

`--config FILE` lays an mfmap config over every log's (the manifest's and the log's own
overrides included), for an ablation over a whole set; such a run is compared with the baseline
but cannot update it.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from mfmap.config import merge_dicts, read_yaml_mapping
from mfmap.errors import MfmapError
from pipelines.regress.manifest import Manifest, ManifestError, load_manifest
from pipelines.regress.model import LogResult, Verdict
from pipelines.regress.report import markdown_summary
from pipelines.regress.runner import run_regression

EXIT_USAGE = 2
# `--ray` with no address: connect to RAY_ADDRESS if set, or start a local instance.
LOCAL_RAY = ""


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="python -m pipelines.regression",
        description="Rebuild and score every log of a manifest; fail on any regression.",
    )
    parser.add_argument("manifest", type=Path, help="regression manifest (YAML)")
    parser.add_argument(
        "--ray",
        nargs="?",
        const=LOCAL_RAY,
        default=None,
        metavar="ADDRESS",
        help="run each log as a Ray task (ADDRESS of a cluster; none: local instance)",
    )
    parser.add_argument(
        "--out", type=Path, default=None, help="output folder (default work/regression/<name>)"
    )
    parser.add_argument(
        "--update-baseline", action="store_true", help="rewrite the baseline with these results"
    )
    parser.add_argument(
        "--workers", type=int, default=None, help="local processes (default: fit CPUs and memory)"
    )
    parser.add_argument(
        "--config", type=Path, default=None, metavar="FILE",
        help="mfmap config laid over every log's (an ablation); cannot update the baseline",
    )
    args = parser.parse_args(argv)
    if args.config is not None and args.update_baseline:
        parser.error("--config runs are ablations: they cannot update the baseline")
    if args.workers is not None and args.workers < 1:
        parser.error("--workers must be at least 1")
    if args.workers is not None and args.ray is not None:
        parser.error("--workers applies to the local pool, not to --ray")
    return args


def lay_config(manifest: Manifest, path: Path) -> None:
    """`path`'s mfmap config laid over every log's, the log's own overrides included."""
    extra = read_yaml_mapping(path, ManifestError)
    manifest.config_overrides = merge_dicts(manifest.config_overrides, extra)
    for entry in manifest.logs:
        entry.config_overrides = merge_dicts(entry.config_overrides, extra)


def _progress(result: LogResult) -> None:
    bad = [c.metric for c in result.regressions]
    names = ", ".join(bad[:5]) + (f" and {len(bad) - 5} more" if len(bad) > 5 else "")
    if names and result.verdict is Verdict.UPDATED:
        names = "changes " + names
    detail = result.outcome.error if result.outcome.error else names
    line = f"{result.verdict.value:<11} {result.name} ({result.outcome.wall_s:.1f} s)"
    if result.regressions and result.other_machine:
        line += " [baseline made on another machine]"
    print(line + (f": {detail}" if detail else ""), file=sys.stderr, flush=True)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    try:
        manifest = load_manifest(args.manifest)
        if args.config is not None:
            lay_config(manifest, args.config)
        out = args.out if args.out is not None else Path("work") / "regression" / manifest.name
        run = run_regression(
            manifest,
            out,
            use_ray=args.ray is not None,
            ray_address=args.ray or None,
            workers=args.workers,
            update_baseline=args.update_baseline,
            on_result=_progress,
        )
    except MfmapError as err:
        print(f"regression: error: {err}", file=sys.stderr)
        return EXIT_USAGE
    sys.stdout.write(markdown_summary(run))
    print(f"reports: {out}/summary.md, junit.xml, results.json", file=sys.stderr)
    if args.update_baseline:
        print(f"baseline written: {manifest.baseline}", file=sys.stderr)
    return run.exit_code


if __name__ == "__main__":
    sys.exit(main())
