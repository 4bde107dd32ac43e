"""The page as an operator uses it, in real headless Chromium against a real service: the next
step scrolled into view, the methods a model-less service cannot run shown disabled with the
reason, the memory's name and its map's identity in the header, the icon, a time scrubber over
the trajectory, a click on the map that runs the position tool there, and a panel of live frames.
Screenshots as in test_page.py ($RAVENMEM_SCREENSHOT_DIR; docs/img/page-*.png come from here)."""

from __future__ import annotations

import httpx
import pytest

from tests.agent.conftest import SCENE, T0
from tests.server.conftest import Served, make_memory, serve_memory
from tests.server.test_page import by_css, chromium, loaded_images, png, screenshot, wait_for


@pytest.fixture(scope="module")
def browser(tmp_path_factory):
    """One headless Chromium for the module (each test loads the page afresh)."""
    yield from chromium(tmp_path_factory.mktemp("chromium-profile"))


def open_page(d, served: Served, width: int = 1280, height: int = 760) -> None:
    d.set_window_size(width, height)
    d.get(served.url + "/")
    wait_for(d, lambda d: d.execute_script("return state.points.length") == len(SCENE), "the path")


def in_view(d, css: str) -> bool:
    return bool(
        d.execute_script(
            "const r = document.querySelector(arguments[0]).getBoundingClientRect();"
            "return r.height > 0 && r.top >= 0 && r.bottom <= window.innerHeight;",
            css,
        )
    )


def search(d, text: str, k: int = 8) -> None:
    q = by_css(d, "#q")[0]
    q.clear()
    q.send_keys(text)
    by_css(d, "#k")[0].clear()
    by_css(d, "#k")[0].send_keys(str(k))
    by_css(d, "#search-form button")[0].click()


def test_search_scrolls_to_the_ask_box_and_ask_to_the_answer(browser, served: Served, tmp_path) -> None:
    d = browser
    open_page(d, served, 1280, 700)
    assert not in_view(d, "#ask-form") or d.execute_script("return window.scrollY") == 0
    search(d, "red", 12)
    wait_for(d, lambda d: len(by_css(d, "#hits .card")) == 12, "12 hit cards")
    # twelve cards push the ask box below the fold of a 700 px window: the page brings it up
    wait_for(d, lambda d: in_view(d, "#ask-form"), "the ask box scrolled into view")
    assert d.execute_script("return window.scrollY") > 0
    assert by_css(d, "#question")[0].get_attribute("value") == "Where did I see red?"  # a start
    by_css(d, "#question")[0].clear()
    by_css(d, "#question")[0].send_keys("where is the yellow thing?")
    from selenium.webdriver.support.ui import Select

    Select(by_css(d, "#method")[0]).select_by_value("offline")
    by_css(d, "#ask-form button")[0].click()
    wait_for(d, lambda d: by_css(d, "#answer-text")[0].text, "the answer")
    wait_for(d, lambda d: in_view(d, "#answer-text"), "the answer scrolled into view")
    assert "x=2.00, y=0.00" in by_css(d, "#answer-text")[0].text
    screenshot(d, tmp_path, "page-scrolled-to-ask")


def test_methods_without_a_model_are_shown_disabled_with_the_reason(
    browser, served: Served, tmp_path
) -> None:
    d = browser
    open_page(d, served)
    options = d.execute_script(
        "return [...document.querySelectorAll('#method option')]"
        ".map(o => [o.value, o.disabled, o.textContent, o.title, o.selected])"
    )
    by_value = {o[0]: o for o in options}
    for m in ("raven", "vlm-only", "caption"):
        _, disabled, text, title, _ = by_value[m]
        assert disabled and text == f"{m} (needs a VLM)" and "--model and --base-url" in title, by_value[m]
    for m in ("offline", "embedder-only", "random"):
        assert not by_value[m][1] and by_value[m][2] == m
    assert by_value["offline"][4]  # the service's default is selected
    note = by_css(d, "#method-note")[0]
    assert note.is_displayed() and note.text.startswith("caption, raven, vlm-only: needs a VLM")


def test_methods_with_a_model_are_enabled(browser, tmp_path) -> None:
    from ravenmem.agent import VLMConfig

    vlm = VLMConfig(base_url="http://127.0.0.1:9/v1", model="m", api_key="k")
    for served in serve_memory(make_memory(tmp_path / "scene.mem"), vlm=vlm):
        d = browser
        open_page(d, served)
        disabled = d.execute_script("return [...document.querySelectorAll('#method option:disabled')].length")
        assert disabled == 0 and not by_css(d, "#method-note")[0].is_displayed()


def test_header_shows_the_name_and_the_map_identity_and_the_icon_is_served(
    browser, served: Served, tmp_path
) -> None:
    from ravenmem.nav.grid import MapConfig, OccupancyGrid

    served.mem.set_name("Lab, second floor")
    d = browser
    open_page(d, served)  # no occupancy map yet: the map identity alone
    wait_for(d, lambda d: by_css(d, "#map-id")[0].is_displayed(), "the map's identity")
    assert by_css(d, "#map-id")[0].text == "map memory:scene.mem (frame map), no occupancy map"
    grid = OccupancyGrid(MapConfig(resolution=0.5), origin=(-2.0, -3.0), shape=(20, 32))
    grid.known[:] = True
    grid.logodds[:] = -1.0
    grid.meta["env"] = "vizdoom:freedoom1/E1M2"
    grid.save(served.mem.path)
    open_page(d, served)
    assert by_css(d, "#memory-name")[0].text == "Lab, second floor"
    assert "scene.mem" in by_css(d, "#memory-name")[0].get_attribute("title")  # the folder, on hover
    wait_for(d, lambda d: by_css(d, "#map-id")[0].is_displayed(), "the map's identity")
    # the map identity (a memory that never named one is in `memory:<folder>`) and its frame
    assert by_css(d, "#map-id")[0].text == (
        "map memory:scene.mem (frame map): vizdoom:freedoom1/E1M2, explored, 0.5 m cells"
    )
    assert d.title == "Lab, second floor - ravenmem"
    icon = httpx.get(served.url + "/favicon.ico")
    assert icon.status_code == 200 and icon.headers["content-type"] == "image/svg+xml"
    assert icon.content.startswith(b"<svg")
    href = d.execute_script("return document.querySelector('link[rel=icon]').href")
    assert href == served.url + "/favicon.ico"
    loaded = d.execute_script(
        "return await new Promise(r => { const i = new Image(); i.onload = () => r(i.naturalWidth);"
        " i.onerror = () => r(0); i.src = '/favicon.ico'; })"
    )
    assert loaded > 0  # the browser draws it
    screenshot(d, tmp_path, "page-header")


def test_the_time_scrubber_shows_and_searches_the_memories_up_to_a_time(
    browser, served: Served, tmp_path
) -> None:
    from selenium.webdriver.common.action_chains import ActionChains

    d = browser
    open_page(d, served)
    assert by_css(d, "#until-label")[0].text.startswith(f"all {len(SCENE)} memories, to 2023-11-14T")
    slider = by_css(d, "#until")[0]
    width = slider.size["width"]
    ActionChains(d).move_to_element_with_offset(slider, int(-width * 0.1), 0).click().perform()  # 40 %
    wait_for(d, lambda d: d.execute_script("return state.until") is not None, "the scrubbed time")
    until = d.execute_script("return state.until")
    shown = sum(1 for i in range(len(SCENE)) if T0 + 10 * i <= until)
    assert 0 < shown < len(SCENE)
    assert d.execute_script("return visible().length") == shown
    assert by_css(d, "#until-label")[0].text.startswith(f"{shown} of {len(SCENE)} memories, up to ")
    # the robot's place at that time: the last memory before it
    now = by_css(d, "#map-marks .now-mark")[0]
    assert now.get_attribute("data-id") == str(shown)
    # a search looks only before that time
    search(d, "blue", 5)
    wait_for(d, lambda d: by_css(d, "#hits .card"), "hits")
    times = d.execute_script("return state.hits.map(h => h.t)")
    assert times and all(t <= until for t in times)
    assert "(up to 2023-" in by_css(d, "#hits-title")[0].text
    screenshot(d, tmp_path, "page-scrubber")
    # back to the end: everything again
    from selenium.webdriver.common.keys import Keys

    slider.send_keys(Keys.END)
    wait_for(d, lambda d: d.execute_script("return state.until") is None, "the scrubber at the end")
    assert not by_css(d, "#map-marks .now-mark")


def test_a_click_on_the_map_runs_the_position_tool_there(browser, served: Served, tmp_path) -> None:
    from selenium.webdriver.common.action_chains import ActionChains

    d = browser
    open_page(d, served)
    wrap = by_css(d, "#map-wrap")[0]
    x, y = SCENE[5][1], SCENE[5][2]  # memory 6 (cyan) at (5, 2)
    sx, sy = d.execute_script("return toScreen(arguments[0], arguments[1])", x, y)
    w, h = wrap.size["width"], wrap.size["height"]
    ActionChains(d).move_to_element_with_offset(wrap, int(sx - w / 2), int(sy - h / 2)).click().perform()
    wait_for(d, lambda d: "nearest x" in by_css(d, "#hits-title")[0].text, "the position tool's hits")
    hits = d.execute_script("return state.hits")
    assert hits[0]["id"] == 6 and hits[0]["distance"] < 0.2
    assert [h["distance"] for h in hits] == sorted(h["distance"] for h in hits)
    assert "m away" in by_css(d, "#hits .card")[0].text
    probe = d.execute_script("return state.probe")
    assert abs(probe["x"] - x) < 0.2 and abs(probe["y"] - y) < 0.2
    assert by_css(d, "#map-marks .probe-mark")
    screenshot(d, tmp_path, "page-position-click")
    # a drag pans, it does not search
    before = d.execute_script("return state.view.cx")
    ActionChains(d).move_to_element(wrap).click_and_hold().move_by_offset(60, 0).release().perform()
    assert d.execute_script("return state.view.cx") != before
    assert d.execute_script("return state.probe.x") == pytest.approx(probe["x"])


def test_live_frames_appear_in_their_panel(browser, served: Served, tmp_path) -> None:
    d = browser
    open_page(d, served)
    wait_for(d, lambda d: by_css(d, "#live.on"), "the event stream")
    assert by_css(d, "#frames-empty")[0].is_displayed() and not by_css(d, "#frames .card")
    ids = []
    for i, colour in enumerate(((0, 0, 255), (255, 0, 0))):
        r = httpx.post(
            served.url + "/memories",
            files={"image": ("f.png", png(colour), "image/png")},
            data={"x": str(13 + 5 * i), "y": "6", "t": str(T0 + 500 + 100 * i)},
        )
        assert r.status_code == 201, r.text
        ids.append(str(r.json()["id"]))
    wait_for(d, lambda d: len(by_css(d, "#frames .card")) == 2, "two live frames")
    wait_for(d, lambda d: loaded_images(d, "#frames .card img") == 2, "their pictures")
    cards = by_css(d, "#frames .card")
    assert [c.get_attribute("data-id") for c in cards] == ids[::-1]  # newest first
    assert f"live {ids[1]}" in cards[0].text and "x 18.00 y 6.00" in cards[0].text
    assert not by_css(d, "#frames-empty")[0].is_displayed()
    # the scrubber follows new memories while at the end
    assert by_css(d, "#until-label")[0].text.startswith(f"all {len(SCENE) + 2} memories")
    screenshot(d, tmp_path, "page-live-frames")


def test_a_search_nothing_supports_is_shown_as_not_found(browser, served: Served, tmp_path) -> None:
    """The verdict `ask` declines by, on the page: a banner and dimmed cards when no hit is
    supported, nothing of the kind when the thing is there; labels wrapped, never cut; and no
    request for /map on a memory without one (it could only answer 404)."""
    d = browser
    open_page(d, served, 1100, 760)
    search(d, "a smell of toast", 4)
    wait_for(d, lambda d: len(by_css(d, "#hits .card")) == 4, "4 hit cards")
    note = by_css(d, "#hits-note")[0]
    assert (
        note.is_displayed() and 'Not found: nothing in this memory supports "a smell of toast"' in note.text
    )
    assert len(by_css(d, "#hits .card.unsupported")) == 4 and "not found" in by_css(d, "#hits .card")[0].text
    screenshot(d, tmp_path, "page-not-found")
    search(d, "red", 4)
    wait_for(d, lambda d: not by_css(d, "#hits-note")[0].is_displayed(), "the banner to go")
    wait_for(d, lambda d: "score 1.000" in by_css(d, "#hits .card")[0].text, "the red hits")
    assert [c.get_attribute("class") for c in by_css(d, "#hits .card")[:2]] == ["card", "card"]
    cut = d.execute_script(
        "return [...document.querySelectorAll('#hits .card .meta')]"
        ".filter(m => m.scrollWidth > m.clientWidth + 1).map(m => m.textContent)"
    )
    assert cut == []  # every label's figures readable at this width
    asked = d.execute_script("return performance.getEntriesByType('resource').map(e => e.name)")
    assert not [u for u in asked if u.split("?")[0].endswith(("/map", "/map.png"))], asked
