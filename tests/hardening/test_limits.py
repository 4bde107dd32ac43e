"""Bounds on what one request may cost, over real HTTP: a body that trickles in is cut off, the
pictures decoded at once are bounded, and a full disk is one line (507) while reads go on and
the service still shuts down cleanly. And every file a user names is read bounded."""

from __future__ import annotations

import gc
import os
import resource
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from pathlib import Path

import httpx
import numpy as np
import pytest

pytest.importorskip("fastapi", reason="the service needs the serve extra: pip install 'ravenmem[serve]'")

import ravenmem  # noqa: E402
from ravenmem.errors import InputError  # noqa: E402
from ravenmem.fsio import read_bounded  # noqa: E402
from ravenmem.types import Pose  # noqa: E402
from tests.conftest import ColorEmbedder, solid  # noqa: E402
from tests.hardening.conftest import one_line_error  # noqa: E402
from tests.hardening.runner import Driver, hostile_files, png_bytes  # noqa: E402
from tests.server.conftest import REPO, make_memory, serve_memory, serve_subprocess, stop  # noqa: E402

T0 = 1_700_000_000.0


# ---------------------------------------------------------------- a body must arrive in time
def test_a_body_sent_a_byte_a_second_is_cut_off(tmp_path):
    make_memory(tmp_path / "m.mem").close()
    proc, url = serve_subprocess(tmp_path / "m.mem", "--body-timeout", "2")
    try:
        host, port = url.removeprefix("http://").split(":")
        with socket.create_connection((host, int(port)), timeout=60) as s:
            s.sendall(
                f"POST /ask HTTP/1.1\r\nHost: {host}:{port}\r\n"
                "Content-Type: application/json\r\nContent-Length: 100000\r\n\r\n".encode()
            )
            s.settimeout(1.0)
            reply, sent = b"", 0
            while sent < 60 and b"\r\n\r\n" not in reply:  # a slow client: one byte a second
                try:
                    s.sendall(b" ")  # blanks before the JSON: a valid body, if it ever ended
                    sent += 1
                    reply += s.recv(65536)
                except TimeoutError:
                    continue
                except (BrokenPipeError, ConnectionResetError):
                    break
            s.settimeout(30.0)  # the headers may come in one packet and the body in the next
            try:
                while b"did not arrive" not in reply and (chunk := s.recv(65536)):
                    reply += chunk
            except OSError:
                pass
        assert reply.startswith(b"HTTP/1.1 408"), reply[:200]
        assert b"did not arrive within 2 s" in reply
        assert sent < 60  # cut off long before the client was done
        assert httpx.get(url + "/health", timeout=30).status_code == 200  # and it still serves
    finally:
        stop(proc)


# ---------------------------------------------------------------- pictures decoded at once
def test_pictures_decoded_at_once_are_bounded_413_and_503(tmp_path):
    mem = make_memory(tmp_path / "m.mem")
    for served in serve_memory(mem, decode_budget=4 << 20):
        gate = served.service.gate
        gate.wait = 0.2
        big = png_bytes(np.zeros((600, 600, 3), np.uint8))  # 0.36 MP: 5.8 MB to decode and embed
        small = png_bytes(solid("red"))
        with served.client() as c:
            r = c.post("/search/image", files={"image": ("big.png", big, "image/png")})
            assert (
                r.status_code == 413
                and "more memory than this service gives one picture" in r.json()["error"]
            )
            held = gate.admit(gate.budget // 16, 1, "other uploads")  # all of it, decoded elsewhere
            try:
                r = c.post("/search/image", files={"image": ("s.png", small, "image/png")})
                assert r.status_code == 503 and r.headers["retry-after"] == "1", r.text
                assert "decoding other large pictures" in r.json()["error"]
            finally:
                gate.release(held)
            r = c.post("/search/image", files={"image": ("s.png", small, "image/png")})
            assert r.status_code == 200 and r.json()["results"]
        # every picture's share is given back when its array is freed, which may be just after
        # the reply was sent (the worker thread drops it): wait for that, do not race it
        deadline = time.monotonic() + 30
        while gate.used and time.monotonic() < deadline:
            gc.collect()
            time.sleep(0.05)
        assert gate.used == 0


# ---------------------------------------------------------------- a full disk
@contextmanager
def small_disk(root: Path, size: str = "3m", fsize: int = 600 << 10) -> Iterator[tuple[Path, str, object]]:
    """A folder whose file system fills up: a real tmpfs of `size` when this process may mount
    one (root), else (or with HARDENING_DISK=fsize) a file-size limit (RLIMIT_FSIZE) the commands
    are started under, which fails writes past it with EFBIG. Yields (folder, what was used,
    preexec_fn for Popen)."""
    folder = root / "disk"
    folder.mkdir()
    mounted = False
    if os.geteuid() == 0 and shutil.which("mount") and os.environ.get("HARDENING_DISK") != "fsize":
        mounted = (
            subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(folder)]).returncode
            == 0
        )
    try:
        if mounted:
            yield folder, f"tmpfs of {size}", None
        else:

            def limit() -> None:
                resource.setrlimit(resource.RLIMIT_FSIZE, (fsize, fsize))

            yield folder, f"RLIMIT_FSIZE of {fsize} bytes", limit
    finally:
        if mounted:
            subprocess.run(["umount", "-l", str(folder)])


def _fill(folder: Path, leave: int) -> None:
    """Fill the file system of `folder` so that about `leave` bytes stay free."""
    st = os.statvfs(folder)
    free = st.f_bavail * st.f_frsize
    if free > leave:
        with open(folder / "filler", "wb") as f, suppress(OSError):
            f.write(b"\0" * (free - leave))


def test_a_full_disk_is_one_line_507_reads_go_on_and_the_service_stops_cleanly(tmp_path):
    with small_disk(tmp_path) as (disk, used, preexec):
        mem = make_memory(disk / "m.mem")
        mem.close()
        if preexec is None:
            _fill(disk, 160 << 10)
        env = {k: v for k, v in os.environ.items() if not k.startswith("RAVENMEM_")}
        env["PYTHONPATH"] = f"{REPO / 'src'}{os.pathsep}{REPO}"
        log = tempfile.TemporaryFile("w+")  # noqa: SIM115 - read after the service stopped
        proc = subprocess.Popen(
            [
                sys.executable,
                str(REPO / "tests/server/serve_color.py"),
                "serve",
                "-m",
                str(disk / "m.mem"),
                "--port",
                "0",
                "--log-level",
                "warning",
                "--keyframes",
                "all",
            ],
            stdout=subprocess.PIPE,
            stderr=log,
            text=True,
            env=env,
            preexec_fn=preexec,
        )
        try:
            assert proc.stdout is not None
            url = proc.stdout.readline().split(" at ")[1].split("/ ")[0].rstrip("/")
            stored, statuses = 0, []
            with httpx.Client(base_url=url, timeout=60) as c:
                for i in range(400):
                    picture = np.random.default_rng(i).integers(0, 255, (240, 320, 3), np.uint8)
                    r = c.post(
                        "/memories",
                        data={"x": str(i), "y": "0", "t": str(T0 + 1000 + i)},
                        files={"image": ("f.png", png_bytes(picture), "image/png")},
                    )
                    statuses.append(r.status_code)
                    if r.status_code == 201:
                        stored += 1
                    elif r.status_code == 507:
                        break
                assert statuses[-1] == 507, (used, statuses[-5:], r.text)
                error = r.json()["error"]
                assert error.startswith("disk full") and len(error.splitlines()) == 1, error
                assert c.get("/search/text", params={"q": "red"}).status_code == 200  # reads go on
                assert c.get("/health").json()["memories"] == 12 + stored
            proc.send_signal(signal.SIGINT)
            assert proc.wait(60) in (
                0,
                130,
                -signal.SIGINT,
            )  # uvicorn re-raises the signal after a clean stop
        finally:
            if proc.poll() is None:
                proc.kill()
        log.seek(0)
        text = log.read()
        assert "Traceback" not in text and "shutdown failed" not in text, text[-3000:]
        with ravenmem.open(disk / "m.mem", embedder=ColorEmbedder()) as m:  # nothing acknowledged lost
            assert m.count() == 12 + stored


def test_ingest_on_a_full_disk_is_one_line(tmp_path):
    files = hostile_files(tmp_path / "files")
    with small_disk(tmp_path, "1m", fsize=40 << 10) as (disk, used, preexec):
        if preexec is None:
            _fill(disk, 24 << 10)
        env = {k: v for k, v in os.environ.items() if not k.startswith("RAVENMEM_")}
        env["PYTHONPATH"] = f"{REPO / 'src'}{os.pathsep}{REPO}"
        r = subprocess.run(
            [
                sys.executable,
                str(REPO / "tests/server/serve_color.py"),
                "ingest",
                str(files / "tum-ok"),
                "-m",
                str(disk / "new.mem"),
                "--embedder",
                "test-color",
                "--no-ocr",
            ],
            capture_output=True,
            text=True,
            env=env,
            preexec_fn=preexec,
            timeout=300,
        )
        lines = r.stderr.strip().splitlines()
        assert r.returncode == 2 and len(lines) == 1, (used, r.stderr[-3000:])
        assert lines[0].startswith("error: disk full"), lines


# ---------------------------------------------------------------- every read bounded
def test_reads_of_named_files_are_bounded_and_a_device_fails_fast(tmp_path, driver: Driver):
    with pytest.raises(InputError, match=r"pose file /dev/zero is larger than the limit of 1 MiB"):
        read_bounded("/dev/zero", 1 << 20, "pose file")
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    with pytest.raises(InputError, match="not a regular file"):
        read_bounded(fifo, 100, "config file")  # refused before open: no wait for a writer
    files = hostile_files(tmp_path / "files")
    r = driver.run(["ingest", str(files / "tum-ok"), "-m", str(tmp_path / "n.mem"), "--poses", "/dev/zero"])
    line = one_line_error(r)  # it stopped at the limit: before, it read until the kernel stepped in
    assert "/dev/zero" in line and "512 MiB" in line
    assert not (tmp_path / "n.mem").exists()


def test_a_query_picture_of_one_pixel_names_the_minimum(tmp_path):
    with ravenmem.create(tmp_path / "m.mem", embedder=ColorEmbedder(), ocr=False) as m:
        m.add(solid("red"), Pose(0.0, 0.0), T0)
        with pytest.raises(InputError, match=r"1x1 pixels is too small \(at least 2x2\)"):
            m.search_image(np.zeros((1, 1, 3), np.uint8))
        assert m.count() == 1
