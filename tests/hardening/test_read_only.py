"""A memory on read-only media answers every reading command; writing commands are one line.

Tests run as root, and root ignores permission bits, so `chmod -R a-w` proves nothing here: the
memory is bind-mounted read-only in a private mount namespace (`unshare -m`, nothing leaks to
the machine), and the `ravenmem` command runs inside it. Where that cannot be done the tests
skip; a second variant runs the command as the user `nobody` on a copy it cannot write, where
that user can run this interpreter.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

import ravenmem
from ravenmem.types import Pose
from tests.cli.helpers import REPO, T0, make_memory
from tests.conftest import ColorEmbedder, solid
from tests.hardening.conftest import snapshot

Runner = Callable[..., subprocess.CompletedProcess[str]]
PICTURE = REPO / "examples" / "tum_desk" / "rgb"


def _site(root: Path) -> Path:
    """A plugin folder that registers the test colour embedder by entry point."""
    site = root / "site"
    dist = site / "ravenmem_ro_color-0.dist-info"
    dist.mkdir(parents=True, exist_ok=True)
    (site / "ravenmem_ro_color.py").write_text(
        "from tests.conftest import ColorEmbedder\n\ndef make(spec, **kw):\n    return ColorEmbedder()\n"
    )
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: ravenmem-ro-color\nVersion: 0\n")
    (dist / "entry_points.txt").write_text("[ravenmem.embedders]\ntest-color = ravenmem_ro_color:make\n")
    return site


def _env(site: Path) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith(("RAVENMEM_", "OPENAI_"))}
    env["PYTHONPATH"] = os.pathsep.join([str(REPO / "src"), str(REPO), str(site)])
    return env


def _mount_runner(root: Path, folder: Path) -> Runner | None:
    """`ravenmem ARGS` with `folder` bind-mounted read-only at root/ro, or None when impossible."""
    if shutil.which("unshare") is None or shutil.which("mount") is None:
        return None
    mnt = root / "ro"
    mnt.mkdir(exist_ok=True)
    script = 'mount --bind -o ro "$1" "$2" && shift 2 && exec "$@"'
    probe = subprocess.run(
        [
            "unshare",
            "-m",
            "sh",
            "-c",
            script + " 2>/dev/null",
            "sh",
            str(folder),
            str(mnt),
            "sh",
            "-c",
            "! touch $0/x",
            str(mnt),
        ],
        capture_output=True,
    )
    if probe.returncode != 0:
        return None
    env = _env(_site(root))

    def run(*args: str) -> subprocess.CompletedProcess[str]:
        cmd = [sys.executable, "-m", "ravenmem.cli.main", *(a.replace("{mem}", str(mnt)) for a in args)]
        return subprocess.run(
            ["unshare", "-m", "sh", "-c", script, "sh", str(folder), str(mnt), *cmd],
            capture_output=True,
            text=True,
            env=env,
            timeout=300,
            cwd=root,
        )

    return run


def _nobody_runner(root: Path, folder: Path) -> Runner | None:
    """`ravenmem ARGS` as the user `nobody` on `folder` made read-only to it, or None."""
    if os.geteuid() != 0 or shutil.which("setpriv") is None:
        return None
    become = ["setpriv", "--reuid=65534", "--regid=65534", "--clear-groups"]
    site = _site(root)
    for p in (root, site):
        p.chmod(0o755)
    subprocess.run(["chmod", "-R", "a+rX,a-w", str(folder)], check=True)
    if subprocess.run(
        [*become, sys.executable, "-c", "import ravenmem"], capture_output=True, env=_env(site)
    ).returncode:
        return None  # this interpreter (or the checkout) is not readable by nobody

    def run(*args: str) -> subprocess.CompletedProcess[str]:
        cmd = [sys.executable, "-m", "ravenmem.cli.main", *(a.replace("{mem}", str(folder)) for a in args)]
        return subprocess.run(
            [*become, *cmd], capture_output=True, text=True, env=_env(site), timeout=300, cwd=root
        )

    return run


@pytest.fixture(scope="module", params=["mount", "nobody"])
def read_only(request: pytest.FixtureRequest) -> Iterator[tuple[Runner, Path]]:
    """A 5-memory memory (`rest.mem`) and a runner that sees it read-only; beside it a memory
    copied while its writer was still at work (`live.mem`: 6 memories, the last in the WAL).
    In a folder of its own under the system's temp folder, which `nobody` can walk into."""
    root = Path(tempfile.mkdtemp(prefix=f"ravenmem-ro-{request.param}-"))
    root.chmod(0o755)
    try:
        yield _prepare(request.param, root)
    finally:
        shutil.rmtree(root, ignore_errors=True)


def _prepare(kind: str, root: Path) -> tuple[Runner, Path]:
    folder = root / "media"
    make_memory(folder / "rest.mem")
    live = root / "live.mem"
    make_memory(live)
    m = ravenmem.open(live, embedder=ColorEmbedder(), writable=True)
    m.add(solid("blue"), Pose(9.0, 9.0), T0 + 900)
    shutil.copytree(live, folder / "live.mem")  # -wal and -shm as a killed writer leaves them
    m.close()
    make = _mount_runner if kind == "mount" else _nobody_runner
    runner = make(root, folder)
    if runner is None:
        pytest.skip(f"cannot make a read-only view here ({kind})")
    return runner, folder


READS = [
    ("info", "-m", "{mem}/rest.mem"),
    ("info", "-m", "{mem}/rest.mem", "--json"),
    ("search", "-m", "{mem}/rest.mem", "red", "--json"),
    ("search", "-m", "{mem}/rest.mem", "--image", str(next(PICTURE.iterdir())), "--json"),
    ("search", "-m", "{mem}/rest.mem", "--like", "1", "--json"),
    ("search", "-m", "{mem}/rest.mem", "--time", "start", "--json"),
    ("search", "-m", "{mem}/rest.mem", "--position", "3,6", "--json"),
    ("search", "-m", "{mem}/rest.mem", "red", "--latest", "--json"),
    ("ask", "where is red?", "-m", "{mem}/rest.mem", "--offline"),
    ("ask", "where is red?", "-m", "{mem}/rest.mem", "--offline", "--json"),
]


@pytest.mark.parametrize("args", READS, ids=lambda a: " ".join(a[:1] + a[3:]))
def test_every_read_answers_on_read_only_media(read_only: tuple[Runner, Path], args: tuple[str, ...]) -> None:
    run, folder = read_only
    before = snapshot(folder)
    r = run(*args)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "Traceback" not in r.stderr + r.stdout
    if "--json" in args:
        out = json.loads(r.stdout)
        if args[0] == "info":
            assert out["memories"] == 5
        elif args[0] == "search":
            assert out["results"], out
    assert snapshot(folder) == before


def test_the_answers_are_the_stored_ones(read_only: tuple[Runner, Path]) -> None:
    run, _ = read_only
    r = run("search", "-m", "{mem}/rest.mem", "--position", "3,6", "-k", "1", "--json")
    assert [h["id"] for h in json.loads(r.stdout)["results"]] == [4], r.stderr[-2000:]
    r = run("search", "-m", "{mem}/rest.mem", "--time", "start", "-k", "10", "--json")
    assert [h["id"] for h in json.loads(r.stdout)["results"]] == [1, 2, 3, 4, 5], r.stderr[-2000:]


def test_a_killed_writers_wal_is_read(read_only: tuple[Runner, Path]) -> None:
    """The -wal and -shm a writer left are read with the database: its last memory is there."""
    run, folder = read_only
    before = snapshot(folder)
    r = run("info", "-m", "{mem}/live.mem", "--json")
    assert r.returncode == 0 and json.loads(r.stdout)["memories"] == 6, r.stderr[-2000:]
    r = run("search", "-m", "{mem}/live.mem", "--position", "9,9", "-k", "1", "--json")
    assert [h["id"] for h in json.loads(r.stdout)["results"]] == [6], r.stderr[-2000:]
    assert snapshot(folder) == before


@pytest.mark.parametrize(
    "args",
    [
        ("forget", "-m", "{mem}/rest.mem", "--before", str(T0 + 15)),
        ("ingest", str(REPO / "examples" / "tum_desk"), "-m", "{mem}/rest.mem"),
        ("consolidate", "-m", "{mem}/rest.mem", "--budget", "3"),
    ],
    ids=lambda a: a[0],
)
def test_a_write_is_one_line(read_only: tuple[Runner, Path], args: tuple[str, ...]) -> None:
    run, folder = read_only
    before = snapshot(folder)
    r = run(*args)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr[-2000:]
    assert len(lines) == 1 and lines[0].startswith("error: ") and "cannot write" in lines[0], lines
    assert snapshot(folder) == before


# ---------------------------------------------------------------- a full disk
FULL = """
mount -t tmpfs -o size=4m tmpfs "$2" || exit 97
cp -a "$1" "$2/m.mem" && (dd if=/dev/zero of="$2/fill" bs=4k 2>/dev/null; true)
shift 2
"$@"
echo "--- files" && ls -A "$(dirname "$0")/m.mem"
"""


@pytest.mark.parametrize(
    "args",
    [
        ("info", "--json"),
        ("search", "red", "--json"),
        ("search", "--time", "start", "--json"),
        ("ask", "where is red?", "--offline", "--json"),
    ],
    ids=lambda a: " ".join(a[:2]),
)
def test_reads_answer_on_a_full_disk(tmp_path: Path, args: tuple[str, ...]) -> None:
    """A reader on a full disk cannot make the -wal and -shm files: it reads the database as
    it is, answers, and leaves no file behind."""
    if shutil.which("unshare") is None:
        pytest.skip("no unshare: cannot mount a full file system here")
    mem = make_memory(tmp_path / "m.mem")
    mnt = tmp_path / "full"
    mnt.mkdir()
    cmd = [sys.executable, "-m", "ravenmem.cli.main", args[0], "-m", str(mnt / "m.mem"), *args[1:]]
    script = FULL.replace('"$(dirname "$0")', f'"{mnt}')
    r = subprocess.run(
        ["unshare", "-m", "sh", "-c", script, "sh", str(mem), str(mnt), *cmd],
        capture_output=True,
        text=True,
        env=_env(_site(tmp_path)),
        timeout=300,
    )
    if r.returncode == 97 or "unshare:" in r.stderr:
        pytest.skip(f"cannot mount a small file system here: {r.stderr.strip()[-200:]}")
    out, _, files = r.stdout.partition("--- files\n")
    assert "Traceback" not in r.stderr and json.loads(out), r.stderr[-2000:]
    if args[0] == "info":
        assert json.loads(out)["memories"] == 5
    assert sorted(files.split()) == sorted(p.name for p in mem.iterdir())  # nothing written
