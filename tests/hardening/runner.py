"""Running the hostile-input table (`cases.py`): the prepared files, one `ravenmem serve` and one
command driver for the whole run, each case's outcome, and the check that nothing was lost.

Used by `tests/hardening/test_hostile.py` (CI) and `benchmarks/bench_hostile.py` (the totals in
docs/measured.md), so both run exactly the same cases.
"""

from __future__ import annotations

import io
import json
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx
import numpy as np
from PIL import Image
from PIL.PngImagePlugin import PngInfo

import ravenmem
from ravenmem.fsio import PICTURE_TAG
from ravenmem.types import Pose
from tests.cli.helpers import huge_png
from tests.cli.helpers import make_memory as make_cli_memory
from tests.conftest import ColorEmbedder, solid
from tests.hardening.cases import CASES, Case, argv, classify_cli, classify_http, classify_mcp, totals

REPO = Path(__file__).resolve().parents[2]
T0 = 1_700_000_000.0


# ---------------------------------------------------------------- the prepared files
def png_bytes(image: np.ndarray) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(image).save(buf, format="PNG")
    return buf.getvalue()


def _tum(folder: Path, times: list[float], gt: list[str]) -> None:
    (folder / "rgb").mkdir(parents=True)
    rows = []
    for i, t in enumerate(times):
        Image.fromarray(np.full((6, 8, 3), 40 * i, np.uint8)).save(folder / "rgb" / f"{i}.png")
        rows.append(f"{t!r} rgb/{i}.png")
    (folder / "rgb.txt").write_text("# timestamp filename\n" + "\n".join(rows) + "\n")
    (folder / "groundtruth.txt").write_text("# t tx ty tz qx qy qz qw\n" + "\n".join(gt) + "\n")


def _gt(times: list[float], x: str = "0") -> list[str]:
    return [f"{t!r} {x} 0 0 0 0 0 1" for t in times]


def _nav2(folder: Path, name: str, resolution: str, origin: str, pad: int = 0, image: str = "") -> None:
    if not image:
        Image.fromarray(np.full((4, 4), 254, np.uint8)).save(folder / f"{name}.pgm")
    text = f"image: {image or name + '.pgm'}\nresolution: {resolution}\norigin: {origin}\nnegate: 0\n"
    (folder / f"{name}.yaml").write_text(text + ("# " + "x" * pad + "\n" if pad else ""))


def hostile_files(folder: Path) -> Path:
    """Every file a case names under `{files}`."""
    folder.mkdir(parents=True, exist_ok=True)
    Image.new("RGB", (1, 1)).save(folder / "one-pixel.png")
    huge_png(folder / "bomb.png")
    (folder / "frame.png").write_bytes(png_bytes(solid("red")))
    depth = Image.fromarray(np.full((48, 64), 1500, np.uint16))
    depth.save(folder / "depth.png")
    ok = [T0 + i for i in range(3)]
    _tum(folder / "tum-ok", ok, _gt(ok))
    _tum(folder / "tum-t1e20", [T0, 1e20], _gt(ok))
    _tum(folder / "tum-t-1e12", [T0, -1e12], _gt(ok))
    _tum(folder / "tum-gt1e15", ok, _gt([*ok, 1e15]))
    _tum(folder / "tum-x1e308", ok, _gt(ok, x="1e308"))
    (folder / "bad-key.toml").write_text('[vlm]\nmodel = "m"\nbogus = 1\n')
    _nav2(folder, "map-ok", "1.0", "[-1.0, -1.0, 0.0]")
    _nav2(folder, "map-res1e-300", "1e-300", "[0.0, 0.0, 0.0]")
    _nav2(folder, "map-origin1e308", "0.05", "[1e308, 0.0, 0.0]")
    _nav2(folder, "map-huge", "0.05", "[0.0, 0.0, 0.0]", pad=2 << 20)
    if not (folder / "fifo").exists():
        os.mkfifo(folder / "fifo")
    # map images that are bombs (a few bytes claiming 400 and 900 megapixels) or a FIFO
    huge_png(folder / "bomb-400mp.png", 20000, 20000)
    (folder / "bomb-900mp.pgm").write_bytes(b"P5\n30000 30000\n255\n" + bytes(64))
    (folder / "bomb-100mp+.pgm").write_bytes(
        b"P5\n10001 10000\n255\n" + bytes(64)
    )  # past the map limit, not Pillow's
    for name, image in [
        ("png", "bomb-400mp.png"),
        ("pgm", "bomb-900mp.pgm"),
        ("pgm-limit", "bomb-100mp+.pgm"),
    ]:
        _nav2(folder, f"map-bomb-{name}", "0.05", "[0.0, 0.0, 0.0]", image=image)
    _nav2(folder, "map-fifo", "0.05", "[0.0, 0.0, 0.0]", image="fifo")
    for a, b in (("loop-a", "loop-b"), ("loop-b", "loop-a")):  # a symbolic link loop
        if not (folder / a).is_symlink():
            (folder / a).symlink_to(folder / b)
    np.save(folder / "vectors.npy", np.zeros((3, 4), np.float32))
    (folder / "notes.parquet").write_text("not a parquet file\n")
    with open(folder / "depth-bomb.npy", "wb") as f:  # a header claiming 10^10 cells, no data
        np.lib.format.write_array_header_1_0(
            f, {"descr": "<f4", "fortran_order": False, "shape": (100000, 100000)}
        )
    _nav2(folder, "map-dev-zero", "0.05", "[0.0, 0.0, 0.0]", image="/dev/zero")
    with open(folder / "huge-poses.csv", "wb") as f:  # sparse: past the limit, nothing to read
        f.truncate(600 << 20)
    (folder / "notes.txt").write_text("not a picture\n")
    if not (folder / "link.png").is_symlink():
        (folder / "link.png").symlink_to(folder / "notes.txt")
    tag = PngInfo()
    tag.add_text(*PICTURE_TAG)
    Image.new("RGB", (4, 4)).save(folder / "ours.png", pnginfo=tag)
    return folder


# ---------------------------------------------------------------- the command driver
class Driver:
    """`forkrun.py`: command lines run in their own processes, the interpreter started once."""

    def __init__(self) -> None:
        env = {k: v for k, v in os.environ.items() if not k.startswith(("RAVENMEM_", "OPENAI_"))}
        env["PYTHONPATH"] = os.pathsep.join([str(REPO / "src"), str(REPO)])
        self.proc = subprocess.Popen(
            [sys.executable, str(REPO / "tests" / "hardening" / "forkrun.py"), "--test-color"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            env=env,
        )

    def run(self, args: list[str], timeout: float = 120) -> dict[str, Any]:
        assert self.proc.stdin is not None and self.proc.stdout is not None
        self.proc.stdin.write(json.dumps({"argv": args, "timeout": timeout}) + "\n")
        self.proc.stdin.flush()
        line = self.proc.stdout.readline()
        if not line:
            raise RuntimeError("the command driver died")
        return json.loads(line)  # type: ignore[no-any-return]

    def close(self) -> None:
        if self.proc.stdin is not None:
            self.proc.stdin.close()
        self.proc.wait(30)


# ---------------------------------------------------------------- one run of the table
@dataclass
class Run:
    """What a run of the table needs, and what it saw."""

    root: Path
    url: str
    driver: Driver
    places: dict[str, str]
    outcomes: dict[str, tuple[str, str]] = field(default_factory=dict)

    @property
    def cli_memory(self) -> Path:
        return Path(self.places["mem"])


@contextmanager
def session(root: Path) -> Iterator[Run]:
    """The prepared files, the CLI's memory (5 memories), a served memory (12) behind one
    `ravenmem serve`, and the command driver; everything stopped afterwards."""
    from tests.server.conftest import make_memory as make_served_memory
    from tests.server.conftest import serve_subprocess, stop

    files = hostile_files(root / "files")
    mem = make_cli_memory(root / "cli.mem")
    (root / "tmp").mkdir(exist_ok=True)
    make_served_memory(root / "served.mem").close()
    driver = Driver()  # it loads the commands while the service starts
    try:
        proc, url = serve_subprocess(root / "served.mem")
    except BaseException:
        driver.close()
        raise
    try:
        imported = driver.run(["map", "-m", str(mem), "--import-nav2", str(files / "map-ok.yaml")])
        assert imported["rc"] == 0, imported  # navigate's cases then reach their options
        yield Run(
            root, url, driver, {"mem": str(mem), "tmp": str(root / "tmp"), "files": str(files), "url": url}
        )
    finally:
        driver.close()
        stop(proc)


def run_cli(run: Run, case: Case) -> tuple[str, str]:
    r = run.driver.run(argv(case, run.places))
    out = classify_cli(case, int(r["rc"]), str(r["stdout"]), str(r["stderr"]))
    return out, f"rc {r['rc']}: {str(r['stderr']).strip()[-600:]}"


def _files(run: Run, spec: str) -> dict[str, Any]:
    folder = Path(run.places["files"])
    if spec.startswith("frame+"):
        depth = {"frame+depth": "depth.png", "frame+depth-bomb": "depth-bomb.npy"}[spec]
        return {
            "image": ("frame.png", (folder / "frame.png").read_bytes(), "image/png"),
            "depth": (depth, (folder / depth).read_bytes(), "application/octet-stream"),
        }
    return {"image": (spec, (folder / spec).read_bytes(), "image/png")}


def run_http(run: Run, case: Case, client: httpx.Client) -> tuple[str, str]:
    method, path = case.call.split(" ", 1)
    kw: dict[str, Any] = {}
    if "json" in case.body:
        kw["json"] = case.body["json"]
    if "data" in case.body:
        kw["data"] = case.body["data"]
    if "files" in case.body:
        kw["files"] = _files(run, case.body["files"])
    try:
        r = client.request(method, run.url + path, **kw)
    except httpx.HTTPError as e:  # the service reset the connection or is gone
        return "traceback", f"{type(e).__name__}: {e}"
    return classify_http(case, r.status_code, r.content), f"HTTP {r.status_code}: {r.text[:600]}"


async def _mcp_calls(url: str, cases: list[Case]) -> list[tuple[bool, str]]:
    from mcp import Client

    out = []
    async with Client(f"{url}/mcp", read_timeout_seconds=60) as client:
        for case in cases:
            res = await client.call_tool(case.call, dict(case.body))
            text = " ".join(getattr(c, "text", "") for c in res.content)
            out.append((bool(res.is_error), text))
    return out


def run_table(run: Run, cases: list[Case] = CASES) -> dict[str, tuple[str, str]]:
    """Every case once; `run.outcomes[case.name] = (outcome, what was seen)`."""
    import anyio

    with httpx.Client(timeout=120) as client:
        for case in cases:
            if case.front == "cli":
                run.outcomes[case.name] = run_cli(run, case)
            elif case.front == "http":
                run.outcomes[case.name] = run_http(run, case, client)
    mcp_cases = [c for c in cases if c.front == "mcp"]
    if mcp_cases:
        try:
            seen = anyio.run(_mcp_calls, run.url, mcp_cases)
        except Exception as e:  # the service is gone
            seen = [(True, f"internal error: {type(e).__name__}")] * len(mcp_cases)
        for case, (is_error, text) in zip(mcp_cases, seen, strict=True):
            run.outcomes[case.name] = (classify_mcp(case, is_error, text), text[:600])
    return run.outcomes


# ---------------------------------------------------------------- nothing lost
def check_intact(run: Run) -> list[str]:
    """After the table: both memories open, search and accept a write, holding what they held
    (5 and 12 memories), and no refused ingest left a memory behind. Returns what failed."""
    try:
        return _check_intact(run)
    except Exception as e:  # a memory that does not open, a service that is gone
        return [f"{type(e).__name__}: {e}"]


def _check_intact(run: Run) -> list[str]:
    lost: list[str] = []
    if (Path(run.places["tmp"]) / "new.mem").exists():
        lost.append("a refused ingest left tmp/new.mem behind")
    info = run.driver.run(["info", "-m", run.places["mem"], "--json"])
    if info["rc"] != 0 or json.loads(str(info["stdout"])).get("memories") != 5:
        lost.append(f"cli memory: info says {str(info['stdout'])[:200]} {str(info['stderr'])[:200]}")
    with ravenmem.open(run.cli_memory, embedder=ColorEmbedder()) as m:
        if [h.memory.id for h in m.search_time("start", k=10)] != [1, 2, 3, 4, 5]:
            lost.append("cli memory: a time search does not list its 5 memories")
        m.add(solid("blue"), Pose(0.0, 0.0), T0 + 500)
        if m.count() != 6:
            lost.append("cli memory: a write was not stored")
    with httpx.Client(base_url=run.url, timeout=60) as c:
        if c.get("/health").json().get("memories") != 12:
            lost.append("served memory: /health does not count its 12 memories")
        if not c.get("/search/text", params={"q": "red", "k": 2}).json().get("results"):
            lost.append("served memory: a text search finds nothing")
        files = _files(run, "frame.png")
        r = c.post("/memories", data={"x": "20", "y": "20", "t": str(T0 + 900)}, files=files)
        if r.status_code != 201:
            lost.append(f"served memory: a valid live add answered {r.status_code} {r.text[:200]}")
    return lost


def main() -> None:  # pragma: no cover - `benchmarks/bench_hostile.py`
    import tempfile

    with tempfile.TemporaryDirectory() as tmp, session(Path(tmp)) as run:
        start = time.perf_counter()
        outcomes = run_table(run)
        lost = check_intact(run)
        wall = time.perf_counter() - start
    t = totals({k: v for k, (v, _) in outcomes.items()})
    by_front = {f: sum(1 for c in CASES if c.front == f) for f in ("cli", "http", "mcp")}
    print(json.dumps(t | {"data_lost": len(lost), "by_front": by_front, "seconds": round(wall, 1)}))
    for name, (outcome, seen) in outcomes.items():
        if outcome != "clear":
            print(f"{outcome}: {name}: {seen}")
    for line in lost:
        print(f"data lost: {line}")


if __name__ == "__main__":  # pragma: no cover
    main()
