"""`ravenmem bench`: the real command in a subprocess. The figures' structure and their
consistency are checked (days per GB follow from the printed bytes and rate), never the speed."""

from __future__ import annotations

import importlib.util
import json
import os
import re
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

from tests.cli.helpers import REPO, ForkedCli, assert_one_line_error, make_memory, run_cli


def _days(bytes_per_memory: float, rate: float) -> float:
    return 1e9 / (bytes_per_memory * rate * 86_400)


@dataclass(frozen=True)
class Run:
    """One `ravenmem bench --json --rate 0.5 --synthetic 3000 --seconds 0.5 --embedder offline`
    (the default set adds the torch runtime where installed: `test_the_default_embedders`), read as it ran:
    its first stderr line, whether it was still running then, the rest, stdout, the exit code."""

    first: str
    running: bool
    rest: str
    out: str
    returncode: int


@pytest.fixture(scope="module")
def synthetic_run() -> Run:
    """The synthetic bench, run once for the tests of its report and of its progress lines
    (a bench run is a minute of CPU)."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO / "src"), str(REPO)]))
    argv = [
        "bench",
        "--json",
        "--rate",
        "0.5",
        "--synthetic",
        "3000",
        "--seconds",
        "0.5",
        "--embedder",
        "offline",
    ]
    proc = subprocess.Popen(
        [sys.executable, "-m", "ravenmem.cli.main", *argv],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    try:
        assert proc.stderr is not None
        first = proc.stderr.readline()
        running = proc.poll() is None  # the first step was announced, not reported at the end
        out, rest = proc.communicate(timeout=600)
    finally:
        proc.kill()
    return Run(first, running, rest, out, proc.returncode)


def test_bench_json_on_a_synthetic_store_is_consistent(synthetic_run: Run) -> None:
    r = synthetic_run
    assert r.returncode == 0, (r.first + r.rest)[-3000:]
    doc = json.loads(r.out)
    assert doc["rate"] == 0.5
    st = doc["store"]
    assert st["synthetic"] is True and st["memories"] == 3000 and st["dim"] == 384 and st["errors"] == {}
    assert set(st["tools"]) == {"text", "image", "time", "position"}
    for tool, t in st["tools"].items():
        assert 0 < t["p50_ms"] <= t["p99_ms"], tool
    offline = [e for e in doc["embedders"] if e["spec"] == "offline"]
    assert len(offline) == 1 and offline[0]["error"] is None and offline[0]["frames_per_s"] > 0
    assert [e["spec"] for e in doc["embedders"]] == ["offline"]  # as asked: --embedder offline
    assert offline[0]["name"].startswith("offline:effnet-lite0+minilm:")
    # the sizing follows from the measured figures
    assert doc["sizing_embedder"] == doc["embedders"][0]["name"]
    assert doc["keyframes_per_s"] == doc["embedders"][0]["frames_per_s"]
    if doc["ocr_frames_per_s"]:
        want = 1 / (1 / doc["keyframes_per_s"] + 1 / doc["ocr_frames_per_s"])
        assert doc["keyframes_per_s_with_ocr"] == pytest.approx(want, rel=1e-9)
    assert doc["disk_includes_thumbnails"] is False and doc["bytes_per_memory_disk"] > 384 * 4
    assert doc["days_per_gb_disk"] == pytest.approx(_days(doc["bytes_per_memory_disk"], 0.5), rel=1e-9)
    if doc["bytes_per_memory_ram"] is not None:  # Linux: measured in a fresh process
        assert doc["days_per_gb_ram"] == pytest.approx(_days(doc["bytes_per_memory_ram"], 0.5), rel=1e-9)
    assert "accelerators" in doc["machine"] and doc["machine"]["cpus"] >= 1


def test_bench_text_on_a_memory_reads_it_only_and_reports_what_cannot_run(tmp_path: Path) -> None:
    """A memory whose embedder is not installed here (the tests' colour embedder): the text tool
    and that embedder are reported as failed, the rest is measured, nothing in the memory changes.
    `--embedder offline`: that one after the memory's (the default set, torch's runtime too, is
    the synthetic run's)."""
    mem = make_memory(tmp_path / "m.mem", n=40)
    # any reader leaves the store's derived caches (columns.cache) behind once; bench adds nothing
    assert run_cli("search", "--time", "+0s", "-m", str(mem)).returncode == 0
    before = {p: (p.stat().st_size, p.stat().st_mtime_ns) for p in mem.rglob("*") if p.is_file()}
    r = run_cli("bench", "-m", str(mem), "--seconds", "0.5", "--embedder", "offline", timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    out = r.stdout
    after = {p: (p.stat().st_size, p.stat().st_mtime_ns) for p in mem.rglob("*") if p.is_file()}
    assert after == before  # read-only
    assert re.search(r"test-color: unavailable \(", out), out  # the memory's own embedder, then --embedder's
    assert "runtime=torch" not in out and len(re.findall(r"^  offline:", out, re.M)) == 1, out
    assert re.search(r"store: 40 memories \(this memory, dim 4\)", out), out
    assert re.search(r"^  text +failed \(", out, re.M), out
    for tool in ("image", "time", "position"):
        assert re.search(rf"^  {tool} +p50 [\d.]+ ms, p99 [\d.]+ ms$", out, re.M), out
    m = re.search(r"bytes per memory: disk ([\d,]+) B \(with thumbnails\)", out)
    days = re.search(r"at 0.12 keyframes/s: ([\d,.]+) days of memory per GB of disk", out)
    assert m and days, out
    printed = float(days.group(1).replace(",", ""))
    lo, hi = (_days(float(m.group(1).replace(",", "")) + d, 0.12) for d in (0.5, -0.5))  # bytes rounded
    assert lo - 0.05 <= printed <= hi + 0.05, (printed, lo, hi)
    assert re.search(r"sustainable: [\d.]+ keyframes/s", out), out  # from the offline embedder


def test_the_default_embedders() -> None:
    """Without --embedder: the offline embedder (unless the memory's is one) and its torch
    runtime where torch is installed, after the memory's own."""
    from ravenmem.capacity import default_specs

    torch = ["offline:runtime=torch"] if importlib.util.find_spec("torch") is not None else []
    assert default_specs([]) == ["offline", *torch]
    assert default_specs(["test-color"]) == ["offline", *torch]
    assert default_specs(["offline:effnet-lite0+minilm:x"]) == torch


@pytest.mark.parametrize(
    "args, match",
    [
        (["--rate", "0"], "--rate: expected a rate > 0"),  # checked by the option model
        (["--rate", "nan"], "--rate: expected a rate > 0"),
        (["--synthetic", "5"], "--synthetic: expected a whole number from 100"),
        (["--seconds", "inf"], "--seconds: expected seconds > 0"),
        (["-m", "/nonexistent/x.mem"], "not a ravenmem memory"),
    ],
)
def test_bench_bad_input_is_one_line(forked_cli: ForkedCli, args: list[str], match: str) -> None:
    line = assert_one_line_error(forked_cli("bench", *args, timeout=120))
    assert match in line


def test_bench_says_each_step_as_it_goes(synthetic_run: Run) -> None:
    """Progress on stderr while it runs (the first line comes before the work it announces is
    done), each step numbered, the synthetic store's build counted; stdout keeps the JSON."""
    first, running, rest, out = (
        synthetic_run.first,
        synthetic_run.running,
        synthetic_run.rest,
        synthetic_run.out,
    )
    assert running and re.match(r"\[1/\d\] embedder offline: loading", first), first
    lines = [first.rstrip("\n"), *rest.splitlines()]
    steps = [ln for ln in lines if ln.startswith("[")]
    total = int(re.match(r"\[1/(\d)\]", first)[1])  # type: ignore[index]
    assert list(dict.fromkeys(s.split("]")[0] for s in steps)) == [
        f"[{i}/{total}" for i in range(1, total + 1)
    ]
    assert any(re.search(r"store: building a synthetic one: 3000/3000 \(100%\)", ln) for ln in lines), lines
    assert synthetic_run.returncode == 0 and json.loads(out)["store"]["memories"] == 3000
