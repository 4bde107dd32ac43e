"""A thin, retrying client for OpenAI-compatible chat endpoints, with images as data URLs.

The `openai` package does the HTTP (connection pool, auth, status errors, its per-read timeout).
Two things are ours, because the SDK's do not meet the deadlines the agent enforces:
- the wall-clock limit of an attempt: the SDK's timeout is httpx's per-phase (connect, read)
  limit, so a server that drips a byte a second is never cut off; each attempt runs on a worker
  thread that is abandoned (its pool closed) when the attempt's budget is spent;
- the retries: the SDK sleeps its own backoff (0.5 s doubling to 8 s, or up to 60 s when a
  Retry-After says so) without knowing the question's deadline, and counts attempts where we
  cannot trace them. Ours retry 408, 429, 5xx, timeouts and dropped connections with
  `backoff * 2**attempt` (capped, Retry-After honoured up to the cap), never past the deadline.
The reply body is read as text and checked here (`parse_completion`): a 200 that is not JSON, a
choice with `message: null`, arguments written as an object, empty tool call ids (Gemini), usage
numbers written as strings each give a parse or a one-line named `VLMError`, never a traceback.
A 400/404/422 to a request that carried `tools` raises `ToolsRejectedError` (the agent switches to
the JSON-in-prompt protocol); one that carried pictures raises `ImagesRejectedError` when the
config does not say the model has vision (the agent retries once with the memories as text).
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
from pydantic import BaseModel, ConfigDict, ValidationError, field_validator

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


class OutOfTimeError(VLMError):
    """The question's deadline (`question_timeout`) passed before the model answered."""


class ToolsRejectedError(VLMError):
    """The endpoint refused a request because of its `tools` field (no function calling)."""


class ImagesRejectedError(VLMError):
    """The endpoint refused a request that carried pictures (a text-only model)."""


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
    reasoning: str | None = None  # reasoning_content / reasoning / thinking, kept apart from the answer


class _Function(BaseModel):
    model_config = ConfigDict(extra="ignore")
    name: str | None = None
    arguments: Any = None


class _ToolCall(BaseModel):
    model_config = ConfigDict(extra="ignore")
    id: str | None = None
    function: _Function | None = None


class _Message(BaseModel):
    model_config = ConfigDict(extra="ignore")
    content: Any = None
    tool_calls: list[_ToolCall] | None = None
    refusal: str | None = None
    reasoning_content: str | None = None
    reasoning: str | None = None
    thinking: str | None = None


class _Choice(BaseModel):
    model_config = ConfigDict(extra="ignore")
    message: _Message | None = None
    finish_reason: str | None = None


class _Usage(BaseModel):
    model_config = ConfigDict(extra="ignore")
    prompt_tokens: int | None = None
    completion_tokens: int | None = None

    @field_validator("prompt_tokens", "completion_tokens", mode="before")
    @classmethod
    def _count(cls, v: Any) -> Any:
        try:  # "12" as well as 12; anything unreadable counts as unknown, not as a failure
            n = int(float(v))
        except (TypeError, ValueError, OverflowError):
            return None
        return n if 0 <= n < 10**9 else None


class _Completion(BaseModel):
    model_config = ConfigDict(extra="ignore")
    choices: list[_Choice] | None = None
    usage: _Usage | None = None


def parse_completion(body: str, where: str = "the model") -> ChatReply:
    """A chat completion body (text) as a `ChatReply`; a body that is not a usable completion is
    a one-line `VLMError` that says what came back."""
    try:
        raw = json.loads(body)
    except (ValueError, RecursionError):
        raise VLMError(f"{where} answered with a body that is not JSON: {_snippet(body)}") from None
    if not isinstance(raw, dict):
        raise VLMError(f"{where} answered with JSON that is not a completion object: {_snippet(body)}")
    if "error" in raw and not raw.get("choices"):  # some servers report errors with status 200
        err = raw["error"]
        msg = err.get("message") if isinstance(err, dict) else err
        raise VLMError(f"{where} answered with an error: {_snippet(str(msg))}")
    try:
        done = _Completion.model_validate(raw)
    except ValidationError as e:
        first = e.errors()[0]
        loc = ".".join(str(p) for p in first["loc"])
        raise VLMError(f"{where} answered with a malformed completion ({loc}: {first['msg']})") from None
    if not done.choices:
        raise VLMError(f"{where} answered with no choices: {_snippet(body)}")
    choice = done.choices[0]
    msg = choice.message or _Message()
    calls = []
    for i, tc in enumerate(msg.tool_calls or []):
        fn = tc.function
        if fn is None or not fn.name:
            continue
        args = fn.arguments
        if args is None or args == "":
            args = "{}"
        elif not isinstance(args, str):  # an object instead of the JSON text the API specifies
            args = json.dumps(args)
        calls.append(ToolCall(id=tc.id or f"call_{i}", name=str(fn.name), arguments=args))
    usage = done.usage or _Usage()
    return ChatReply(
        content=_text(msg.content),
        tool_calls=calls,
        refusal=msg.refusal,
        finish_reason=choice.finish_reason,
        prompt_tokens=usage.prompt_tokens or 0,
        completion_tokens=usage.completion_tokens or 0,
        raw=raw,
        reasoning=msg.reasoning_content or msg.reasoning or msg.thinking,
    )


def _text(content: Any) -> str | None:
    """Message content as text: a string, or the text of a list of content parts."""
    if content is None or isinstance(content, str):
        return content
    if isinstance(content, list):
        texts = [str(p["text"]) for p in content if isinstance(p, dict) and isinstance(p.get("text"), str)]
        return "".join(texts) if texts else None
    return str(content)


def _snippet(text: str, n: int = 80) -> str:
    return repr(" ".join(str(text).split())[:n])


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


def has_images(messages: Any) -> bool:
    """Whether a request's messages carry a picture (an image_url content part)."""
    return any(
        isinstance(m, dict)
        and isinstance(m.get("content"), list)
        and any(isinstance(p, dict) and p.get("type") == "image_url" for p in m["content"])
        for m in messages
    )


def _flat(message: dict[str, Any]) -> dict[str, Any]:
    """A message whose content parts are all text, with its content as one string: every server
    takes that, while chat templates that concatenate `content` (llama.cpp's GGUF ones) fail on
    a list of parts."""
    parts = message.get("content")
    if isinstance(parts, list) and all(isinstance(p, dict) and p.get("type") == "text" for p in parts):
        return {**message, "content": "\n".join(str(p.get("text", "")) for p in parts)}
    return message


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
        tool_choice: str | dict[str, Any] | None = None,
        *,
        temperature: float | None = None,
        seed: int | None = None,
        deadline: float | None = None,
        response_format: dict[str, Any] | None = None,
    ) -> ChatReply:
        """One completion, retried on transient failures; raises VLMError when they persist.

        `temperature` and `seed` override the config's for this request; `deadline` is a
        `time.monotonic()` instant after which no attempt runs and no wait is slept;
        `response_format` is sent as given (only without tools: see `VLMConfig`).
        """
        cfg = self.config
        kwargs: dict[str, Any] = {
            "model": cfg.model,
            "messages": [_flat(m) for m in messages],
            "temperature": cfg.temperature if temperature is None else temperature,
            "max_tokens": cfg.max_tokens,
        }
        seed = cfg.seed if seed is None else seed
        if seed is not None and cfg.send_seed:
            kwargs["seed"] = seed
        if tools:
            kwargs["tools"] = tools
            if cfg.tool_choice:
                kwargs["tool_choice"] = tool_choice or "auto"
        elif response_format is not None:
            kwargs["response_format"] = response_format
        pictures = has_images(messages)
        refused_500 = 0  # attempts answered 500: how a text-only GGUF chat template refuses pictures
        last = ""
        for attempt in range(cfg.max_retries + 1):
            budget = cfg.timeout
            if deadline is not None:
                budget = min(budget, deadline - time.monotonic())
                if budget <= 0:
                    raise OutOfTimeError(f"{self.where}: out of time for this question{_after(last)}")
            t0 = time.perf_counter()
            event: dict[str, Any] = {"attempt": attempt, "request": redact_images(kwargs)}
            self.events.append(event)
            self.requests += 1
            retry_after: float | None = None
            body = ""
            try:
                body = self._attempt(kwargs, budget)
                reply = parse_completion(body, self.where)
            except _Deadline:
                last = f"timed out after {budget:.3g} s (no complete reply within the time limit)"
                event["error"] = last
            except self._openai.APIStatusError as e:
                status = e.status_code
                last = f"HTTP {status}: {_error_text(e)}"
                event["error"] = last
                if status in (400, 404, 415, 422) and pictures and cfg.vision is None:
                    raise ImagesRejectedError(f"{self.where} refused a request with pictures ({last})") from e
                refused_500 += status == 500
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
            except VLMError as e:  # a 200 that is not a usable completion: a proxy page, a torn body
                last = str(e).removeprefix(f"{self.where} answered with ")
                event["error"] = last
                if body:
                    event["response_text"] = body[:2000]
            else:
                event["elapsed_s"] = round(time.perf_counter() - t0, 3)
                event["response"] = reply.raw
                return reply
            event["elapsed_s"] = round(time.perf_counter() - t0, 3)
            if attempt < cfg.max_retries:
                wait = min(cfg.backoff_max, cfg.backoff * (2**attempt))
                if retry_after is not None:
                    wait = min(cfg.backoff_max, max(wait, retry_after))
                if deadline is not None and time.monotonic() + wait >= deadline:
                    raise OutOfTimeError(f"{self.where}: out of time for this question{_after(last)}")
                self.retries += 1
                event["retry_in_s"] = wait
                self._sleep(wait)
        if pictures and cfg.vision is None and refused_500 == cfg.max_retries + 1:
            # llama-cpp-python's server answers 500 ("can only concatenate str (not "list") to
            # str") when a text-only model's chat template meets image parts: a 500 that every
            # retry repeats, to a request with pictures, is taken as a refusal of the pictures
            raise ImagesRejectedError(f"{self.where} refused a request with pictures ({last})")
        raise VLMError(f"{self.where} failed after {cfg.max_retries + 1} attempt(s): {last}")

    def _attempt(self, kwargs: dict[str, Any], budget: float) -> str:
        """One HTTP request, given at most `budget` seconds of wall-clock time; the body as text."""
        client = self._client
        box: dict[str, Any] = {}
        done = threading.Event()

        def work() -> None:
            try:
                raw = client.with_options(timeout=budget).chat.completions.with_raw_response.create(**kwargs)
                box["reply"] = raw.http_response.text
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
        return str(box["reply"])

    def close(self) -> None:
        self._client.close()


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
