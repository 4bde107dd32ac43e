"""The page in a real browser (Debian's headless Chromium through Selenium) against a real service.

Skipped with a reason when Chromium or chromedriver is missing, unless RAVENMEM_REQUIRE_BROWSER=1
(CI sets it), where a missing browser fails. Screenshots go to $RAVENMEM_SCREENSHOT_DIR when set
(else the test's tmp folder); their paths are printed (`pytest -s` shows them).
"""

from __future__ import annotations

import io
import os
import shutil
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
from PIL import Image

from tests.agent.conftest import SCENE, T0
from tests.server.conftest import TOKEN, Served

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
DRIVER = shutil.which("chromedriver") or "/usr/bin/chromedriver"
WAIT = 30


def _require_browser() -> None:
    missing = [p for p in (CHROMIUM, DRIVER) if not Path(p).exists()]
    if not missing:
        return
    msg = f"headless Chromium is not installed ({', '.join(missing)} missing): apt-get install chromium chromium-driver"
    if os.environ.get("RAVENMEM_REQUIRE_BROWSER") == "1":
        pytest.fail(msg)
    pytest.skip(msg)


@pytest.fixture
def browser(tmp_path) -> Iterator[object]:
    yield from chromium(tmp_path / "chromium-profile")


def chromium(profile: Path) -> Iterator[object]:
    """Headless Chromium through chromedriver, its profile in `profile`; quit at the end."""
    _require_browser()
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service as DriverService

    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM
    for arg in (
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-dev-shm-usage",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--no-first-run",
        f"--user-data-dir={profile}",
        "--window-size=1400,900",
    ):
        opts.add_argument(arg)
    driver = webdriver.Chrome(service=DriverService(DRIVER), options=opts)
    driver.set_page_load_timeout(WAIT)
    try:
        yield driver
    finally:
        driver.quit()


def wait_for(driver, condition, what: str):
    from selenium.webdriver.support.ui import WebDriverWait

    try:
        return WebDriverWait(driver, WAIT, poll_frequency=0.1).until(lambda d: condition(d))
    except Exception as e:
        logs = driver.execute_script("return document.getElementById('status').textContent")
        raise AssertionError(f"timed out waiting for {what} (page status: {logs!r})") from e


def screenshot(driver, tmp_path: Path, name: str) -> Path:
    folder = Path(os.environ.get("RAVENMEM_SCREENSHOT_DIR") or tmp_path)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{name}.png"
    driver.save_screenshot(str(path))
    print(f"screenshot: {path}")
    return path


def by_css(driver, css: str) -> list:
    from selenium.webdriver.common.by import By

    return driver.find_elements(By.CSS_SELECTOR, css)


def loaded_images(driver, css: str) -> int:
    return int(
        driver.execute_script(
            "return [...document.querySelectorAll(arguments[0])]"
            ".filter(i => i.src.startsWith('blob:') && i.complete && i.naturalWidth > 0).length",
            css,
        )
    )


def png(color: tuple[int, int, int]) -> bytes:
    buf = io.BytesIO()
    Image.new("RGB", (32, 24), color).save(buf, "PNG")
    return buf.getvalue()


def test_page_search_ask_and_live_updates(browser, served: Served, tmp_path):
    d = browser
    d.get(served.url + "/")
    wait_for(d, lambda d: d.execute_script("return state.points.length") == len(SCENE), "the path")
    assert by_css(d, "#count")[0].text == str(len(SCENE))
    assert by_css(d, "#memory-name")[0].text == "scene.mem"
    assert not by_css(d, "#token-box")[0].is_displayed()  # loopback: no token asked for
    wait_for(d, lambda d: by_css(d, "#live.on"), "the event stream to open")
    # the canvas has the path drawn on it (not a blank canvas)
    inked = d.execute_script(
        "const c = document.getElementById('map-canvas'); const a = c.getContext('2d')"
        ".getImageData(0, 0, c.width, c.height).data; let n = 0;"
        "for (let i = 3; i < a.length; i += 4) if (a[i] > 0) n++; return n;"
    )
    assert inked > 500

    # search: thumbnails with score, time and pose, and numbered marks on the map
    q = by_css(d, "#q")[0]
    q.clear()
    q.send_keys("red")
    by_css(d, "#k")[0].clear()
    by_css(d, "#k")[0].send_keys("4")
    by_css(d, "#search-form button")[0].click()
    wait_for(d, lambda d: len(by_css(d, "#hits .card")) == 4, "4 hit cards")
    wait_for(d, lambda d: loaded_images(d, "#hits .card img") == 4, "4 hit thumbnails")
    cards = by_css(d, "#hits .card")
    assert {c.get_attribute("data-id") for c in cards[:2]} == {"2", "9"}  # the red memories first
    first = cards[0].text
    assert "#1 score 1.000" in first and "2023-11-14T22:1" in first and "x " in first and "yaw" in first
    marks = by_css(d, "#map-marks .hit-mark")
    assert len(marks) == 4 and {m.get_attribute("data-id") for m in marks[:2]} == {"2", "9"}
    # each mark sits where the map draws its memory
    for m in marks:
        hit = d.execute_script(
            "return state.hits.find(h => String(h.id) === arguments[0])", m.get_attribute("data-id")
        )
        sx, sy = d.execute_script("return toScreen(arguments[0], arguments[1])", hit["x"], hit["y"])
        circle = m.find_element("css selector", "circle")
        assert (
            abs(float(circle.get_attribute("cx")) - sx) < 0.5
            and abs(float(circle.get_attribute("cy")) - sy) < 0.5
        )
    screenshot(d, tmp_path, "page-search")

    # ask (offline): the answer, its evidence pictures, and its position and heading on the map
    from selenium.webdriver.support.ui import Select

    Select(by_css(d, "#method")[0]).select_by_value("offline")
    by_css(d, "#question")[0].send_keys("where is the yellow thing?")
    by_css(d, "#ask-form button")[0].click()
    wait_for(d, lambda d: by_css(d, "#map-marks .answer-mark"), "the answer mark")
    assert "x=2.00, y=0.00" in by_css(d, "#answer-text")[0].text
    assert "position question" in by_css(d, "#answer-facts")[0].text
    wait_for(d, lambda d: loaded_images(d, "#evidence .card img") >= 1, "an evidence picture")
    assert by_css(d, "#evidence .card")[0].get_attribute("data-id") == "3"
    sx, sy = d.execute_script("return toScreen(2, 0)")
    mark = by_css(d, "#map-marks .answer-mark circle")[0]
    assert abs(float(mark.get_attribute("cx")) - sx) < 0.5 and abs(float(mark.get_attribute("cy")) - sy) < 0.5
    arrow = by_css(d, "#map-marks .answer-mark line")[0]  # heading 0.2 rad: right and slightly up
    dx = float(arrow.get_attribute("x2")) - float(arrow.get_attribute("x1"))
    dy = float(arrow.get_attribute("y2")) - float(arrow.get_attribute("y1"))
    assert dx > 20 and -6 < dy < -3
    screenshot(d, tmp_path, "page-answer")

    # a frame added over HTTP appears on the page while it is open
    r = httpx.post(
        served.url + "/memories",
        files={"image": ("f.png", png((0, 0, 255)), "image/png")},
        data={"x": "13", "y": "6", "t": str(T0 + 500)},
    )
    assert r.status_code == 201
    new_id = r.json()["id"]
    wait_for(d, lambda d: by_css(d, "#count")[0].text == str(len(SCENE) + 1), "the live count")
    wait_for(d, lambda d: by_css(d, f"#map-marks .live-mark[data-id='{new_id}']"), "the new memory's mark")
    assert f"memory {new_id} at x 13.00 y 6.00" in by_css(d, "#log li")[0].text
    assert d.execute_script("return state.points[state.points.length - 1][0]") == new_id
    screenshot(d, tmp_path, "page-live")


def test_page_with_a_token_in_the_url_fragment(browser, served_token: Served, tmp_path):
    d = browser
    d.get(served_token.url + "/")  # no token: the page asks for one
    wait_for(d, lambda d: by_css(d, "#token-box")[0].is_displayed(), "the token box")
    d.get(served_token.url + f"/#token={TOKEN}")
    d.refresh()
    wait_for(d, lambda d: by_css(d, "#count")[0].text == str(len(SCENE)), "the memory count")
    assert "token" not in d.current_url  # the fragment is dropped once read
    by_css(d, "#q")[0].send_keys("blue")
    by_css(d, "#search-form button")[0].click()
    wait_for(d, lambda d: loaded_images(d, "#hits .card img") >= 3, "thumbnails fetched with the token")
    assert len(by_css(d, "#map-marks .hit-mark")) >= 3


def test_page_draws_the_occupancy_map_under_the_path(browser, served: Served, tmp_path):
    from ravenmem.nav.grid import MapConfig, OccupancyGrid

    grid = OccupancyGrid(MapConfig(resolution=0.25), origin=(-2.0, -3.0), shape=(40, 64))
    grid.known[:] = True
    grid.logodds[:] = -1.0
    r, c = grid.world_to_cell(6.0, -1.5)
    grid.logodds[r - 2 : r + 3, c - 2 : c + 3] = 2.0  # a block of wall around (6, -1.5)
    grid.save(served.mem.path)
    d = browser
    d.get(served.url + "/")
    wait_for(
        d, lambda d: d.execute_script("return !!(state.map && state.map.img.naturalWidth)"), "the map picture"
    )
    d.execute_script("draw()")

    def pixel(x: float, y: float) -> list[int]:
        return d.execute_script(
            "const [sx, sy] = toScreen(arguments[0], arguments[1]); const c = document.getElementById('map-canvas');"
            "const k = window.devicePixelRatio || 1;"
            "return [...c.getContext('2d').getImageData(Math.round(sx * k), Math.round(sy * k), 1, 1).data];",
            x,
            y,
        )

    wall, floor = pixel(6.3, -1.3), pixel(6.3, 2.3)  # off the metre grid lines
    assert sum(wall[:3]) < 200 and wall[3] > 0, wall  # dark where the wall is
    assert sum(floor[:3]) > 600, floor  # light on free floor away from the path
    screenshot(d, tmp_path, "page-map")
