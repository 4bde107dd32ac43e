"""The hostile-input suite: one table of bad inputs, each tried on the product as a user meets it.

A case is one line: `cli(...)` a `ravenmem` command line (run in its own process by
`forkrun.py`), `http(...)` a request to a real `ravenmem serve`, `mcp(...)` a tool call through
the `mcp` package's client. Each names a piece of the problem that its one-line error must
hold (`expect`). Placeholders in command lines and paths: `{mem}` the memory the CLI cases share
(5 memories and a 4 x 4 m map), `{tmp}` a scratch folder, `{url}` the running service, `{files}` the folder of prepared
hostile files (see `runner.hostile_files`).

Every outcome is one of (`classify_*`):
- clear: refused with one line naming the problem (CLI: exit 2 or 1, one `error: ...` line, no
  traceback; HTTP: a 4xx, 503 or 507 with `{"error": "<one line>"}`; MCP: an error result);
- traceback: a traceback, an HTTP 500, an MCP "internal error", a command killed or hung;
- silent: accepted (exit 0, HTTP 2xx, an MCP result), i.e. nonsense taken as input;
- unclear: refused, but not in one line naming the problem.
After the table, the memories must still open, search and accept writes, holding what they
held before: anything else is data lost (`tests/hardening/test_hostile.py`).
"""

from __future__ import annotations

import json
import shlex
from dataclasses import dataclass, field
from typing import Any

BIG = "99999999999999999999999"  # past SQLite's INTEGER


@dataclass(frozen=True)
class Case:
    front: str  # cli | http | mcp
    call: str  # the command line, `METHOD /path?query`, or the MCP tool
    expect: str  # what the one-line error must name
    body: dict[str, Any] = field(default_factory=dict)  # http: json / form / files; mcp: arguments

    @property
    def name(self) -> str:
        extra = json.dumps(self.body, sort_keys=True)[:60] if self.body else ""
        if "files" in self.body:  # the upload tells two live adds of the same fields apart
            extra += f" [{self.body['files']}]"
        name = f"{self.front}: {self.call} {extra}".strip()
        return name.encode("utf-8", "backslashreplace").decode("utf-8")  # a name that is not UTF-8, printable


def cli(line: str, expect: str) -> Case:
    return Case("cli", line, expect)


def http(line: str, expect: str, **body: Any) -> Case:
    return Case("http", line, expect, body)


def mcp(tool: str, expect: str, **args: Any) -> Case:
    return Case("mcp", tool, expect, args)


def post(t: object = None, **form: object) -> dict[str, Any]:
    """A live add's form fields (a valid frame unless overridden), with a small PNG."""
    fields = {"x": "1", "y": "2", "z": "0", "source": "hostile"} | {k: str(v) for k, v in form.items()}
    if t is not None:
        fields["t"] = str(t)
    return {"data": fields, "files": "frame.png"}


CASES: list[Case] = [
    # ------------------------------------------------------------ times and numbers at the door
    http("POST /memories", "t", **post(t=-1e12)),
    http("POST /memories", "t", **post(t=1e12)),
    http("POST /memories", "t", **post(t=1e15)),
    http("POST /memories", "t", **post(t=1e20)),
    http("POST /memories", "t", **post(t=1e305)),
    http("POST /memories", "t", **post(t="nan")),
    http("POST /memories", "pose", **post(x=1e308)),
    http("POST /memories", "pose", **post(yaw=1e300)),
    http("POST /memories", "depth_scale", **post(depth_scale="1e300") | {"files": "frame+depth"}),
    http("POST /memories", "source", **post(source="s" * 300)),
    http("POST /memories", "too small", **post() | {"files": "one-pixel.png"}),
    cli("ingest {files}/tum-t1e20 -m {mem} --embedder test-color", "timestamp"),
    cli("ingest {files}/tum-t-1e12 -m {mem} --embedder test-color", "timestamp"),
    cli("ingest {files}/tum-gt1e15 -m {mem} --embedder test-color", "'t'"),
    cli("ingest {files}/tum-x1e308 -m {mem} --embedder test-color", "'x'"),
    # ------------------------------------------------------------ absurd times in filters and in forget
    cli("search -m {mem} --time 1e308", "out of range"),
    cli("search -m {mem} --time '99999999999 days ago'", "out of range"),
    cli("search -m {mem} red --after 1e308", "after"),
    cli("search -m {mem} red --before -1e12", "before"),
    cli("search -m {mem} --position 1,1 --after '99999999999 days ago'", "after"),
    cli("forget -m {mem} --before 1e308", "before"),
    cli("forget -m {mem} --after -1e308", "after"),
    cli("forget -m {mem} --before '99999999999 days ago'", "before"),
    cli("forget -m {mem} --after 9999-12-31T00:00:00Z --dry-run", "after"),
    http("GET /search/time?t=1e308", "time"),
    http("GET /search/time?t=99999999999%20days%20ago", "out of range"),
    http("GET /search/text?q=red&after=1e308", "after"),
    http("GET /search/position?x=1&y=1&before=-1e12", "before"),
    http("GET /search/image?memory_id=1&before=99999999999%20days%20ago", "before"),
    http("POST /search/image?after=1e308", "after", files="frame.png"),
    mcp("search_time", "out of range", time="99999999999 days ago"),
    mcp("search_text", "after", query="red", after=1e308),
    mcp("search_position", "before", x=1, y=1, before=-1e12),
    # ------------------------------------------------------------ also seen: names, files, uploads
    cli("ingest {files}/tum-ok -m {files}/loop-a --embedder test-color", "symbolic link"),
    cli("ingest {files}/tum-ok -m '{tmp}/bad\udcff.mem' --embedder test-color", "UTF-8"),
    cli("info -m '{tmp}/bad\udcff.mem'", "UTF-8"),
    cli("serve -m {mem} --log-level nope", "--log-level"),
    cli(
        "import {files}/vectors.npy --meta {files}/notes.parquet -m {tmp}/new.mem --embedder test-color",
        "Parquet",
    ),
    http("POST /memories", "cells", **post() | {"files": "frame+depth-bomb"}),
    # ------------------------------------------------------------ ids past SQLite's INTEGER
    http(f"GET /memories/{BIG}", BIG),
    http(f"GET /memories/{BIG}/image", BIG),
    http(f"GET /search/image?memory_id={BIG}", BIG),
    http("GET /search/image?memory_id=-1", "-1"),
    http("POST /ask", "image_memory_id", json={"question": "where is it?", "image_memory_id": 1e30}),
    mcp("search_image", "memory_id", memory_id=10**23, k=1),
    cli(f"search -m {{mem}} --like {BIG}", "--like"),
    cli("search -m {mem} --like -1", "--like"),
    # ------------------------------------------------------------ every option checked once
    cli("serve -m {mem} --max-upload-mb nan", "--max-upload-mb"),
    cli("serve -m {mem} --max-upload-mb inf", "--max-upload-mb"),
    cli("serve -m {mem} --max-upload-mb -1", "--max-upload-mb"),
    cli("serve -m {mem} --wait nan", "--wait"),
    cli("serve -m {mem} --timeout nan", "--timeout"),
    cli("serve -m {mem} --timeout 0", "--timeout"),
    cli("serve -m {mem} --body-timeout inf", "--body-timeout"),
    cli("serve -m {mem} --port 70000", "--port"),
    cli("serve -m {mem} --top-k 0", "--top-k"),
    cli("serve -m {mem} --max-tool-calls 0", "--max-tool-calls"),
    cli("serve -m {mem} --config /etc/passwd", "--config"),
    cli("navigate -m {mem} --to 1e308,1e308", "--to"),
    cli("navigate -m {mem} --to 1,1 --from nan,1", "--from"),
    cli("navigate -m {mem} --to 1,1 --robot-radius 1e308", "--robot-radius"),
    cli("navigate -m {mem} --to 1,1 --robot-radius -1", "--robot-radius"),
    cli("navigate -m {mem} --to 1,1 --robot-radius nan", "--robot-radius"),
    cli("navigate -m {mem} --to 1,1 --png {tmp}", "--png"),
    cli("ask 'where is red?' -m {mem} --offline --temperature nan", "--temperature"),
    cli("ask 'where is red?' -m {mem} --offline --top-k 0", "--top-k"),
    cli("ask 'where is red?' -m {mem} --offline --top-k text=0", "--top-k"),
    cli("ask 'where is red?' -m {mem} --offline --max-tool-calls 0", "--max-tool-calls"),
    cli("ask 'where is red?' -m {mem} --offline --image-max-side -1", "--image-max-side"),
    cli("ask 'where is red?' -m {mem} --offline --trace /proc/nope/t.json", "--trace"),
    cli("ask 'where is red?' -m {mem} --offline --trace {tmp}", "--trace"),
    cli("ask 'where is red?' -m {mem} --offline --config /etc/passwd", "--config"),
    cli("ask 'where is red?' -m {mem} --offline --config {files}/bad-key.toml", "--config"),
    cli("ask 'where is red?' -m {mem} --offline --timeout -5", "--timeout"),
    cli("ask 'where is red?' -m {mem} --offline --max-retries -1", "--max-retries"),
    cli("ask 'where is red?' -m {mem} --offline --frames 0", "--frames"),
    cli("ask 'where is red?' -m {mem} --offline --seed -1", "--seed"),
    cli("ask 'where is red?' -m {mem} --offline --navigate --from 1e308,0", "--from"),
    cli("map -m {mem} --import-nav2 {files}/map-res1e-300.yaml --overwrite", "resolution"),
    cli("map -m {mem} --import-nav2 {files}/map-origin1e308.yaml --overwrite", "origin"),
    cli("map -m {mem} --rebuild --resolution 0", "--resolution"),
    cli("ingest {files}/tum-ok -m {tmp}/new.mem --embedder test-color --fps nan", "--fps"),
    cli("ingest {files}/tum-ok -m {tmp}/new.mem --embedder test-color --stride 0", "--stride"),
    cli("ingest {files}/tum-ok -m {tmp}/new.mem --embedder test-color --thumb-size -1", "--thumb-size"),
    cli("ingest {files}/tum-ok -m {tmp}/new.mem --embedder test-color --batch-size 0", "--batch-size"),
    cli("consolidate -m {mem} --budget 3 --max-distance nan --dry-run", "--max-distance"),
    cli("consolidate -m {mem} --max-similarity 2 --dry-run", "--max-similarity"),
    cli("consolidate -m {mem} --budget 0 --dry-run", "--budget"),
    cli("search -m {mem} red -k 0", "--k"),
    cli("search -m {mem} red -k 100000", "--k"),
    cli("search -m {mem} --position 1,1 --radius nan", "--radius"),
    cli("view -m {mem} -k 0", "--k"),
    # ------------------------------------------------------------ queries that overflow or mean nothing
    cli("search -m {mem} red --near 1e308,0,1", "near"),
    cli("search -m {mem} red --near 0,0,1e308", "near"),
    cli("search -m {mem} --position 1e308,0", "x"),
    cli("search -m {mem} --time 1e400", "time"),
    cli("search -m {mem} --image {files}/one-pixel.png", "too small"),
    cli("search -m {mem} --image {files}/bomb.png", "bomb.png"),
    cli("search -m {mem} --image /dev/zero", "/dev/zero"),
    cli("search --server {url} --image /dev/zero", "/dev/zero"),
    cli("ask 'what is this?' --server {url} --offline --image /dev/zero", "/dev/zero"),
    http("GET /search/text?q=%FF%FE%FA", "UTF-8"),
    http("GET /search/text?q=red&near=1e308,0,1", "near"),
    http("GET /search/position?x=1e308&y=0", "x"),
    http("GET /search/position?x=1&y=1&radius=1e300", "radius"),
    http("GET /search/time?t=1e400", "time"),
    http("GET /search/text?q=red&k=0", "k"),
    http("POST /search/image", "too small", files="one-pixel.png"),
    http("POST /search/image", "pixels", files="bomb.png"),
    mcp("search_position", "x", x=1e308, y=0),
    mcp("search_text", "near", query="red", near=[1e308, 0, 1]),
    mcp("search_text", "query", query=""),
    mcp("search_time", "time", time="1e400"),
    mcp("search_image", "image", image="not base64!"),
    mcp("search_text", "k", query="red", k=0),
    # ------------------------------------------------------------ reads bounded by size
    cli("ingest {files}/tum-ok -m {tmp}/new.mem --embedder test-color --poses /dev/zero", "limit"),
    cli("ingest {files}/tum-ok -m {tmp}/new.mem --embedder test-color --poses {files}/fifo", "regular file"),
    cli(
        "ingest {files}/tum-ok -m {tmp}/new.mem --embedder test-color --poses {files}/huge-poses.csv", "limit"
    ),
    cli("ask 'where is red?' -m {mem} --offline --config /dev/zero", "--config"),
    cli("map -m {mem} --import-nav2 {files}/map-huge.yaml --overwrite", "limit"),
    # ------------------------------------------------------------ bombs and FIFOs in map files
    cli("map -m {mem} --import-nav2 {files}/map-bomb-png.yaml --overwrite", "pixels"),
    cli("map -m {mem} --import-nav2 {files}/map-bomb-pgm.yaml --overwrite", "pixels"),
    cli("map -m {mem} --import-nav2 {files}/map-bomb-pgm-limit.yaml --overwrite", "pixels"),
    cli("map -m {mem} --import-nav2 {files}/map-fifo.yaml --overwrite", "regular file"),
    cli("map -m {mem} --import-nav2 {files}/map-dev-zero.yaml --overwrite", "/dev/zero"),
    cli("eval study embedders --labels /dev/zero --images {tmp} --embedders offline", "/dev/zero"),
    # ------------------------------------------------------------ outputs never destroy inputs
    cli("search -m {mem} red --sheet {mem}/memory.json", "--sheet"),
    cli("search -m {mem} red --sheet {mem}/store.sqlite", "--sheet"),
    cli("search -m {mem} red --sheet {mem}/new.png", "memory folder"),
    cli("search -m {mem} red --sheet {files}/notes.txt --force", "not a picture"),
    cli("search -m {mem} red --sheet {files}/link.png --force", "symbolic link"),
    cli("search -m {mem} red --sheet {files}/ours.png", "--force"),
    cli("ask 'where is red?' -m {mem} --offline --sheet {mem}/memory.json", "--sheet"),
    cli("navigate -m {mem} --to 1,1 --png {mem}/map.png", "--png"),
]


def argv(case: Case, places: dict[str, str]) -> list[str]:
    return [a.format(**places) for a in shlex.split(case.call)]


def one_line(text: str) -> bool:
    return len(text.strip().splitlines()) == 1


def classify_cli(case: Case, rc: int, stdout: str, stderr: str) -> str:
    if "Traceback" in stdout + stderr or rc < 0:
        return "traceback"
    if rc == 0:
        return "silent"
    lines = stderr.strip().splitlines()
    if rc in (1, 2) and len(lines) == 1 and lines[0].startswith("error: ") and case.expect in lines[0]:
        return "clear"
    return "unclear"


def classify_http(case: Case, status: int, body: bytes) -> str:
    if status >= 500 and status not in (503, 507):
        return "traceback"
    if status < 400:
        return "silent"
    try:
        error = json.loads(body)["error"]
    except (ValueError, KeyError, TypeError):
        return "unclear"
    return "clear" if isinstance(error, str) and one_line(error) and case.expect in error else "unclear"


def classify_mcp(case: Case, is_error: bool, text: str) -> str:
    if "internal error" in text or "Traceback" in text:
        return "traceback"
    if not is_error:
        return "silent"
    return "clear" if one_line(text) and case.expect in text else "unclear"


def totals(outcomes: dict[str, str]) -> dict[str, int]:
    """tried / clear / traceback / silent / unclear over the table's outcomes."""
    out = {"tried": len(outcomes), "clear": 0, "traceback": 0, "silent": 0, "unclear": 0}
    for v in outcomes.values():
        out[v] += 1
    return out
