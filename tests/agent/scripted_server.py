"""A scripted VLM served over real HTTP on 127.0.0.1, speaking OpenAI chat completions.

Used by the agent tests and the evaluation tests: the client under test talks to it exactly as
to vLLM / Ollama / OpenAI, and every request body is recorded for assertions.

    from tests.agent.scripted_server import ScriptedModel, answer, tool, error
    with ScriptedModel([tool("search_text", query="red backpack"), answer(question_type="position", evidence=[3])]) as srv:
        cfg = VLMConfig(base_url=srv.base_url, model="scripted", backoff=0.0)
        ...
        srv.requests          # list of JSON bodies received by POST /v1/chat/completions, in order
        srv.tool_names(0)     # names of the tools offered in request 0
        srv.images(1)         # number of image_url parts in request 1

Script items (plain dicts, consumed one per request; helpers below build them):
- {"content": str}                       assistant text (e.g. a JSON answer)
- {"tool_calls": [{"name": str, "arguments": dict | str, "id": str, "as_object": bool}, ...]}
                                         (`id` "" as Gemini sends; `as_object` sends the arguments
                                         as a JSON object, not the string the API specifies)
- {"refusal": str}                       content null, message.refusal set
- {"status": int, "error": str, "headers": {...}}   an HTTP error (429, 500, 503, 400, ...)
- {"raw": str, "content_type": str}      a 200 response whose body is this text (broken JSON, HTML)
- {"message": dict | None}               the choice's message exactly as given (shapes of other servers)
- {"choices": list}                      the completion's choices exactly as given
- "delay": seconds (any item)            sleep before responding (provokes client timeouts)
- "drip": seconds (any item)             send the response (status line, headers, body) one byte
                                         at a time, this long apart: a server that is never
                                         silent long enough for a per-read timeout
- "finish_reason", "usage": {...}        override the defaults
- a callable(body: dict) -> item         decided per request (e.g. answer with what was shown)
When the script runs out, `default` is used (an item or callable); without one, HTTP 500.
`reject_tools=True` answers 400 to any request that carries `tools` without consuming the script
(an endpoint without function calling); `reject_images=STATUS` answers that status to any
request with an image part (a text-only model: vLLM and OpenAI say 400, llama.cpp's server 500).
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any

Item = dict[str, Any] | Callable[[dict[str, Any]], dict[str, Any]]


def content(text: str, **extra: Any) -> dict[str, Any]:
    return {"content": text, **extra}


def answer(**fields: Any) -> dict[str, Any]:
    """A reply whose content is the JSON answer object (fields as given)."""
    return {"content": json.dumps(fields)}


def tool(name: str, **arguments: Any) -> dict[str, Any]:
    """A reply with one native tool call."""
    return {"tool_calls": [{"name": name, "arguments": arguments}]}


def tools(*calls: tuple[str, dict[str, Any]]) -> dict[str, Any]:
    """A reply with several native tool calls in one turn."""
    return {"tool_calls": [{"name": n, "arguments": a} for n, a in calls]}


def json_tool(name: str, **arguments: Any) -> dict[str, Any]:
    """A tool request written as JSON text (the JSON-in-prompt protocol)."""
    return {"content": json.dumps({"tool": name, "arguments": arguments})}


def error(status: int, message: str = "scripted error", **extra: Any) -> dict[str, Any]:
    return {"status": status, "error": message, **extra}


def refuse(text: str = "I'm sorry, but I can't help with that.") -> dict[str, Any]:
    return {"refusal": text}


class ScriptedModel:
    """The server; a context manager (or call start()/stop())."""

    def __init__(
        self,
        script: list[Item] | None = None,
        default: Item | None = None,
        reject_tools: bool = False,
        reject_images: int | None = None,
    ) -> None:
        self.script: list[Item] = list(script or [])
        self.default = default
        self.reject_tools = reject_tools
        self.reject_images = reject_images
        self.requests: list[dict[str, Any]] = []
        self.headers: list[dict[str, str]] = []  # request headers, names lower-cased
        self.responses: list[dict[str, Any]] = []
        self.drips_abandoned = 0  # dripped responses the client hung up on
        self._lock = threading.Lock()
        self._httpd: ThreadingHTTPServer | None = None
        self._thread: threading.Thread | None = None

    # ---------------------------------------------------------------- lifecycle
    def start(self) -> ScriptedModel:
        owner = self

        class Handler(BaseHTTPRequestHandler):
            def log_message(self, *args: Any) -> None:  # keep test output clean
                pass

            def do_GET(self) -> None:
                if self.path.rstrip("/").endswith("/models"):
                    self._send(200, {"object": "list", "data": [{"id": "scripted", "object": "model"}]})
                else:
                    self._send(404, {"error": {"message": "not found"}})

            def do_POST(self) -> None:
                length = int(self.headers.get("content-length") or 0)
                raw = self.rfile.read(length)
                if not self.path.rstrip("/").endswith("/chat/completions"):
                    self._send(404, {"error": {"message": f"no route {self.path}"}})
                    return
                try:
                    body = json.loads(raw)
                except json.JSONDecodeError:
                    self._send(400, {"error": {"message": "request body is not JSON"}})
                    return
                status, payload, headers, delay, drip = owner._respond(
                    body, {k.lower(): v for k, v in self.headers.items()}
                )
                if delay:
                    time.sleep(delay)
                if drip:
                    self._drip(status, payload, drip)
                else:
                    self._send(status, payload, headers)

            def _send(self, status: int, payload: Any, headers: dict[str, str] | None = None) -> None:
                data = payload.encode() if isinstance(payload, str) else json.dumps(payload).encode()
                headers = dict(headers or {})
                try:
                    self.send_response(status)
                    self.send_header("content-type", headers.pop("content-type", "application/json"))
                    self.send_header("content-length", str(len(data)))
                    for k, v in (headers or {}).items():
                        self.send_header(k, v)
                    self.end_headers()
                    self.wfile.write(data)
                except (BrokenPipeError, ConnectionResetError):  # the client gave up (timeout tests)
                    pass

            def _drip(self, status: int, payload: Any, every: float) -> None:
                data = json.dumps(payload).encode()
                head = f"HTTP/1.1 {status} OK\r\ncontent-type: application/json\r\ncontent-length: {len(data)}\r\n\r\n"
                self.close_connection = True
                try:
                    for byte in head.encode() + data:
                        self.wfile.write(bytes([byte]))
                        self.wfile.flush()
                        time.sleep(every)
                except (BrokenPipeError, ConnectionResetError, OSError):  # the client gave up
                    owner.drips_abandoned += 1

        self._httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self._httpd.daemon_threads = True
        self._thread = threading.Thread(
            target=self._httpd.serve_forever, kwargs={"poll_interval": 0.02}, daemon=True
        )
        self._thread.start()
        return self

    def stop(self) -> None:
        if self._httpd is not None:
            self._httpd.shutdown()
            self._httpd.server_close()
            self._httpd = None

    def __enter__(self) -> ScriptedModel:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    @property
    def base_url(self) -> str:
        assert self._httpd is not None, "server not started"
        return f"http://127.0.0.1:{self._httpd.server_address[1]}/v1"

    def push(self, *items: Item) -> None:
        with self._lock:
            self.script.extend(items)

    # ---------------------------------------------------------------- inspection
    def tool_names(self, i: int) -> list[str]:
        return [t["function"]["name"] for t in self.requests[i].get("tools", [])]

    def images(self, i: int) -> int:
        return sum(1 for p in self._parts(i) if p.get("type") == "image_url")

    def texts(self, i: int) -> str:
        """Every text of request i (system, user, tool messages) joined: for 'in' assertions."""
        out = []
        for m in self.requests[i]["messages"]:
            if isinstance(m.get("content"), str):
                out.append(m["content"])
        out += [p.get("text", "") for p in self._parts(i) if p.get("type") == "text"]
        return "\n".join(out)

    def _parts(self, i: int) -> list[dict[str, Any]]:
        return [
            p
            for m in self.requests[i]["messages"]
            if isinstance(m.get("content"), list)
            for p in m["content"]
        ]

    # ---------------------------------------------------------------- responding
    def _respond(
        self, body: dict[str, Any], headers: dict[str, str]
    ) -> tuple[int, Any, dict[str, str], float, float]:
        with self._lock:
            self.requests.append(body)
            self.headers.append(headers)
            n = len(self.requests)
            parts = [
                p
                for m in body.get("messages", [])
                if isinstance(m.get("content"), list)
                for p in m["content"]
            ]
            if self.reject_images and any(p.get("type") == "image_url" for p in parts):
                item: Any = error(self.reject_images, "this model does not take images")
            elif self.reject_tools and body.get("tools"):
                item = error(400, "this model does not support tools")
            elif self.script:
                item = self.script.pop(0)
            elif self.default is not None:
                item = self.default
            else:
                item = error(500, "script exhausted")
        if callable(item):
            item = item(body)
        delay = float(item.get("delay", 0.0))
        drip = float(item.get("drip", 0.0))
        if "status" in item:
            payload = {
                "error": {"message": item.get("error", "error"), "type": "scripted", "code": item["status"]}
            }
            self.responses.append({"status": item["status"], **payload})
            return int(item["status"]), payload, dict(item.get("headers", {})), delay, drip
        if "raw" in item:
            self.responses.append({"raw": item["raw"]})
            kind = {"content-type": item["content_type"]} if "content_type" in item else {}
            return 200, str(item["raw"]), kind, delay, drip
        message: dict[str, Any] = {"role": "assistant", "content": item.get("content")}
        finish = item.get("finish_reason", "stop")
        for key in ("reasoning_content", "reasoning"):
            if key in item:
                message[key] = item[key]
        if item.get("tool_calls"):
            message["tool_calls"] = [
                {
                    "id": c.get("id", f"call_{n}_{j}"),
                    "type": "function",
                    "function": {
                        "name": c["name"],
                        "arguments": c["arguments"]
                        if isinstance(c["arguments"], str) or c.get("as_object")
                        else json.dumps(c["arguments"]),
                    },
                }
                for j, c in enumerate(item["tool_calls"])
            ]
            finish = item.get("finish_reason", "tool_calls")
        if "refusal" in item:
            message["refusal"] = item["refusal"]
            message["content"] = None
        if "message" in item:
            message = item["message"]
        prompt_tokens = len(json.dumps(body.get("messages", []))) // 4
        completion_tokens = max(1, len(json.dumps(message)) // 4)
        choices = item.get("choices", [{"index": 0, "message": message, "finish_reason": finish}])
        payload = {
            "id": f"chatcmpl-scripted-{n}",
            "object": "chat.completion",
            "created": int(time.time()),
            "model": body.get("model", "scripted"),
            "choices": choices,
            "usage": item.get(
                "usage",
                {
                    "prompt_tokens": prompt_tokens,
                    "completion_tokens": completion_tokens,
                    "total_tokens": prompt_tokens + completion_tokens,
                },
            ),
        }
        self.responses.append(payload)
        return 200, payload, {}, delay, drip
