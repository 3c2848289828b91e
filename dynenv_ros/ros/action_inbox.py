"""The simulator's action readers, on a DDS participant and a thread of their own, so a flood cannot starve it.

Measured (``dynenv-bench flood``, docs/benchmarks.md): two processes publishing actions at full speed on one robot's
topic overflow the receiving participant's transport, and what else arrives there is lost and repaired seconds later
— the simulator's service requests too (get_parameters took up to 3 s). Reading actions on a second participant
keeps that traffic apart: the simulator's own participant (services, parameters, diagnostics) is not the one being
flooded. The inbox thread drains each queue in batches and screens every message against the game state (a cheap,
read-only check); refusals are only counted, and what may be accepted now is handed to the owner's thread through a
bounded queue and a guard condition, so the game state is only ever changed on the owner's thread.
"""
from __future__ import annotations

import atexit
import sys
import threading
from collections import Counter, deque
from collections.abc import Callable, Sequence
from typing import Any

import rclpy
from rclpy.context import Context
from rclpy.executors import ExternalShutdownException, ShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile

from dynenv_ros.ros.drain import take
from dynenv_ros.ros.node_runner import shutdown_quietly

# Messages read per callback beyond the one the executor handed in: the executor takes one per wake-up (a few
# hundred a second), far below a flood's rate; a batch of this size costs ~10 ms of screening.
DRAIN_LIMIT = 500

# The inbox thread's longest wait before it looks whether it was closed, and how long ``close`` waits for it (a
# batch of DRAIN_LIMIT messages takes ~10 ms; the margin is for a loaded machine).
SPIN_POLL_S = 0.1
JOIN_TIMEOUT_S = 10.0

# screen(robot index, message) -> "" when the message may be accepted now, else the counter key of its refusal
# ("rejected_late", ...) and the reason, as (key, reason).
Screen = Callable[[int, Any], tuple[str, str]]


def enclave_arguments(argv: Sequence[str]) -> list[str]:
    """``--ros-args --enclave <name>`` if ``argv``'s ROS arguments name an enclave, else nothing."""
    if "--ros-args" not in argv:
        return []
    ros_args = list(argv[list(argv).index("--ros-args") + 1:])
    for flag in ("--enclave", "-e"):
        if flag in ros_args and ros_args.index(flag) + 1 < len(ros_args):
            return ["--ros-args", "--enclave", ros_args[ros_args.index(flag) + 1]]
    return []


class ActionInbox:
    """Subscribes to one action topic per robot and hands screened messages to ``deliver`` on the owner's thread.

    With ``own_participant`` the readers live on a context (DDS participant) and thread of their own; without, on
    the owner's node, screened in its callbacks. The simulator uses its own participant in real time only: a second
    participant discovers a policy's writer on its own schedule, and in stepped mode an action sent before the
    policy's writer had matched the inbox's reader was lost and stalled the game (the simulator had already seen
    the writer from its own participant); real time shrugs off one lost action, stepped mode cannot.
    """

    def __init__(self, owner: Node, msg_type: type, topic_names: Sequence[str], qos: QoSProfile, depth: int,
                 screen: Screen, deliver: Callable[[int, Any], None],
                 refused: Callable[[Counter[str], str], None], own_participant: bool = True) -> None:
        self._screen, self._deliver, self._report_refused = screen, deliver, refused
        self._queues: list[deque[Any]] = [deque(maxlen=depth) for _ in topic_names]
        self._lock = threading.Lock()
        self._refused: Counter[str] = Counter()
        self._last_reason = ""
        self._context: Context | None = None
        self._thread: threading.Thread | None = None
        self._closing = threading.Event()              # set by close: the thread stops at its next check
        self._msg_type = msg_type
        if not own_participant:
            self._node = owner
            self.subscriptions = [owner.create_subscription(msg_type, name, self._receiver(i), qos)
                                  for i, name in enumerate(topic_names)]
            return
        # Remappings and the namespace are the owner's: resolve the names on the owner's node.
        resolved = [owner.resolve_topic_name(t) for t in topic_names]
        self._context = Context()
        # Not the process's arguments (rclpy's default): their remappings and node name would apply twice. Only the
        # SROS2 enclave carries over, so the inbox's participant joins a secured graph under the owner's identity.
        rclpy.init(args=enclave_arguments(sys.argv), context=self._context,
                   domain_id=owner.context.get_domain_id())
        self._node = rclpy.create_node(f"{owner.get_name()}_actions", context=self._context, enable_rosout=False,
                                       start_parameter_services=False)
        self.subscriptions = [self._node.create_subscription(msg_type, name, self._receiver(i), qos)
                              for i, name in enumerate(resolved)]
        self._wake = owner.create_guard_condition(self._hand_over)
        self._stop = self._node.create_guard_condition(lambda: None)
        self._executor = SingleThreadedExecutor(context=self._context)
        self._executor.add_node(self._node)
        self._thread = threading.Thread(target=self._spin, name="action_inbox", daemon=True)
        # A daemon thread still waiting in rcl when the interpreter finalizes is unwound through C++ frames that
        # cannot be, and the process aborts (exit -6). An owner that never got to close the inbox (a signal while
        # a constructor ran, this one included) leaves that to exit; atexit runs before finalization.
        atexit.register(self.close)
        self._thread.start()

    def _spin(self) -> None:
        # In bounded waits, so the thread notices ``close`` on its own: rclpy's ``Executor.shutdown`` from another
        # thread destroys the guard conditions the spinning thread is waiting on (a segfault, seen on Ctrl-C during
        # start-up), so ``close`` only asks, joins, and then tears down with the thread gone.
        try:
            while not self._closing.is_set() and self._context.ok():
                self._executor.spin_once(timeout_sec=SPIN_POLL_S)
        except (ExternalShutdownException, ShutdownException):
            pass
        except Exception:
            # A signal shuts the inbox's context down under a wait already past its check: rcl then refuses the
            # wait set ("the given context is not valid"). That is a stop; a failure while the inbox runs is real.
            if not self._closing.is_set() and self._context.ok():
                raise

    def resubscribe(self, robot: int, qos: QoSProfile) -> None:
        """Read ``robot``'s topic with ``qos`` from now on (a reader's QoS is fixed at creation). On the owner's
        thread, for readers on the owner's node: there is no other thread to race."""
        if self._thread is not None:
            raise RuntimeError("resubscribe is for an inbox on its owner's node")
        old = self.subscriptions[robot]
        self.subscriptions[robot] = self._node.create_subscription(self._msg_type, old.topic_name,
                                                                   self._receiver(robot), qos)
        self._node.destroy_subscription(old)

    def _receiver(self, robot: int) -> Callable[[Any], None]:
        return lambda msg: self.receive(robot, msg)

    def receive(self, robot: int, msg: Any) -> None:
        """In the subscription's callback: screen ``msg`` and everything queued behind it, in a
        bounded batch, then wake the owner if there is anything to hand over or count."""
        handed = self._screen_one(robot, msg)
        subscription = self.subscriptions[robot]
        for _ in range(DRAIN_LIMIT):
            taken = take(subscription)
            if taken is None:
                break
            handed = self._screen_one(robot, taken) or handed
        if self._thread is None:
            self._hand_over()               # already on the owner's thread
        elif handed or self._refused:
            self._wake.trigger()

    def _screen_one(self, robot: int, msg: Any) -> bool:
        key, reason = self._screen(robot, msg)
        if key:
            with self._lock:
                self._refused[key] += 1
                self._last_reason = reason
            return False
        self._queues[robot].append(msg)
        return True

    def _hand_over(self) -> None:
        """On the owner's thread: every queued message to ``deliver`` (in order per robot), then the refusals
        counted since the last hand-over to ``refused``."""
        for robot, queue in enumerate(self._queues):
            while queue:
                self._deliver(robot, queue.popleft())
        with self._lock:
            refused, self._refused = self._refused, Counter()
            last = self._last_reason
        if refused:
            self._report_refused(refused, last)

    def close(self) -> None:
        """Stop the inbox's thread, then its participant; again is a no-op."""
        if self._context is None or self._closing.is_set():
            return                          # the owner's subscriptions go with the owner
        atexit.unregister(self.close)
        self._closing.set()
        try:
            self._stop.trigger()            # wake the wait now rather than at its poll
        except Exception:                   # the context is already shut down: the poll ends the wait
            pass
        if self._thread.ident is not None:          # started
            self._thread.join(timeout=JOIN_TIMEOUT_S)
        if self._thread.is_alive():
            # Tearing down under a live wait is the crash this order exists to avoid; the daemon thread ends with
            # the process instead.
            print("action inbox: its thread did not stop; leaving its participant to the process exit",
                  file=sys.stderr, flush=True)
            return
        self._executor.shutdown(timeout_sec=0)
        self._node.destroy_node()
        shutdown_quietly(self._context)
