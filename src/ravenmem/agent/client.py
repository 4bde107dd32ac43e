"""A thin, retrying client for OpenAI-compatible chat endpoints, with images as data URLs.

The `openai` package does the HTTP; retries are ours (the SDK's are switched off) so that
every attempt is counted, traced and tested: 429, 5xx, timeouts and dropped connections are
retried with exponential backoff up to `max_retries`, then a `VLMError` says what happened.
A 400/404/422 to a request that carried `tools` raises `ToolsRejectedError`, which the agent
takes as "this endpoint has no function calling" and switches to the JSON-in-prompt protocol.
"""

from __future__ import annotations

import base64
import copy
import hashlib
import io
import json
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import RavenmemError
from .config import VLMConfig


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


def image_data_url(image: np.ndarray | str | Path, max_side: int = 0, quality: int = 85) -> str:
    """A JPEG data URL. Files that already are JPEGs (our thumbnails) are sent byte for byte."""
    if isinstance(image, (str, Path)):
        p = Path(image)
        data = p.read_bytes()
        if p.suffix.lower() in (".jpg", ".jpeg") and max_side <= 0:
            return "data:image/jpeg;base64," + base64.b64encode(data).decode("ascii")
        from PIL import Image

        with Image.open(io.BytesIO(data)) as im:
            image = np.asarray(im.convert("RGB"))
    from ..imageio import resize_max_side

    buf = io.BytesIO()
    resize_max_side(np.ascontiguousarray(image), max_side).save(buf, format="JPEG", quality=quality)
    return "data:image/jpeg;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


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


class VLMClient:
    """Sends chat requests; counts requests, retries and tokens; records a redacted trace."""

    def __init__(self, config: VLMConfig, sleep: Callable[[float], None] = time.sleep) -> None:
        if not config.configured:
            raise VLMError(
                "no VLM model configured: set RAVENMEM_VLM_MODEL (and RAVENMEM_VLM_BASE_URL) or pass --model"
            )
        import openai

        self.config = config
        self._sleep = sleep
        self._openai = openai
        self._client = openai.OpenAI(
            base_url=config.base_url, api_key=config.api_key or "EMPTY", timeout=config.timeout, max_retries=0
        )
        self.requests = 0
        self.retries = 0
        self.events: list[dict[str, Any]] = []  # redacted request/response pairs, cleared by the caller

    @property
    def where(self) -> str:
        return f"{self.config.model} at {self.config.base_url or 'api.openai.com'}"

    def chat(
        self,
        messages: list[dict[str, Any]],
        tools: list[dict[str, Any]] | None = None,
        tool_choice: str | None = None,
    ) -> ChatReply:
        """One completion, retried on transient failures; raises VLMError when they persist."""
        cfg = self.config
        kwargs: dict[str, Any] = {
            "model": cfg.model,
            "messages": messages,
            "temperature": cfg.temperature,
            "max_tokens": cfg.max_tokens,
        }
        if tools:
            kwargs["tools"] = tools
            kwargs["tool_choice"] = tool_choice or "auto"
        last = ""
        for attempt in range(cfg.max_retries + 1):
            t0 = time.perf_counter()
            event: dict[str, Any] = {"attempt": attempt, "request": redact_images(kwargs)}
            self.events.append(event)
            self.requests += 1
            retry_after: float | None = None
            try:
                resp = self._client.chat.completions.create(**kwargs)
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
                last = f"timed out after {cfg.timeout:g} s"
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
                self.retries += 1
                wait = min(cfg.backoff_max, cfg.backoff * (2**attempt))
                if retry_after is not None:
                    wait = min(cfg.backoff_max, max(wait, retry_after))
                event["retry_in_s"] = wait
                self._sleep(wait)
        raise VLMError(f"{self.where} failed after {cfg.max_retries + 1} attempt(s): {last}")

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
