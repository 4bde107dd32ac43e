"""The one request for asking: `AskArgs`, declared once, checked once at the door.

Every front end takes a question through this model, as every search goes through
`ravenmem.tools`: the HTTP body of `POST /ask` is `AskArgs` itself (its OpenAPI schema is made
from it), the MCP `ask` tool's input schema is `input_schema()`, a `ravenmem_msgs/srv/Ask`
request maps its fields onto it (`ros.services.ask_args_of`), `ravenmem ask` has one option per
field (`cli.agent.ASK_OPTIONS`, tied to it by a test) and `ravenmem ask --server` sends it as
the body. A value that is wrong (an unknown method or preset, a k out of range, a question
longer than `MAX_QUESTION`) is one line (`check`), whatever the method. The method's name is
checked where the options are made (`to_options`, `MethodOptions.check`: plugins register
methods by name, and a method that needs a model the service lacks is refused there too).

It lives in `runtime/`, not in `agent/`: it names what the application core does around the
agent (navigate to the answer, from where, with which robot radius) and which picture to ask
with (a stored memory's, or an upload), which the agent knows nothing of; `to_options` is
where it becomes the agent's own `MethodOptions`. The model endpoint (URL, key, provider,
timeouts) is never part of a request: a service uses its own, the CLI reads its flags.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Annotated, Any, Literal

from pydantic import (
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    ValidationError,
    WithJsonSchema,
    field_validator,
    model_validator,
)
from pydantic.json_schema import GenerateJsonSchema

from ..agent.ask import MethodOptions
from ..agent.base import METHODS
from ..agent.presets import PRESETS, get_preset
from ..errors import InputError
from ..memory.protocol import MAX_K, check_k
from ..tools import TOOLS
from ..types import MAX_COORD, MAX_ID, check_coord, check_id

if TYPE_CHECKING:
    from ..agent.config import VLMConfig

MAX_QUESTION = 4000  # characters: a question, not a document (a 100 kB "question" is refused)
MAX_CALLS = 20  # tool calls a question may ask for
TimeMode = Literal["forward", "centred", "nearest"]

_K = {"type": "integer", "minimum": 1, "maximum": MAX_K}
TOP_K_SCHEMA: dict[str, Any] = {
    "anyOf": [
        _K,
        {
            "type": "object",
            "properties": {t: _K for t in (*(x.key for x in TOOLS.values()), *TOOLS)},
            "additionalProperties": False,
        },
    ],
    "description": f"memories per tool call: N, or per tool {{'text': 30, 'time': 200}} (1 to {MAX_K})",
}


def check_top_k(top_k: object) -> int | dict[str, int] | None:
    """Memories per tool call: None, N, or {tool: N} for at most the four tools (N from 1 to
    MAX_K); tool names are checked by the agent."""
    if top_k is None:
        return None
    if isinstance(top_k, dict):
        if not 1 <= len(top_k) <= len(TOOLS):
            raise InputError(f"top_k: give N or {{tool: N}} for up to {len(TOOLS)} tools")
        return {str(name): check_k(k) for name, k in top_k.items()}
    return check_k(top_k)


def check_calls(calls: object) -> int | None:
    if calls is None:
        return None
    if isinstance(calls, bool) or not isinstance(calls, int) or not 1 <= calls <= MAX_CALLS:
        raise InputError(f"max_tool_calls must be a whole number from 1 to {MAX_CALLS}, got {calls!r}")
    return calls


TopK = Annotated[int | dict[str, int], BeforeValidator(check_top_k), WithJsonSchema(TOP_K_SCHEMA)]


class AskArgs(BaseModel):
    """One question and how to answer it. Every field but `question` may be left out: the
    service's defaults, then the preset's, then the method's apply."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    question: str = Field(..., min_length=1, max_length=MAX_QUESTION, description="the question")
    image: str | None = Field(None, description="a query picture: base64 JPEG/PNG or a data: URL")
    image_memory_id: Annotated[int, BeforeValidator(check_id)] | None = Field(
        None, description="use this memory's picture as the query picture (instead of image)"
    )
    method: str | None = Field(
        None, description="how to answer: raven | offline | embedder-only | vlm-only | caption | random"
    )
    preset: str | None = Field(
        None, description="the paper's settings for a benchmark (budget, k per tool, temperature)"
    )
    top_k: TopK | None = None
    max_tool_calls: int | None = Field(
        None, ge=1, le=MAX_CALLS, description="tool calls before the model must answer"
    )
    temperature: float | None = Field(
        None, ge=0, le=2, allow_inf_nan=False, description="sampling temperature sent to the model"
    )
    seed: int | None = Field(
        None, ge=0, le=MAX_ID, description="seed sent to the model (and the random baseline)"
    )
    show_scores: bool | None = Field(
        None, description="show similarity scores and distances to the model (default true)"
    )
    time_mode: TimeMode | None = Field(None, description="the time tool's window (default forward)")
    frames: int | None = Field(None, ge=1, le=1_000_000, description="vlm-only: most frames in the prompt")
    image_max_side: int | None = Field(
        None, ge=0, le=8192, description="longest side in px of pictures sent to the model (0 = as stored)"
    )
    max_position_offset: float | None = Field(
        None,
        ge=0,
        le=4 * MAX_COORD,
        allow_inf_nan=False,
        description="metres from every memory shown beyond which a model's position is unsupported",
    )
    navigate: bool = Field(
        False, description="also plan a path on the memory's map to the answer (its goal: `navigation`)"
    )
    start: tuple[float, float] | None = Field(
        None, description="with navigate: the start [x, y] in map metres (default: the robot's latest pose)"
    )
    robot_radius: float | None = Field(
        None, ge=0, le=10, allow_inf_nan=False, description="with navigate: robot radius in metres"
    )
    allow_unsupported: bool = Field(
        False,
        description="use (and drive to) a position farther than the support threshold from every "
        "memory the model was shown; without it such an answer is refused",
    )

    @field_validator("question")
    @classmethod
    def _question(cls, v: str) -> str:
        if not v.strip():
            raise ValueError("must not be blank")
        return v.strip()

    @field_validator("preset")
    @classmethod
    def _preset(cls, v: str | None) -> str | None:
        get_preset(v)
        return v

    @field_validator("start")
    @classmethod
    def _start(cls, v: tuple[float, float] | None) -> tuple[float, float] | None:
        if v is None:
            return None
        x, y = (check_coord(c, "start") for c in v)
        return (x, y)

    @model_validator(mode="after")
    def _together(self) -> AskArgs:
        if self.image is not None and self.image_memory_id is not None:
            raise ValueError("give image or image_memory_id, not both")
        if not self.navigate and (self.start is not None or self.robot_radius is not None):
            raise ValueError("start and robot_radius apply with navigate only")
        return self

    # ---------------------------------------------------------------- at the door
    @classmethod
    def check(cls, data: Any) -> AskArgs:
        """`data` (a mapping: a JSON body, MCP arguments, a message's fields) as `AskArgs`, or a
        one-line `InputError` naming the field."""
        if isinstance(data, AskArgs):
            return data
        if not isinstance(data, dict):
            raise InputError("ask: the arguments must be an object with at least a question")
        try:
            return cls.model_validate(data)
        except ValidationError as e:
            raise InputError(f"ask: {one_line(e)}") from None

    def given(self) -> dict[str, Any]:
        """The fields set, as JSON (what `ravenmem ask --server` sends)."""
        return self.model_dump(mode="json", exclude_defaults=True)

    def to_options(self, default_method: str, vlm: VLMConfig | None = None, **defaults: Any) -> MethodOptions:
        """The agent's `MethodOptions`: the request's own values, then `defaults` (a service's
        preset, top_k and max_tool_calls), then the preset's and the method's."""
        mine = {
            k: getattr(self, k)
            for k in ("preset", "top_k", "max_tool_calls", "temperature", "seed", "show_scores")
            + ("time_mode", "frames", "image_max_side", "max_position_offset")
        }
        given = {k: v for k, v in mine.items() if v is not None}
        merged = {k: v for k, v in defaults.items() if v is not None} | given
        return MethodOptions.of(self.method or default_method, vlm=vlm, **merged).check()


def one_line(e: ValidationError) -> str:
    """A pydantic error as one line: `field: what is wrong`."""
    err = e.errors()[0]
    where = ".".join(str(p) for p in err.get("loc", ()) if not isinstance(p, int)) or "arguments"
    msg = str(err.get("msg", "invalid")).removeprefix("Value error, ")
    return " ".join(f"{where}: {msg}".split())


class _NoNulls(GenerateJsonSchema):
    """Optional fields as the plain type (leaving a field out is how a client says "default"),
    which is what MCP clients and models read best."""

    def nullable_schema(self, schema: Any) -> Any:
        return self.generate_inner(schema["schema"])


def input_schema() -> dict[str, Any]:
    """`AskArgs` as the JSON schema of a tool's input (the MCP `ask` tool): no null branches,
    the methods and presets known now as enums."""
    schema = AskArgs.model_json_schema(schema_generator=_NoNulls)
    props = schema["properties"]
    for p in props.values():
        p.pop("title", None)
        if p.get("default") is None:
            p.pop("default", None)
    props["method"]["enum"] = METHODS.names()
    props["preset"]["enum"] = sorted(PRESETS)
    schema.pop("title", None)
    schema["additionalProperties"] = False
    return schema
