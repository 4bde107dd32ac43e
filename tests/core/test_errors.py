"""ravenmem's errors are also the built-in exceptions they are a kind of, the facade raises only
ravenmem's own errors, and `import ravenmem` offers the public API and nothing else."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

import ravenmem
from ravenmem.errors import (
    EmptyMemoryError,
    InputError,
    MemoryBusyError,
    MemoryNotFoundError,
    MissingDependencyError,
    NotFoundError,
    RavenmemError,
    StoreUnavailableError,
    one_line,
    require,
)
from ravenmem.types import Frame, Pose
from tests.conftest import ColorEmbedder, solid


def test_code_that_knows_only_python_catches_ravenmem_errors(tmp_path) -> None:
    missing = tmp_path / "nowhere.mem"
    with pytest.raises(ValueError, match="does not exist"):  # what a caller of open writes first
        ravenmem.open(missing)
    with pytest.raises(FileNotFoundError) as e:
        ravenmem.open(missing)
    assert isinstance(e.value, MemoryNotFoundError) and isinstance(e.value, InputError)
    assert str(e.value) == f"memory {missing} does not exist"  # one line, as the CLI prints it
    (tmp_path / "plain").mkdir()
    with pytest.raises(FileNotFoundError, match="not a ravenmem memory"):
        ravenmem.open(tmp_path / "plain")
    with pytest.raises(ValueError):
        ravenmem.create(tmp_path / "m.mem", thumb_size=-1, embedder=ColorEmbedder())
    with pytest.raises(ImportError, match="pip install 'ravenmem\\[nothing\\]'") as imp:
        require("ravenmem_no_such_module", "nothing")
    assert isinstance(imp.value, MissingDependencyError)
    for cls, builtin in (
        (EmptyMemoryError, LookupError),
        (NotFoundError, LookupError),
        (MemoryBusyError, BlockingIOError),
        (StoreUnavailableError, ConnectionError),
    ):
        err = cls("one line")
        assert isinstance(err, builtin) and isinstance(err, RavenmemError) and str(err) == "one line"


def test_the_facade_raises_its_own_error_for_an_unknown_memory_id(tmp_path) -> None:
    with ravenmem.create(tmp_path / "m.mem", embedder=ColorEmbedder(), ocr=False, thumb_size=0) as mem:
        frames = [
            Frame(image=solid(c), t=100.0 + i, pose=Pose(i, 0.0), index=i)
            for i, c in enumerate(("red", "green", "blue"))
        ]
        ids = mem.add_frames(frames)
        assert [r.id for r in mem.get(ids[::-1])] == ids[::-1]
        with pytest.raises(NotFoundError, match="no such memory: 999, 1000") as e:
            mem.get([ids[0], 999, 1000])
        assert not isinstance(e.value, KeyError) and isinstance(e.value, LookupError)


def test_a_busy_memory_is_a_blocking_io_error(tmp_path) -> None:
    with ravenmem.create(tmp_path / "m.mem", embedder=ColorEmbedder(), ocr=False):
        with pytest.raises(BlockingIOError, match="being written by") as e:
            ravenmem.open(tmp_path / "m.mem", writable=True)
        assert isinstance(e.value, MemoryBusyError)


def test_import_ravenmem_offers_the_public_api_only() -> None:
    names = set(dir(ravenmem))
    assert names == {*ravenmem.__all__, "__version__"}
    assert not names & {"Any", "annotations", "memory", "types", "typing", "_typing"}
    for name in ravenmem.__all__:  # every name it offers is there (Agent is loaded when asked)
        assert getattr(ravenmem, name) is not None
    code = "import json; from ravenmem import *; print(json.dumps(sorted(k for k in dir() if k[0] != '_')))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert json.loads(out) == sorted([*ravenmem.__all__, "json"])


def test_a_bad_pose_is_an_input_error_naming_it() -> None:
    with pytest.raises(InputError, match="pose has a non-finite value") as e:
        Pose(float("nan"), 0.0)
    assert "\n" not in str(e.value)
    with pytest.raises(InputError, match="quaternion has zero or non-finite norm"):
        Pose.from_quaternion(0, 0, 0, 0, 0, 0, 0)


def test_one_line_flattens_a_multi_line_message() -> None:
    e = RuntimeError("Couldn't parse params file:\n  'bad.yaml'\r\n\tat line 3  ")
    assert one_line(e) == "Couldn't parse params file: 'bad.yaml' at line 3"
    assert one_line(InputError("already one line")) == "already one line"
    assert one_line(ValueError()) == ""  # nothing to say: the caller names the type (embed.hf)
