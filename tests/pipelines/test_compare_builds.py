"""compare_builds: the same map with other timings is identical; one changed byte is not."""

from __future__ import annotations

import json
from pathlib import Path

from pipelines.compare_builds import compare


def _build(root: Path, build_s: float, cloud: bytes) -> None:
    folder = root / "logs" / "tiny" / "build"
    folder.mkdir(parents=True)
    report = {"log": str(root / "log.mcap"), "summary": {"floors": 2, "build_s": build_s},
              "timings_s": {"total": build_s}, "mapping": {"elapsed_s": build_s, "keyframes": 35},
              "graph": {"seconds": build_s, "iterations": 4}}
    (folder / "report.json").write_text(json.dumps(report))
    (folder / "report.html").write_text(f"<td>{build_s} s</td>")
    (folder / "config.yaml").write_text(f"# {build_s}\n")
    (folder / "map.ply").write_bytes(cloud)
    (root / "logs" / "tiny" / "eval.json").write_text(json.dumps({"seconds": build_s}))


def test_timings_differ_map_the_same(tmp_path: Path) -> None:
    _build(tmp_path / "a", 11.1, b"ply 1 2 3")
    _build(tmp_path / "b", 6.4, b"ply 1 2 3")
    assert compare(tmp_path / "a", tmp_path / "b") == []


def test_one_byte_of_the_map_differs(tmp_path: Path) -> None:
    _build(tmp_path / "a", 11.1, b"ply 1 2 3")
    _build(tmp_path / "b", 11.1, b"ply 1 2 4")
    (tmp_path / "b" / "logs" / "tiny" / "build" / "floors.json").write_text("{}")
    assert compare(tmp_path / "a", tmp_path / "b") == [
        "differs: logs/tiny/build/map.ply", "only after: logs/tiny/build/floors.json"]


def test_a_counted_figure_in_the_report_differs(tmp_path: Path) -> None:
    _build(tmp_path / "a", 11.1, b"ply")
    _build(tmp_path / "b", 11.1, b"ply")
    path = tmp_path / "b" / "logs" / "tiny" / "build" / "report.json"
    doc = json.loads(path.read_text())
    doc["mapping"]["keyframes"] = 36
    path.write_text(json.dumps(doc))
    assert compare(tmp_path / "a", tmp_path / "b") == ["differs: logs/tiny/build/report.json"]
