"""A thin, retrying client for OpenAI-compatible chat endpoints, with images as data URLs.

The `openai` package does the HTTP; retries are ours (the SDK's are switched off) so that
every attempt is counted, traced and tested: 429, 5xx, timeouts and dropped connections are
retried with exponential backoff up to `max_retries`, then a `VLMError` says what happened.
Time is bounded in wall clock, not per read: each attempt gets at most `timeout` seconds and
the caller's deadline (the agent's per-question limit) cuts attempts and waits short.
A 400/404/422 to a request that carried `tools` raises `ToolsRejectedError`, which the agent
takes as "this endpoint has no function calling" and switches to the JSON-in-prompt protocol.
"""

from __future__ import annotations

import contextlib
import copy
import hashlib
import json
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InputError, RavenmemError
from .config import VLMConfig
from .images import data_url, jpeg_of_array, jpeg_of_bytes

MAX_REPLY_BYTES = 16 * 1024 * 1024  # a chat completion is kilobytes; more is not a reply
NO_MODEL = (
    "no VLM model configured: pass --model (and --base-url), or set RAVENMEM_VLM_MODEL "
    "(and RAVENMEM_VLM_BASE_URL), or put them in [vlm] of ~/.config/ravenmem/config.toml; "
    "use --offline for the model-free reasoner"
)


class VLMError(RavenmemError):
    """The VLM could not be reached or kept failing; the message says how and how often."""


class ToolsRejectedError(VLMError):
    """The endpoint refused a request because of its `tools` field (no function calling)."""


@dataclass
class ToolCall:
    id: str
    name: str
    arguments: str  # JSON text exactly as the model wrote it


@dataclass
class ChatReply:
    content: str | None
    tool_calls: list[ToolCall] = field(default_factory=list)
    refusal: str | None = None
    finish_reason: str | None = None
    prompt_tokens: int = 0
    completion_tokens: int = 0
    raw: dict[str, Any] = field(default_factory=dict)


def image_data_url(image: np.ndarray | str | Path, max_side: int = 0) -> str:
    """A JPEG data URL of an array or an image file (a JPEG that fits is sent byte for byte);
    a file that does not decode as an image is an `InputError`."""
    if isinstance(image, (str, Path)):
        try:
            data = Path(image).read_bytes()
        except OSError as e:
            raise InputError(f"image file {image} cannot be read: {e}") from e
        jpeg = jpeg_of_bytes(data, max_side)
        if jpeg is None:
            raise InputError(f"image file {image} is not an image that can be decoded")
        return data_url(jpeg)
    return data_url(jpeg_of_array(image, max_side))


def redact_images(messages: Any) -> Any:
    """A copy of a request with every data URL replaced by its size and digest (for traces)."""
    out = copy.deepcopy(messages)

    def walk(node: Any) -> None:
        if isinstance(node, dict):
            for k, v in node.items():
                if k == "url" and isinstance(v, str) and v.startswith("data:"):
                    raw = v.split(",", 1)[-1]
                    digest = hashlib.sha1(raw.encode("ascii")).hexdigest()[:12]
                    node[k] = f"<{v[5 : v.find(';')]} {len(raw) * 3 // 4} bytes sha1:{digest}>"
                else:
                    walk(v)
        elif isinstance(node, list):
            for v in node:
                walk(v)

    walk(out)
    return out


class _Deadline(Exception):
    """An attempt ran out of wall-clock time (raised in the caller, not the worker)."""


class VLMClient:
    """Sends chat requests; counts requests, retries and tokens; records a redacted trace.

    Every attempt runs on a worker thread that the caller waits on for at most the attempt's
    budget (`timeout`, cut to what is left before `deadline`); when the budget is spent the
    connection pool is closed, which aborts the worker's socket, and the attempt counts as
    timed out. So a reply is bounded in wall-clock time, not just per read.
    """

    def __init__(self, config: VLMConfig, sleep: Callable[[float], None] = time.sleep) -> None:
        if not config.configured:
            raise InputError(NO_MODEL)
        import openai

        self.config = config
        self._sleep = sleep
        self._openai = openai
        self._client = self._make_client()
        self.requests = 0
        self.retries = 0
        self.events: list[dict[str, Any]] = []  # redacted request/response pairs, cleared by the caller

    def _make_client(self) -> Any:
        cfg = self.config
        http = self._openai.DefaultHttpxClient(event_hooks={"response": [_check_reply_size]})
        return self._openai.OpenAI(
            base_url=cfg.base_url,
            api_key=cfg.api_key or "EMPTY",
            timeout=cfg.timeout,
            max_retries=0,
            http_client=http,
        )

    @property
    def where(self) -> str:
        return f"{self.config.model} at {self.config.base_url or 'api.openai.com'}"

    def chat(
        self,
        messages: list[dict[str, Any]],
        tools: list[dict[str, Any]] | None = None,
        tool_choice: str | None = None,
        *,
        temperature: float | None = None,
        seed: int | None = None,
        deadline: float | None = None,
    ) -> ChatReply:
        """One completion, retried on transient failures; raises VLMError when they persist.

        `temperature` and `seed` override the config's for this request; `deadline` is a
        `time.monotonic()` instant after which no attempt runs and no wait is slept.
        """
        cfg = self.config
        kwargs: dict[str, Any] = {
            "model": cfg.model,
            "messages": messages,
            "temperature": cfg.temperature if temperature is None else temperature,
            "max_tokens": cfg.max_tokens,
        }
        seed = cfg.seed if seed is None else seed
        if seed is not None:
            kwargs["seed"] = seed
        if tools:
            kwargs["tools"] = tools
            kwargs["tool_choice"] = tool_choice or "auto"
        last = ""
        for attempt in range(cfg.max_retries + 1):
            budget = cfg.timeout
            if deadline is not None:
                budget = min(budget, deadline - time.monotonic())
                if budget <= 0:
                    raise VLMError(f"{self.where}: out of time for this question{_after(last)}")
            t0 = time.perf_counter()
            event: dict[str, Any] = {"attempt": attempt, "request": redact_images(kwargs)}
            self.events.append(event)
            self.requests += 1
            retry_after: float | None = None
            try:
                resp = self._attempt(kwargs, budget)
            except _Deadline:
                last = f"timed out after {budget:.3g} s (no complete reply within the time limit)"
                event["error"] = last
            except self._openai.APIStatusError as e:
                status = e.status_code
                last = f"HTTP {status}: {_error_text(e)}"
                event["error"] = last
                if tools and status in (400, 404, 422):
                    raise ToolsRejectedError(f"{self.where} rejected the tools field ({last})") from e
                if status != 429 and status < 500 and status != 408:
                    raise VLMError(f"{self.where} refused the request: {last}") from e
                retry_after = _retry_after(e)
            except self._openai.APITimeoutError:
                last = f"timed out after {budget:.3g} s (no complete reply within the time limit)"
                event["error"] = last
            except self._openai.APIConnectionError as e:
                last = f"connection failed ({e.__cause__ or e})"
                event["error"] = last
            except (self._openai.APIResponseValidationError, json.JSONDecodeError) as e:
                last = f"malformed response body ({str(e)[:120]})"
                event["error"] = last
            else:
                event["elapsed_s"] = round(time.perf_counter() - t0, 3)
                return self._reply(resp, event)
            event["elapsed_s"] = round(time.perf_counter() - t0, 3)
            if attempt < cfg.max_retries:
                wait = min(cfg.backoff_max, cfg.backoff * (2**attempt))
                if retry_after is not None:
                    wait = min(cfg.backoff_max, max(wait, retry_after))
                if deadline is not None and time.monotonic() + wait >= deadline:
                    raise VLMError(f"{self.where}: out of time for this question{_after(last)}")
                self.retries += 1
                event["retry_in_s"] = wait
                self._sleep(wait)
        raise VLMError(f"{self.where} failed after {cfg.max_retries + 1} attempt(s): {last}")

    def _attempt(self, kwargs: dict[str, Any], budget: float) -> Any:
        """One HTTP request, given at most `budget` seconds of wall-clock time."""
        client = self._client
        box: dict[str, Any] = {}
        done = threading.Event()

        def work() -> None:
            try:
                box["reply"] = client.with_options(timeout=budget).chat.completions.create(**kwargs)
            except BaseException as e:  # handed to the caller below
                box["error"] = e
            finally:
                done.set()

        threading.Thread(target=work, name="ravenmem-vlm-request", daemon=True).start()
        if not done.wait(budget):
            self._client = self._make_client()
            with contextlib.suppress(Exception):  # closing a half-used pool must not hide the timeout
                client.close()  # aborts the worker's socket; its late error is ignored
            raise _Deadline
        if "error" in box:
            raise box["error"]
        return box["reply"]

    def close(self) -> None:
        self._client.close()

    def _reply(self, resp: Any, event: dict[str, Any]) -> ChatReply:
        raw = resp.model_dump(exclude_none=True) if hasattr(resp, "model_dump") else dict(resp)
        event["response"] = raw
        if not getattr(resp, "choices", None):
            raise VLMError(f"{self.where} answered with no choices: {str(raw)[:200]}")
        choice = resp.choices[0]
        msg = choice.message
        calls = [
            ToolCall(id=tc.id or f"call_{i}", name=tc.function.name, arguments=tc.function.arguments or "{}")
            for i, tc in enumerate(msg.tool_calls or [])
            if getattr(tc, "function", None) is not None
        ]
        usage = resp.usage
        return ChatReply(
            content=msg.content,
            tool_calls=calls,
            refusal=getattr(msg, "refusal", None),
            finish_reason=choice.finish_reason,
            prompt_tokens=int(getattr(usage, "prompt_tokens", 0) or 0),
            completion_tokens=int(getattr(usage, "completion_tokens", 0) or 0),
            raw=raw,
        )


def _after(last: str) -> str:
    return f" (last error: {last})" if last else ""


def _check_reply_size(response: Any) -> None:
    """Refuse a reply that announces a body larger than MAX_REPLY_BYTES before reading it."""
    size = response.headers.get("content-length")
    if size is not None and size.isdigit() and int(size) > MAX_REPLY_BYTES:
        raise VLMError(f"the reply announces {int(size)} bytes, over the {MAX_REPLY_BYTES}-byte limit")


def _error_text(e: Any) -> str:
    body = getattr(e, "body", None)
    if isinstance(body, dict):
        err = body.get("error", body)
        msg = err.get("message") if isinstance(err, dict) else err
        if msg:
            return str(msg)[:300]
    return str(getattr(e, "message", e))[:300]


def _retry_after(e: Any) -> float | None:
    try:
        value = e.response.headers.get("retry-after")
        return float(value) if value is not None else None
    except (AttributeError, TypeError, ValueError):
        return None
