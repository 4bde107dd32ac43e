"""`ravenmem ros run --lifecycle`: the node as a managed (lifecycle) node, brought up the way a
Nav2 stack brings up its own (`nav2_lifecycle_manager`, `ros2 lifecycle set`, or any client of
`lifecycle_msgs/srv/ChangeState` on `/ravenmem/change_state`).

    unconfigured --configure--> inactive --activate--> active
                 <--cleanup---           <--deactivate--
    any of them  --shutdown---> finalized (the process exits 0; SIGINT/SIGTERM do the same)

- configure: read the parameters (declared when the node is made, so `ros2 param set` works
  before), open the memory (`--create`: create it when missing), make the publishers, the
  services and the question action, warm the embedder up. A memory that cannot be opened (or a
  parameter the node cannot use) fails the transition with one line in the log; the node stays
  unconfigured and may be configured again.
- activate: subscribe to the cameras, odometry or /tf, the camera info and the map; frames are
  stored.
- deactivate: the subscriptions go (an inactive node takes no bandwidth); an image already
  delivered is counted skipped (`node inactive`); the images waiting for their pose and those
  queued for the writer are stored (or skipped with their reason) before the transition ends.
- cleanup: the run's counts noted in the manifest, the memory closed (everything written is on
  disk, the writer lock released: `ravenmem info` or another writer may open it), the
  publishers, services and action gone.
- shutdown, from any state: as deactivate and cleanup, then the process exits 0.

While inactive, `~/ask`, `~/search` and `~/ask_action` still answer from the memory (reading
moves nothing), but a question that asks to navigate is refused (`found` false, `reason` says
the node is inactive): an inactive node sends no goal. /diagnostics is published in both
configured states.

Each transition runs in the node's default callback group, which the pose, map and camera-info
callbacks and the settling tick share (`RavenmemNode(sensors=...)`), so none of them runs in
the middle of a transition. The process around the node (arguments, rclpy, the executor) is
`ros.run`, the same as for the plain node.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn

from ..agent.ask import AskResult
from ..agent.progress import Progress
from ..errors import InputError, RavenmemError, one_line
from ..runtime.ask import AskArgs
from .intake import SequenceGaps
from .node import RavenmemNode, open_service
from .params import NodeSettings
from .services import ServiceBackend

if TYPE_CHECKING:
    import numpy as np

log = logging.getLogger(__name__)

SKIP_INACTIVE = "node inactive"  # an image delivered while the node deactivates
NAVIGATE_INACTIVE = "the node is inactive: activate it to navigate (questions without navigate are answered)"
DRAIN_S = 60.0  # how long deactivate waits for the frames queued for the writer
LINGER_S = 0.5  # ros.run spins on after the shutdown transition: its reply reaches the caller


class Made:
    """The rclpy entities a node made since this was taken, so that a transition can undo what
    the one before it made (configure and cleanup, activate and deactivate). The entities seen
    at the start are held, so no new one can be mistaken for one of them. A subscription to
    /clock is rclpy's own (its time source makes one when `use_sim_time` is set at run time),
    never the node's: it is kept."""

    KINDS = ("subscriptions", "timers", "publishers", "services", "clients", "waitables")

    def __init__(self, node: Any) -> None:
        self.node = node
        self.before = {kind: list(getattr(node, kind)) for kind in self.KINDS}

    def destroy(self, *kinds: str) -> int:
        """Destroy the entities of these kinds (all by default) made since; how many."""
        n = 0
        for kind in kinds or self.KINDS:
            old = {id(e) for e in self.before[kind]}
            for e in [e for e in getattr(self.node, kind) if id(e) not in old and not _clock(e)]:
                if kind == "waitables":  # an action server or client
                    e.destroy()
                else:
                    getattr(self.node, f"destroy_{kind[:-1]}")(e)
                n += 1
        return n


def _clock(entity: Any) -> bool:
    return getattr(entity, "topic_name", None) == "/clock"


class ManagedBackend(ServiceBackend):
    """The questions and searches of a managed node: answered from the memory in both
    configured states; a question that asks to navigate only while the node is active."""

    def __init__(self, inner: ServiceBackend, active: Callable[[], bool]) -> None:
        super().__init__(inner.service, inner.start, inner.drive)
        self.active = active

    def ask(self, args: AskArgs, image: np.ndarray | None, progress: Progress | None = None) -> AskResult:
        if args.navigate and not self.active():
            raise InputError(NAVIGATE_INACTIVE)
        return super().ask(args, image, progress)


class Managed:
    """What each transition does (see the module docstring); one transition at a time."""

    def __init__(self, node: Any, memory: Path, create: bool) -> None:
        self.node, self.memory, self.create = node, memory, create
        self.ros: RavenmemNode | None = None
        self.active = False
        self.lock = threading.Lock()
        self._made: Made | None = None  # since configure
        self._inputs: Made | None = None  # since activate

    def _say(self, line: str) -> None:
        self.node.get_logger().info(line)

    def _configured(self) -> RavenmemNode:
        if self.ros is None:
            raise InputError("the node is not configured")
        return self.ros

    def configure(self) -> None:
        settings = NodeSettings.read(self.node)
        made = Made(self.node)
        service = open_service(self.memory, self.create, settings)
        try:
            ros = RavenmemNode(
                self.node, settings, service, subscribe=False, sensors=self.node.default_callback_group
            )
            ros.backend = ManagedBackend(ros.backend, lambda: self.active)
            service.attach(ros)
            service.warm_up()
        except BaseException:
            made.destroy()
            service.close()
            raise
        self.ros, self._made = ros, made
        self._say(f"configured: {self.memory} ({service.mem.count()} memories); inactive")

    def activate(self) -> None:
        ros = self._configured()
        inputs = Made(self.node)
        ros.intake.gaps = SequenceGaps()  # new subscriptions: what was sent before is not a loss
        ros.intake.stopping = False
        try:
            ros.subscribe_inputs()
        except BaseException:
            ros.intake.stopping = True
            inputs.destroy()
            raise
        self._inputs = inputs
        self.active = True
        self._say("active: taking frames")

    def deactivate(self) -> None:
        ros = self._configured()
        self.active = False
        ros.intake.stop_reason = SKIP_INACTIVE
        ros.intake.stopping = True
        if self._inputs is not None:
            self._inputs.destroy("subscriptions", "timers")
            self._inputs = None
        ros.image_subs.clear()
        ros.transport = None
        ros.intake.settle(flush=True)
        self._drain(ros)
        self._say(f"inactive: frames no longer taken ({ros.intake.counts.stored} stored since configure)")

    def _drain(self, ros: RavenmemNode) -> None:
        """Wait (bounded) until the writer answered every frame handed to it."""
        end = time.monotonic() + DRAIN_S
        while ros.intake.counts.in_writer > 0 and time.monotonic() < end:
            time.sleep(0.05)
        if ros.intake.counts.in_writer > 0:
            self.node.get_logger().warning(
                f"{ros.intake.counts.in_writer} frame(s) still being stored after {DRAIN_S:.0f} s"
            )

    def cleanup(self) -> None:
        ros = self._configured()
        if self.active:  # shutdown from active
            self.deactivate()
        else:  # after a failed activate or deactivate, images may still wait
            ros.stop_intake()
        self.ros = None
        try:
            ros.finish()  # the writer stores what is queued, the run noted, the memory closed
        finally:
            if self._made is not None:
                self._made.destroy()
                self._made = None
        self._say(f"cleaned up: {self.memory} closed ({ros.intake.counts.stored} stored since configure)")

    def shutdown(self) -> None:
        """Close whatever is open (idempotent: the shutdown transition, a signal, an error)."""
        if self.ros is not None:
            self.cleanup()


class ManagedNode(LifecycleNode):
    """The lifecycle node `ravenmem`: rclpy's state machine and its services
    (`~/change_state`, `~/get_state`, ...), each transition handed to `Managed`. A configure
    or activate that fails says why in one line and leaves the node in the state it was in (what
    it had made undone); a deactivate, cleanup or shutdown cannot be undone half-way, so its
    failure is an error, after which whatever is open is closed (unconfigured)."""

    def __init__(self, memory: Path, create: bool, stop: threading.Event) -> None:
        super().__init__("ravenmem")
        NodeSettings.declare_all(self)
        self.work = Managed(self, memory, create)
        self.stop = stop  # set once finalized: the process exits
        self.finished = False

    def _run(
        self, name: str, step: Callable[[], None], failed: TransitionCallbackReturn
    ) -> TransitionCallbackReturn:
        try:
            with self.work.lock:
                step()
        except Exception as e:  # the reason in one line; the traceback only in the debug log
            why = one_line(e)
            if not isinstance(e, (RavenmemError, OSError)):
                why = f"{type(e).__name__}: {why}"
                log.debug("%s failed", name, exc_info=True)
            self.get_logger().error(f"{name} failed: {why}")
            return failed
        return TransitionCallbackReturn.SUCCESS

    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        return self._run("configure", self.work.configure, TransitionCallbackReturn.FAILURE)

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        return self._run("activate", self.work.activate, TransitionCallbackReturn.FAILURE)

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        return self._run("deactivate", self.work.deactivate, TransitionCallbackReturn.ERROR)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        return self._run("cleanup", self.work.cleanup, TransitionCallbackReturn.ERROR)

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        done = self._run("shutdown", self.work.shutdown, TransitionCallbackReturn.ERROR)
        self.finished = True
        self.stop.set()  # the memory is closed: the process may exit
        return done

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        """After a failed deactivate, cleanup or shutdown: close what is still open, then
        unconfigured."""
        self._run("error processing", self.work.shutdown, TransitionCallbackReturn.SUCCESS)
        self.work.ros, self.work.active = None, False
        return TransitionCallbackReturn.SUCCESS

    def close(self) -> None:
        """A signal stopped the process: the shutdown transition (the state machine tells its
        listeners), and the memory closed even when a transition was under way."""
        if self.finished:
            return
        self.get_logger().info("stopping: shutdown (the frames already taken are stored)")
        try:
            self.trigger_shutdown()
        except Exception:  # in the middle of a transition: no shutdown from there
            log.debug("shutdown transition refused", exc_info=True)
        with self.work.lock:
            self.work.shutdown()
