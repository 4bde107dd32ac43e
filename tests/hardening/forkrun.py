"""`python tests/hardening/forkrun.py`: run many `ravenmem` command lines, each in its own process.

The hostile-input suite runs a hundred command lines; starting Python and importing ravenmem
for each would take minutes on a loaded machine. This driver imports the real command once
(with the colour test embedder registered by name, as `tests/server/serve_color.py` does), then
for each JSON line `{"argv": [...]}` on stdin forks a child that runs `ravenmem.cli.main.main`
with that argv, its stdout and stderr in files, and exits with the command's own exit code; the
driver answers one JSON line `{"rc": ..., "stdout": ..., "stderr": ...}`. Each command is a
separate process with the real entry point, exit code and streams, as a user's would be.
"""

from __future__ import annotations

import contextlib
import importlib
import json
import os
import signal
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from ravenmem.cli.main import main  # noqa: E402
from ravenmem.embed.base import EMBEDDERS  # noqa: E402
from tests.conftest import ColorEmbedder  # noqa: E402

EMBEDDERS.register("test-color")(lambda spec, **kw: ColorEmbedder())

# What the commands import on demand (their subcommand's modules, scipy, PyAV, faiss, the agent),
# imported here once so that each forked command finds it loaded: a hundred children each
# importing it again took ~0.5 s apiece. The commands still run whole; only the import is shared.
PRELOAD = (
    "ravenmem.spec",
    "ravenmem.agent",
    "ravenmem.ingest.pipeline",
    "ravenmem.ingest.sources",
    "ravenmem.store.local",
    "ravenmem.runtime.service",
    "ravenmem.nav",
    "ravenmem.robot",
    "ravenmem.server.client",
    "ravenmem.cli.agent",
    "ravenmem.cli.lifelong",
    "ravenmem.cli.nav",
    "ravenmem.cli.serve",
    "ravenmem.cli.source",
)


def preload() -> None:
    for name in PRELOAD:
        with contextlib.suppress(ImportError):  # an extra not installed: its commands refuse alone
            importlib.import_module(name)


def run(argv: list[str], timeout: float) -> dict[str, object]:
    with tempfile.TemporaryFile("w+b") as out, tempfile.TemporaryFile("w+b") as err:
        pid = os.fork()
        if pid == 0:  # the child: the command, with its own streams and exit code
            os.dup2(out.fileno(), 1)
            os.dup2(err.fileno(), 2)
            sys.stdin = open(os.devnull)  # noqa: SIM115 - the child exits below
            signal.alarm(max(1, int(timeout)))  # a command that hangs is killed (rc -14)
            code = 0
            try:
                sys.argv = ["ravenmem", *argv]
                main(argv)
            except SystemExit as e:
                code = e.code if isinstance(e.code, int) else (0 if e.code is None else 1)
            except BaseException:
                import traceback

                traceback.print_exc()
                code = 1
            finally:
                sys.stdout.flush()
                sys.stderr.flush()
            os._exit(code)
        _, status = os.waitpid(pid, 0)
        rc = os.waitstatus_to_exitcode(status)
        out.seek(0)
        err.seek(0)
        return {
            "rc": rc,
            "stdout": out.read().decode("utf-8", "backslashreplace"),
            "stderr": err.read().decode("utf-8", "backslashreplace"),
        }


def serve_forever() -> None:
    for line in sys.stdin:
        req = json.loads(line)
        sys.stdout.write(json.dumps(run(req["argv"], float(req.get("timeout", 120)))) + "\n")
        sys.stdout.flush()


if __name__ == "__main__":
    preload()
    serve_forever()
