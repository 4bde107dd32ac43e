"""The memory as ROS 2 services, `ravenmem_msgs/srv/Ask` and `ravenmem_msgs/srv/Search`, with no
transport in it: request in, reply out (as dicts, or as CDR bytes). The Zenoh link serves them as
queryables (`ros.zenoh`), the ROS 2 node as rclpy services (`ros.node`); both call `ask_reply`
and `search_reply` here, over a `Backend` (the served memory: `ServiceBackend`).

The interface files are the ones a ROS 2 user builds (`ravenmem_msgs/`, next to this module:
`colcon build` it in a workspace); the types are registered in the CDR type store from that
very text, so the bytes here are the bytes a built `ravenmem_msgs` reads.

Key names (how a ROS 2 client's call reaches a Zenoh queryable):
- `zenoh-bridge-ros2dds` routes service `/ravenmem/ask` to key `ravenmem/ask` (behind the
  bridge's `namespace` when it has one): the request is the CDR of `Ask_Request` (its 4-byte
  header, then the fields), the 16-byte DDS request id rides as the query's attachment and the
  bridge puts it back itself; the reply is the CDR of `Ask_Response`. A liveliness token
  `@/<zid>/@ros2_lv/SS/ravenmem§ask/ravenmem_msgs§srv§Ask` announces the server to bridges, so
  they offer it to their ROS 2 graph (`ros2 service list`).
- `rmw_zenoh` puts service `/ravenmem/ask` on `<domain>/ravenmem/ask/ravenmem_msgs::srv::dds_::Ask_/<type hash>`;
  the queryable takes any hash (`*`). Its query attachment is the sequence number (int64), the
  source timestamp (int64) and the client's 16-byte GID; the reply carries the same sequence
  number and GID with this server's timestamp. Not declared: rmw_zenoh's graph liveliness
  token (which needs the REP-2011 type hash), so `ros2 service call` over rmw_zenoh may wait
  for "service availability"; a client that calls without waiting is answered.
"""

from __future__ import annotations

import json
import logging
import math
import struct
import time
from importlib import resources
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from ..agent.ask import AskResult
from ..agent.progress import Progress
from ..errors import RavenmemError, one_line
from ..refusal import refusal_of
from ..runtime.ask import AskArgs
from ..stamps import sec_nanosec
from . import msgs

if TYPE_CHECKING:
    from ..runtime.service import Service

log = logging.getLogger(__name__)

PACKAGE = "ravenmem_msgs"
ASK = f"{PACKAGE}/srv/Ask"
SEARCH = f"{PACKAGE}/srv/Search"
MEMORY = f"{PACKAGE}/msg/Memory"
SERVICES = {"ask": ASK, "search": SEARCH}


def interface_dir() -> Any:
    """The `ravenmem_msgs` package folder (package.xml, CMakeLists.txt, msg/, srv/)."""
    return resources.files("ravenmem.ros") / PACKAGE


def interface_texts() -> dict[str, str]:
    """{type name: .msg text} of every message, request and response in `ravenmem_msgs`."""
    root = interface_dir()
    out: dict[str, str] = {}
    for f in sorted((root / "msg").iterdir(), key=lambda p: p.name):
        if f.name.endswith(".msg"):
            out[f"{PACKAGE}/msg/{f.name[:-4]}"] = f.read_text(encoding="utf-8")
    for f in sorted((root / "srv").iterdir(), key=lambda p: p.name):
        if f.name.endswith(".srv"):
            request, _, response = f.read_text(encoding="utf-8").partition("\n---")
            name = f"{PACKAGE}/srv/{f.name[:-4]}"
            out[f"{name}_Request"], out[f"{name}_Response"] = request, response.lstrip("-")
    return out


def register() -> None:
    """Teach the CDR type store the `ravenmem_msgs` types (idempotent)."""
    msgs.register(interface_texts())


class Backend(Protocol):
    """What the services need of a memory: answer (and plan), search, and its map."""

    def ask(self, args: AskArgs, image: np.ndarray | None, progress: Progress | None = None) -> AskResult:
        """The typed result of a question (with `args.navigate`, its plan); each tool call, as
        it ends, to `progress`."""
        ...

    def answer_json(self, result: AskResult) -> dict[str, Any]:
        """The result as `ravenmem ask --json` gives it (for `answer_json`)."""
        ...

    def search(
        self, tool: str, query: str, k: int, after: str | None, before: str | None, near: list[float] | None
    ) -> list[dict[str, Any]]:
        """Hits in the `--json` shape (`tools.hit_json`)."""
        ...

    @property
    def frame_id(self) -> str: ...


# ------------------------------------------------------------------------- Ask

# the fields of `ravenmem_msgs/srv/Ask`'s request that are `AskArgs` fields, by name (the
# picture is a `sensor_msgs/Image`, decoded here, not a field of the request model)
ASK_FIELDS = ("question", "navigate")


def ask_args_of(request: dict[str, Any]) -> AskArgs:
    """The `AskArgs` of an `Ask_Request` (as a dict), checked at the door like every front end's."""
    return AskArgs.check({k: request[k] for k in ASK_FIELDS if k in request})


def ask_reply(backend: Backend, request: dict[str, Any], progress: Progress | None = None) -> dict[str, Any]:
    """`Ask_Response` (as a dict) for an `Ask_Request` (as a dict): never raises; a question
    that cannot be answered comes back with `found` false and the reason. `progress` hears of
    each tool call as it ends (the question action's feedback)."""
    if not str(request.get("question") or "").strip():
        return {"found": False, "reason": "empty question"}
    try:
        args = ask_args_of(request)
        result = backend.ask(args, _image(request.get("image")), progress)
        data = backend.answer_json(result)
    except RavenmemError as e:
        return {"found": False, "reason": one_line(e)}
    except Exception:  # a robot gets a reason, the log the traceback
        log.exception("ravenmem_msgs/srv/Ask failed")
        return {"found": False, "reason": "internal error; the service log has the details"}
    ans, plan = result.answer, result.plan if args.navigate else None
    reason = ""
    if ans.failed:
        reason = refusal_of(ans) or ""
    elif plan is not None and not plan.ok:
        reason = str(getattr(plan, "reason", "") or "no path")
    elif result.drive is not None and result.drive.get("status") != "succeeded":
        reason = f"the robot did not get there: NavigateToPose {result.drive.get('status')}"
    goal = plan.pose_stamped() if plan is not None and plan.ok else None
    return {
        "answer": ans.text,
        "found": ans.found and not ans.failed,
        "unsupported": ans.unsupported,
        "reason": reason,
        "goal": goal or {},
        "time": stamp(ans.time),
        "map_id": ans.map_id or getattr(plan, "map_id", None) or "",
        "answer_json": json.dumps(data, default=str),
    }


def _image(msg: Any) -> np.ndarray | None:
    """The request's picture as RGB, None when it has none (height 0)."""
    if not isinstance(msg, dict) or not int(msg.get("height") or 0):
        return None
    image = msgs.to_message(msg, msgs.IMAGE)
    rgb = msgs.decode_image(image, msgs.IMAGE)
    if isinstance(rgb, str):
        raise RavenmemError(f"the request's image: {rgb}")
    return rgb


def stamp(t: Any) -> dict[str, int]:
    """`builtin_interfaces/Time` of Unix seconds (zero for none, or for an unusable time)."""
    if not isinstance(t, (int, float)) or not math.isfinite(t) or t < 0:
        return {"sec": 0, "nanosec": 0}
    return sec_nanosec(float(t))


# ------------------------------------------------------------------------- Search


def search_reply(backend: Backend, request: dict[str, Any]) -> dict[str, Any]:
    """`Search_Response` (as a dict) for a `Search_Request`: the hits as `Memory` messages in the
    memory's frame, or `error` with the reason."""
    tool = str(request.get("tool") or "text")
    k = int(request.get("k") or 5)
    near = [float(v) for v in request.get("near") or []]
    if near and len(near) != 3:
        return {"memories": [], "error": "near must be empty or x, y, radius"}
    try:
        rows = backend.search(
            tool,
            str(request.get("query") or ""),
            k,
            request.get("after") or None,
            request.get("before") or None,
            near or None,
        )
    except RavenmemError as e:
        return {"memories": [], "error": one_line(e)}
    except Exception:
        log.exception("ravenmem_msgs/srv/Search failed")
        return {"memories": [], "error": "internal error; the service log has the details"}
    frame = backend.frame_id
    return {"memories": [_memory(r, frame) for r in rows], "error": ""}


def _memory(row: dict[str, Any], frame: str) -> dict[str, Any]:
    yaw = float(row.get("yaw") or 0.0)
    return {
        "id": int(row["id"]),
        "pose": {
            "header": {"stamp": stamp(row.get("t")), "frame_id": frame},
            "pose": {
                "position": {"x": float(row["x"]), "y": float(row["y"]), "z": float(row.get("z") or 0.0)},
                "orientation": {"x": 0.0, "y": 0.0, "z": math.sin(yaw / 2), "w": math.cos(yaw / 2)},
            },
        },
        "score": float(row["score"]) if row.get("score") is not None else 0.0,
        "distance": float(row["distance"]) if row.get("distance") is not None else -1.0,
        "supported": row.get("supported") is not False,  # the text tool's verdict (agent.support)
    }


# ------------------------------------------------------------------------- CDR


def handle(service: str, backend: Backend, payload: bytes) -> bytes:
    """CDR reply for a CDR request of `service` (`ask` or `search`); a request that does not
    decode gets a reply that says so (a robot waiting for an answer gets one)."""
    register()
    srv = SERVICES[service]
    try:
        request = msgs.to_dict(msgs.deserialize(payload, f"{srv}_Request"))
    except Exception as e:  # not CDR of this request type
        log.warning("%s: undecodable request (%s)", srv, e)
        request = None
    if request is None:
        reply = {"reason": "undecodable request"} if service == "ask" else {"error": "undecodable request"}
    elif service == "ask":
        reply = ask_reply(backend, request)
    else:
        reply = search_reply(backend, request)
    return msgs.serialize(msgs.to_message(reply, f"{srv}_Response"), f"{srv}_Response")


def dds_type(srv: str) -> str:
    """The DDS name of a service type, as rmw_zenoh keys carry it: `pkg::srv::dds_::Name_`."""
    pkg, _, name = srv.split("/")
    return f"{pkg}::srv::dds_::{name}_"


def keys(name: str, service: str, domain: int) -> tuple[str, str]:
    """(bridge key, rmw_zenoh key expression) of service `<name>/<service>` (see the module docstring)."""
    base = f"{name.strip('/')}/{service}"
    return base, f"{domain}/{base}/{dds_type(SERVICES[service])}/*"


def bridge_token(zid: str, name: str, service: str) -> str:
    """The liveliness key by which zenoh-bridge-ros2dds learns of a service server (slashes of
    the key and the type written as the bridge escapes them)."""
    esc = "§"
    ke = f"{name.strip('/')}/{service}".replace("/", esc)
    return f"@/{zid}/@ros2_lv/SS/{ke}/{SERVICES[service].replace('/', esc)}"


def rmw_reply_attachment(request_attachment: bytes | None) -> bytes | None:
    """The attachment of a reply to an rmw_zenoh request: its sequence number and GID, this
    server's timestamp (None when the request carried no rmw_zenoh attachment)."""
    if request_attachment is None or len(request_attachment) != 32:
        return None
    seq, _ = struct.unpack_from("<qq", request_attachment)
    return struct.pack("<qq", seq, time.time_ns()) + bytes(request_attachment[16:32])


def rmw_request_attachment(seq: int, gid: bytes) -> bytes:
    """What an rmw_zenoh client attaches to a request (used by the tests' client)."""
    return struct.pack("<qq", int(seq), time.time_ns()) + bytes(gid[:16]).ljust(16, b"\0")


# ------------------------------------------------------------------------- the served memory


class ServiceBackend:
    """The services over a running `ravenmem serve` (`runtime.service.Service`): questions as
    `POST /ask` answers them (the service's method and model), goals from `nav.goals.goal_for`
    (from `start()`, the robot's latest pose, when known), searches through the tools table."""

    def __init__(self, service: Service, start: Any = None, drive: Any = None) -> None:
        self.service = service
        self.start = start or (lambda: None)
        self.drive = drive  # goal -> the NavigateToPose action's result, when the link has one

    @property
    def frame_id(self) -> str:
        return self.service.mem.frame_id

    def ask(self, args: AskArgs, image: np.ndarray | None, progress: Progress | None = None) -> AskResult:
        """`Service.ask`, from the robot's latest pose, driven there when the link can drive."""
        return self.service.ask(args, image, start=self.start(), drive=self.drive, progress=progress)

    def answer_json(self, result: AskResult) -> dict[str, Any]:
        return self.service.result_json(result, lambda rec: None)

    def search(
        self, tool: str, query: str, k: int, after: str | None, before: str | None, near: list[float] | None
    ) -> list[dict[str, Any]]:
        from ..runtime.service import tool_args
        from ..tools import get_tool

        t = get_tool(tool)
        if t.key == "image":
            raise RavenmemError(f"tool {t.name} needs a picture: ask with the HTTP API or MCP instead")
        args = tool_args(t.key, query, "position query", after, before, near if t.key == "text" else None)
        hits = self.service.search(t, t.validate(args), k)
        return self.service.rows(hits, lambda rec: None)
