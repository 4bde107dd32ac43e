"""`python tests/hardening/forkrun.py`: run many `ravenmem` command lines, each in its own process.

The hostile-input suite runs a hundred command lines; starting Python and importing ravenmem
for each would take minutes on a loaded machine. This driver imports the real command once
(and what its commands import on demand: PRELOAD), then
for each JSON line `{"argv": [...]}` on stdin forks a child that runs `ravenmem.cli.main.main`
with that argv, its stdout and stderr in files, and exits with the command's own exit code; the
driver answers one JSON line `{"rc": ..., "stdout": ..., "stderr": ...}`. Each command is a
separate process with the real entry point, exit code and streams, as a user's would be.

A request may also carry `env` (the command's whole environment, as `subprocess.run(env=...)`
gives it), `paths` (folders put on sys.path after the checkout, as on PYTHONPATH: a plugin
site) and `cwd`. The colour test embedder is registered only under `--test-color` (the
hardening table's commands use it; a plain `ravenmem` does not know it). What importing the
command set in os.environ (e.g. the hub's progress bars off) is set again in a child given
its own environment, as the import would have set it there. (`tests/cli/helpers.ForkedCli`.)
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
from typing import Any

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))

_ENV_AT_START = dict(os.environ)

from ravenmem.cli.main import main  # noqa: E402

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


def preload() -> dict[str, str]:
    """Import PRELOAD; what the imports set in os.environ."""
    for name in PRELOAD:
        with contextlib.suppress(ImportError):  # an extra not installed: its commands refuse alone
            importlib.import_module(name)
    return {k: v for k, v in os.environ.items() if k not in _ENV_AT_START}


def register_test_color() -> None:
    from ravenmem.embed.base import EMBEDDERS
    from tests.conftest import ColorEmbedder

    EMBEDDERS.register("test-color")(lambda spec, **kw: ColorEmbedder())


def _enter(req: dict[str, Any], import_env: dict[str, str]) -> None:
    """In the child: the request's environment, sys.path and working folder."""
    if req.get("env") is not None:
        os.environ.clear()
        os.environ.update(req["env"])
        for k, v in import_env.items():
            os.environ.setdefault(k, v)
    if req.get("paths"):
        checkout = [i for i, p in enumerate(sys.path) if p in (str(REPO), str(REPO / "src"))]
        at = max(checkout) + 1 if checkout else len(sys.path)
        sys.path[at:at] = list(req["paths"])
    if req.get("cwd"):
        os.chdir(req["cwd"])


def run(req: dict[str, Any], import_env: dict[str, str]) -> dict[str, object]:
    argv, timeout = list(req["argv"]), float(req.get("timeout", 120))
    with tempfile.TemporaryFile("w+b") as out, tempfile.TemporaryFile("w+b") as err:
        pid = os.fork()
        if pid == 0:  # the child: the command, with its own streams and exit code
            os.dup2(out.fileno(), 1)
            os.dup2(err.fileno(), 2)
            sys.stdin = open(os.devnull)  # noqa: SIM115 - the child exits below
            signal.alarm(max(1, int(timeout)))  # a command that hangs is killed (rc -14)
            code = 0
            try:
                _enter(req, import_env)
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


def serve_forever(import_env: dict[str, str]) -> None:
    for line in sys.stdin:
        sys.stdout.write(json.dumps(run(json.loads(line), import_env)) + "\n")
        sys.stdout.flush()


if __name__ == "__main__":
    if "--test-color" in sys.argv[1:]:
        register_test_color()
    serve_forever(preload())
