"""Screenshots of the service's page on a real memory, for docs/img/ (what a person sees).

    ravenmem demo --maps vizdoom:freedoom1/E1M2 --out /tmp/demo
    python scripts/page_screenshots.py /tmp/demo/freedoom1_E1M2/memory docs/img

Serves a copy of the memory (live adds write to it) on 127.0.0.1 and drives Debian's headless
Chromium (Selenium) through a search, an offline question, the time scrubber, a click on the map
and three live frames (the memory's own first pictures, added again at new times). The page's
behaviour is tested in tests/server/test_page*.py; this only takes pictures.
"""

from __future__ import annotations

import argparse
import io
import shutil
import socket
import sys
import tempfile
import threading
import time
from pathlib import Path

import httpx


def serve(path: Path) -> tuple[str, object]:
    import uvicorn

    import ravenmem
    from ravenmem.runtime.service import Service, ServiceConfig
    from ravenmem.server.app import create_app
    from ravenmem.server.run import make_server

    mem = ravenmem.open(path, writable=True)
    service = Service(mem, ServiceConfig())
    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    server = make_server(uvicorn.Config(create_app(service), log_level="warning"), service)
    threading.Thread(target=server.run, kwargs={"sockets": [sock]}, daemon=True).start()
    while not server.started:
        time.sleep(0.05)
    return f"http://127.0.0.1:{sock.getsockname()[1]}", server


def browser(profile: Path):
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service as DriverService

    opts = webdriver.ChromeOptions()
    opts.binary_location = shutil.which("chromium") or "/usr/bin/chromium"
    for arg in (
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-dev-shm-usage",
        "--window-size=1400,900",
    ):
        opts.add_argument(arg)
    opts.add_argument(f"--user-data-dir={profile}")
    return webdriver.Chrome(
        service=DriverService(shutil.which("chromedriver") or "/usr/bin/chromedriver"), options=opts
    )


def until(d, js: str, timeout: float = 60.0) -> None:
    end = time.monotonic() + timeout
    while not d.execute_script(js):
        if time.monotonic() > end:
            raise SystemExit(f"timed out waiting for: {js}")
        time.sleep(0.1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("memory", type=Path)
    ap.add_argument("out", type=Path, nargs="?", default=Path("docs/img"))
    ap.add_argument("--search", default="an explosive barrel")
    ap.add_argument("--ask", default="Where did I see the floor lamp?")
    a = ap.parse_args()
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.by import By

    a.out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        copy = Path(tmp) / a.memory.name
        shutil.copytree(a.memory, copy, ignore=shutil.ignore_patterns("writer.lock"))
        url, server = serve(copy)
        d = browser(Path(tmp) / "profile")
        try:

            def shot(name: str) -> None:  # JPEG, quality 85: a fifth of the PNG's size
                from PIL import Image

                png = Path(tmp) / f"{name}.png"
                d.save_screenshot(str(png))
                Image.open(png).convert("RGB").save(a.out / f"{name}.jpg", quality=85, optimize=True)
                print(a.out / f"{name}.jpg")

            d.get(url + "/")
            until(d, "return state.points.length > 0 && state.map && state.map.img.naturalWidth > 0")
            d.find_element(By.ID, "q").send_keys(a.search)
            d.find_element(By.CSS_SELECTOR, "#search-form button").click()
            until(
                d,
                "return [...document.querySelectorAll('#hits img')].filter(i => i.naturalWidth).length >= 6",
            )
            d.find_element(By.ID, "question").clear()
            d.find_element(By.ID, "question").send_keys(a.ask)
            d.find_element(By.CSS_SELECTOR, "#ask-form button").click()
            until(d, "return document.getElementById('answer-text').textContent.length > 0")
            time.sleep(0.5)
            shot("page-search-ask")
            d.execute_script("window.scrollTo(0, 0)")
            slider = d.find_element(By.ID, "until")
            ActionChains(d).move_to_element_with_offset(
                slider, -slider.size["width"] // 5, 0
            ).click().perform()
            until(d, "return state.until !== null")
            shot("page-scrubber")
            slider.send_keys("\ue010")  # End: all memories again
            pts = d.execute_script("return state.points")
            mid = pts[len(pts) // 3]
            sx, sy = d.execute_script("return toScreen(arguments[0], arguments[1])", mid[2], mid[3])
            wrap = d.find_element(By.ID, "map-wrap")
            w, h = wrap.size["width"], wrap.size["height"]
            ActionChains(d).move_to_element_with_offset(
                wrap, int(sx - w / 2), int(sy - h / 2)
            ).click().perform()
            until(d, "return document.getElementById('hits-title').textContent.startsWith('nearest')")
            until(
                d,
                "return [...document.querySelectorAll('#hits img')].filter(i => i.naturalWidth).length >= 4",
            )
            d.execute_script("window.scrollTo(0, 0)")
            shot("page-position-click")
            for i, p in enumerate(pts[:3]):
                pic = httpx.get(f"{url}/memories/{p[0]}/image").content
                httpx.post(
                    url + "/memories",
                    files={"image": ("f.jpg", io.BytesIO(pic), "image/jpeg")},
                    data={
                        "x": str(p[2] + 0.5),
                        "y": str(p[3] + 0.5),
                        "yaw": str(p[4]),
                        "t": str(pts[-1][1] + 10 * (i + 1)),
                    },
                    timeout=60,
                )
            until(d, "return document.querySelectorAll('#frames .card').length >= 1")
            time.sleep(1.0)
            d.execute_script("document.getElementById('frames').scrollIntoView({block: 'center'})")
            shot("page-live-frames")
        finally:
            d.quit()
            server.should_exit = True
    sys.exit(0)


if __name__ == "__main__":
    main()
