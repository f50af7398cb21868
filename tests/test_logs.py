"""Warnings through logging: the collector's prefixes, its order, and nothing printed twice."""

from __future__ import annotations

import logging

import pytest

from mfmap.logs import collect_warnings


class _Kept(logging.Handler):
    def __init__(self) -> None:
        super().__init__(level=logging.DEBUG)
        self.messages: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.messages.append(record.getMessage())


def test_each_line_is_prefixed_with_its_stage() -> None:
    with collect_warnings() as collected:
        logging.getLogger("mfmap.graph.optimize").warning("edge %d->%d refers to an unknown keyframe", 3, 4)
        logging.getLogger("mfmap.floors").warning("one floor")
        logging.getLogger("mfmap.ingest.core").warning("dropped 2")
        logging.getLogger("mfmap.mapping.chunks").warning("mapped")
        logging.getLogger("mfmap.export.write").warning("no grid")
        logging.getLogger("mfmap.localize.searching").warning("no fit")
        logging.getLogger("mfmap.pipeline").warning("threads")
        logging.getLogger("mfmap.runfolder").warning("replaced")
        logging.getLogger("mfmap.localize.mapfolder").warning("thin", extra={"stage": "map"})
        logging.getLogger("mfmap.pipeline").warning("no barometer", extra={"stage": ""})
        logging.getLogger("mfmap.graph").info("not a warning")
        logging.getLogger("elsewhere").warning("not mfmap's")
    assert collected.lines() == [
        "graph: edge 3->4 refers to an unknown keyframe", "floors: one floor", "ingest: dropped 2",
        "mapping: mapped", "export: no grid", "localize: no fit", "build: threads", "build: replaced",
        "map: thin", "no barometer",
    ]


def test_the_first_stages_lead_each_group_in_its_order() -> None:
    """A build's notes, then the log's warnings (known last), then the others as they arose."""
    with collect_warnings(first=("build", "ingest")) as collected:
        logging.getLogger("mfmap.pipeline").warning("note 1")
        logging.getLogger("mfmap.floors.pipeline").warning("f1")
        logging.getLogger("mfmap.graph").warning("g1")
        logging.getLogger("mfmap.floors").warning("f2")
        logging.getLogger("mfmap.pipeline").warning("bare", extra={"stage": ""})
        logging.getLogger("mfmap.ingest").warning("i1")
        logging.getLogger("mfmap.ingest").warning("i2")
        logging.getLogger("mfmap.export").warning("e1")
    assert collected.lines() == ["build: note 1", "ingest: i1", "ingest: i2", "floors: f1", "graph: g1",
                                 "floors: f2", "bare", "export: e1"]


def test_nested_collectors_each_get_every_record() -> None:
    with collect_warnings() as outer:
        logging.getLogger("mfmap.floors").warning("before")
        with collect_warnings() as inner:
            logging.getLogger("mfmap.graph").warning("inside")
        logging.getLogger("mfmap.export").warning("after")
    assert inner.lines() == ["graph: inside"]
    assert outer.lines() == ["floors: before", "graph: inside", "export: after"]


def test_nothing_collected_is_printed(capfd: pytest.CaptureFixture[str]) -> None:
    """Neither Python's last-resort handler nor a handler on the root logger shows a collected
    warning: the caller prints the report's warnings itself."""
    root, mfmap = logging.getLogger(), logging.getLogger("mfmap")
    kept = _Kept()
    root.addHandler(kept)
    try:
        with collect_warnings() as collected:
            logging.getLogger("mfmap.graph").warning("once")
        assert kept.messages == []
        with collect_warnings() as collected:  # and with no handler anywhere
            root.removeHandler(kept)
            logging.getLogger("mfmap.graph").warning("once")
    finally:
        root.removeHandler(kept)
    assert collected.lines() == ["graph: once"]
    out, err = capfd.readouterr()
    assert "once" not in out and "once" not in err
    assert mfmap.propagate and not mfmap.handlers  # as it was


def test_warnings_are_collected_whatever_the_loggers_level() -> None:
    mfmap = logging.getLogger("mfmap")
    mfmap.setLevel(logging.ERROR)
    try:
        with collect_warnings() as collected:
            logging.getLogger("mfmap.floors").warning("kept")
        assert mfmap.level == logging.ERROR
    finally:
        mfmap.setLevel(logging.NOTSET)
    assert collected.lines() == ["floors: kept"]
