"""report.html's 3D view in a real headless browser (Debian's Chromium, driven by playwright)."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

pytestmark = pytest.mark.slow
CHROMIUM = Path(os.environ.get("MFMAP_CHROMIUM", "/usr/bin/chromium"))
FLAGS = ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync"]
BACKGROUND = np.array([250, 250, 250])


@pytest.fixture(scope="module")
def page(sim_build: Callable[[str], tuple[Path, Path]], tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Any, list[str]]]:
    if not CHROMIUM.exists():
        pytest.fail(f"{CHROMIUM} is missing: `make setup` installs Debian's chromium for this test")
    from playwright.sync_api import sync_playwright

    _, out = sim_build("two-floor")
    profile = tmp_path_factory.mktemp("chromium-profile")
    with sync_playwright() as pw:
        context = pw.chromium.launch_persistent_context(
            str(profile), executable_path=str(CHROMIUM), headless=True, args=FLAGS,
            viewport={"width": 1200, "height": 900})
        try:
            tab = context.new_page()
            errors: list[str] = []
            tab.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
            tab.on("pageerror", lambda e: errors.append(str(e)))
            # Offline: any request leaving the page's own file is an error.
            tab.route("**/*", lambda route: route.continue_() if route.request.url.startswith("file:")
                      else (errors.append(f"request to {route.request.url}"), route.abort()))
            tab.goto((out / "report.html").as_uri())
            tab.wait_for_selector("canvas#mfmap-3d[data-ready='1']", timeout=60_000)
            yield tab, errors
        finally:
            context.close()


def _frames(tab: Any) -> int:
    return int(tab.locator("#mfmap-3d").get_attribute("data-frames"))


def _shot(tab: Any, after: int | None = None) -> np.ndarray:
    """The canvas once it has drawn a frame after frame `after` and has none due."""
    if after is not None:
        tab.wait_for_function(
            f"(c => Number(c.dataset.frames) > {after} && c.dataset.busy === '0')"
            "(document.getElementById('mfmap-3d'))", timeout=60_000)
    png = tab.locator("#mfmap-3d").screenshot()
    img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)[:, :, ::-1].astype(int)  # RGB
    return np.asarray(img[2:-2, 2:-2])  # without the canvas's border


def _shares(img: np.ndarray) -> dict[str, float]:
    """Shares of the canvas drawn at all, and in floor 0's blue and floor 1's orange."""
    r, g, b = img[..., 0], img[..., 1], img[..., 2]
    drawn = np.abs(img - BACKGROUND).sum(axis=-1) > 30
    n = float(drawn.size)
    return {"drawn": drawn.sum() / n,
            "blue": (drawn & (b > r + 60)).sum() / n,
            "orange": (drawn & (r > b + 60) & (g > 0.35 * r)).sum() / n}


def _spread_px(img: np.ndarray) -> float:
    """How far the drawn pixels spread over the canvas (their rms distance from their centre)."""
    rows, cols = np.nonzero(np.abs(img - BACKGROUND).sum(axis=-1) > 30)
    return float(np.sqrt(rows.var() + cols.var()))


def _toggle(tab: Any, name: str) -> int:
    """Click a toggle; the frame count before it (for `_shot`)."""
    before = _frames(tab)
    tab.locator(f"input[data-toggle='{name}']").click()
    return before


def test_report_page_is_small_and_offline(sim_build: Callable[[str], tuple[Path, Path]]) -> None:
    _, out = sim_build("two-floor")
    page_html = (out / "report.html").read_text()
    assert len(page_html.encode()) < 5_000_000
    assert "http://" not in page_html and "https://" not in page_html


def test_3d_view_draws_and_its_toggles_change_it(page: tuple[Any, list[str]]) -> None:
    tab, errors = page
    start = _shares(_shot(tab))
    assert start["drawn"] > 0.05 and start["blue"] > 0.01 and start["orange"] > 0.01, start
    _toggle(tab, "trajectory")
    _toggle(tab, "connectors")
    no_upper = _shares(_shot(tab, _toggle(tab, "L1")))
    assert no_upper["orange"] < 0.001 and no_upper["blue"] > 0.01, no_upper
    empty = _shares(_shot(tab, _toggle(tab, "L0")))
    assert empty["drawn"] < 0.002, empty
    only_upper = _shares(_shot(tab, _toggle(tab, "L1")))
    assert only_upper["orange"] > 0.01 and only_upper["blue"] < 0.001, only_upper
    assert errors == []


def test_3d_view_rotates_and_zooms(page: tuple[Any, list[str]]) -> None:
    tab, errors = page
    tab.reload()  # every toggle on again, the first view
    tab.wait_for_selector("canvas#mfmap-3d[data-ready='1']", timeout=60_000)
    box = tab.locator("#mfmap-3d").bounding_box()
    before = _shot(tab)
    n = _frames(tab)
    tab.mouse.move(box["x"] + 300, box["y"] + 300)
    tab.mouse.down()
    tab.mouse.move(box["x"] + 450, box["y"] + 340, steps=5)
    tab.mouse.up()
    rotated = _shot(tab, n)
    assert np.abs(rotated - before).sum(axis=-1).astype(bool).mean() > 0.02
    spread = _spread_px(rotated)
    tab.mouse.move(box["x"] + 500, box["y"] + 310)
    n = _frames(tab)
    tab.mouse.wheel(0, -600)  # zoom in (the view moves 0.55 times as far): the building grows
    assert _spread_px(_shot(tab, n)) > 1.3 * spread
    assert errors == []
