"""Where the VLM lives: base URL, model and key from flags > environment > config file.

One config shape for every OpenAI-compatible endpoint (vLLM, Ollama, OpenAI, Gemini's
OpenAI-compatible URL). The config file is `~/.config/ravenmem/config.toml` (or
`$XDG_CONFIG_HOME/ravenmem/config.toml`, or the file named by `$RAVENMEM_CONFIG`), section `[vlm]`
with the same keys as `VLMConfig`.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any, Literal
from urllib.parse import urlsplit

from ..errors import InputError
from ..fsio import MAX_CONFIG, read_text

ToolMode = Literal["auto", "native", "json"]
TOOL_MODES = ("auto", "native", "json")
ResponseFormat = Literal["none", "json_object", "json_schema", "json_object_schema"]
RESPONSE_FORMATS = ("none", "json_object", "json_schema", "json_object_schema")

# What each server documents, as settings (explicit settings win; nothing is guessed from a URL):
# - openai, vllm: `response_format` {"type": "json_schema"} (vLLM enforces it by guided decoding);
# - ollama: /v1 takes `response_format` json_schema (Ollama >= 0.5) but ignores `tool_choice`, so
#   after the tool budget no tools are offered at all instead of trusting "none";
# - llama.cpp (llama-cpp-python's server and llama-server): "auto" tool choice gives prose with
#   most GGUF chat templates, a tool_choice naming a function gives a grammar-constrained call,
#   and `response_format` {"type": "json_object", "schema": ...} is enforced by a grammar: the
#   JSON-in-prompt protocol with every step constrained to a tool call or the answer, the first
#   step to a search_text call (a 135M model otherwise answers before it has looked); its server
#   refuses OpenAI's {"type": "json_schema"} form (a validation error, as HTTP 500), and a text
#   model's chat template refuses image parts with HTTP 500;
# - gemini (its OpenAI-compatible URL): `seed` is refused ("Unknown name seed"), tool call ids
#   come back empty (the client numbers them), and `response_format` cannot be combined with
#   tools (it is only sent on requests without tools, for every provider).
PROVIDERS: dict[str, dict[str, Any]] = {
    "openai": {"response_format": "json_schema"},
    "vllm": {"response_format": "json_schema"},
    "ollama": {"response_format": "json_schema", "tool_choice": False},
    "llama.cpp": {"tool_mode": "json", "response_format": "json_object_schema", "first_tool": "search_text"},
    "gemini": {"response_format": "json_schema", "send_seed": False},
}
DEFAULTS: dict[str, Any] = {
    "tool_mode": "auto",
    "response_format": "none",
    "send_seed": True,
    "tool_choice": True,
    "first_tool": None,
}

ENV_KEYS = {
    "base_url": "RAVENMEM_VLM_BASE_URL",
    "model": "RAVENMEM_VLM_MODEL",
    "api_key": "RAVENMEM_VLM_API_KEY",
    "timeout": "RAVENMEM_VLM_TIMEOUT",
    "max_retries": "RAVENMEM_VLM_MAX_RETRIES",
    "tool_mode": "RAVENMEM_VLM_TOOL_MODE",
    "question_timeout": "RAVENMEM_VLM_QUESTION_TIMEOUT",
    "max_tokens": "RAVENMEM_VLM_MAX_TOKENS",
    "provider": "RAVENMEM_VLM_PROVIDER",
    "vision": "RAVENMEM_VLM_VISION",
    "response_format": "RAVENMEM_VLM_RESPONSE_FORMAT",
}


@dataclass
class VLMConfig:
    """Connection and retry settings for one OpenAI-compatible chat endpoint.

    `timeout` is the wall-clock limit of one HTTP attempt, from connecting to the last byte of
    the reply (not a per-read limit: a server that drips a byte every second is cut off too).
    `question_timeout` bounds one whole question: every model turn, retry and backoff wait.
    `max_retries` counts retries after the first attempt (on 429, 5xx, timeouts and dropped
    connections); waits grow as `backoff * 2**attempt`, capped at `backoff_max`, honour a
    server's Retry-After when it is shorter than the cap, and never run past the deadline.
    `tool_mode` picks native function calling, a JSON-in-prompt protocol, or `auto` (native,
    switching to JSON when the endpoint rejects the `tools` field). `temperature` and `seed`
    are sent with every request (`seed` only when set and `send_seed`; not every server honours it).

    `provider` (openai | vllm | ollama | llama.cpp | gemini) fills in the settings below that are
    left unset with what that server documents (`PROVIDERS`); explicit settings win.
    `vision`: True sends pictures, False describes every memory as text (time, pose, score, OCR
    text, labels), None sends pictures and falls back to text, once, when the server refuses
    them. `response_format` constrains the replies of requests that offer no tools: "json_schema"
    (OpenAI's form), "json_object_schema" (llama.cpp's `{"type": "json_object", "schema": ...}`),
    "json_object" (any JSON) or "none". `tool_choice` False: the server ignores `tool_choice`
    (Ollama), so no tools are offered once the budget is spent. `first_tool` names a tool the
    model must call first (sent as a tool_choice naming it; llama.cpp constrains its arguments).
    """

    base_url: str | None = None
    model: str | None = None
    api_key: str | None = None
    timeout: float = 60.0
    question_timeout: float = 300.0
    max_retries: int = 3
    backoff: float = 1.0
    backoff_max: float = 20.0
    tool_mode: ToolMode | None = None
    temperature: float = 0.0
    seed: int | None = None
    max_tokens: int = 1024
    image_detail: str | None = None  # OpenAI's "low" | "high" | "auto"; None = not sent
    provider: str | None = None
    vision: bool | None = None
    response_format: ResponseFormat | None = None
    send_seed: bool | None = None
    tool_choice: bool | None = None
    first_tool: str | None = None

    def __post_init__(self) -> None:
        if self.provider is not None and self.provider not in PROVIDERS:
            raise InputError(f"vlm provider must be one of {', '.join(PROVIDERS)}, got {self.provider!r}")
        profile = PROVIDERS.get(self.provider or "", {})
        for key, default in DEFAULTS.items():
            if getattr(self, key) is None:
                setattr(self, key, profile.get(key, default))
        if self.response_format not in RESPONSE_FORMATS:
            raise InputError(
                f"vlm response_format must be one of {', '.join(RESPONSE_FORMATS)}, got {self.response_format!r}"
            )
        if self.first_tool in ("", "none"):  # "none" undoes a provider's first tool
            self.first_tool = None
        if self.first_tool is not None:
            from ..tools import get_tool

            self.first_tool = get_tool(self.first_tool).name  # an unknown tool is a one-line error
        if self.tool_mode not in TOOL_MODES:
            raise InputError(f"vlm tool_mode must be one of {', '.join(TOOL_MODES)}, got {self.tool_mode!r}")
        for name in ("timeout", "question_timeout"):
            value = getattr(self, name)
            if not math.isfinite(value) or value <= 0:
                raise InputError(f"vlm {name} must be a finite number of seconds > 0, got {value}")
        if not math.isfinite(self.temperature) or not 0 <= self.temperature <= 2:
            raise InputError(f"vlm temperature must be from 0 to 2, got {self.temperature}")
        if self.max_retries < 0:
            raise InputError(f"vlm max_retries must be >= 0, got {self.max_retries}")
        if self.backoff < 0 or self.backoff_max < 0:
            raise InputError("vlm backoff values must be >= 0")

    @property
    def configured(self) -> bool:
        """A model name is the one thing we cannot guess; without it there is no VLM."""
        return bool(self.model)

    @property
    def host(self) -> str:
        """host[:port] of the endpoint, without any user name or password in the URL."""
        if not self.base_url:
            return "api.openai.com"
        u = urlsplit(self.base_url)
        if not u.hostname:
            return self.base_url.split("/")[0]
        return u.hostname + (f":{u.port}" if u.port else "")

    def public(self) -> dict[str, Any]:
        """The settings without the key (for traces and reports)."""
        d = asdict(self)
        d["api_key"] = "***" if self.api_key else None
        return d

    @classmethod
    def resolve(
        cls,
        config_path: str | os.PathLike[str] | None = None,
        env: Mapping[str, str] | None = None,
        **flags: Any,
    ) -> VLMConfig:
        """Merge flags (non-None values win) over environment over the config file."""
        env = os.environ if env is None else env
        merged: dict[str, Any] = dict(_read_file(_config_file(config_path, env)))
        for key, var in ENV_KEYS.items():
            if env.get(var):
                merged[key] = env[var]
        if not merged.get("api_key") and env.get("OPENAI_API_KEY"):
            merged["api_key"] = env["OPENAI_API_KEY"]
        merged.update({k: v for k, v in flags.items() if v is not None})
        return cls(**_coerce(merged, "vlm settings"))


def _config_file(path: str | os.PathLike[str] | None, env: Mapping[str, str]) -> Path | None:
    if path is not None:
        p = Path(path)
        if not p.exists():
            raise InputError(f"config file {p} does not exist")
        return p
    if env.get("RAVENMEM_CONFIG"):
        return Path(env["RAVENMEM_CONFIG"])
    base = Path(env["XDG_CONFIG_HOME"]) if env.get("XDG_CONFIG_HOME") else Path.home() / ".config"
    return base / "ravenmem" / "config.toml"


def _read_file(path: Path | None) -> dict[str, Any]:
    if path is None or not path.exists():
        return {}
    try:
        import tomllib
    except ModuleNotFoundError:  # pragma: no cover - Python 3.10
        import tomli as tomllib  # type: ignore[no-redef]
    try:
        data = tomllib.loads(read_text(path, MAX_CONFIG, "config file"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise InputError(f"{path}: not valid TOML ({e})") from e
    section = data.get("vlm", {})
    if not isinstance(section, dict):
        raise InputError(f"{path}: [vlm] must be a table")
    unknown = set(section) - {f.name for f in fields(VLMConfig)}
    if unknown:
        raise InputError(f"{path}: unknown key(s) in [vlm]: {', '.join(sorted(unknown))}")
    return _coerce(section, f"{path} [vlm]")


def _coerce(values: Mapping[str, Any], where: str) -> dict[str, Any]:
    """Turn strings from env/files into the field types, naming the field that is wrong."""
    types = {f.name: f.type for f in fields(VLMConfig)}
    out: dict[str, Any] = {}
    for key, val in values.items():
        if key not in types:
            raise InputError(f"{where}: unknown setting {key!r}")
        kind = str(types[key])
        try:
            if val is None:
                out[key] = None
            elif kind.startswith("bool"):
                out[key] = _bool(val)
            elif kind.startswith("float"):
                out[key] = float(val)
            elif kind.startswith("int"):
                out[key] = int(val)
            else:
                out[key] = str(val)
        except (TypeError, ValueError) as e:
            raise InputError(f"{where}: {key} = {val!r} is not a valid {kind}") from e
    return out


def _bool(val: Any) -> bool | None:
    if isinstance(val, bool):
        return val
    word = str(val).strip().lower()
    if word in ("auto", ""):
        return None
    if word in ("1", "true", "yes", "on"):
        return True
    if word in ("0", "false", "no", "off"):
        return False
    raise ValueError(word)
