"""Run-time controls of the game and of learning (issue 43 item 5): the simulator's ``/sim/reset`` and
``/sim/step`` and every node's settable parameters (``~/set_parameters``) change the game or what is learnt, and DDS
without SROS2 does not say who calls them. ``runtime_controls`` (read-only, default true for local simulation) says
whether a node offers them; the deployment profile and the train graph switch them off, and the node says so once
at start. Parameter services cannot carry an operator's signature (rcl_interfaces types), so off, not signed, is
the protection here (docs/decisions.md, issue 43).
"""
from __future__ import annotations

from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node

from dynenv_ros.ros.parameters import declare_bool

PARAMETER = "runtime_controls"
REFUSED = ("runtime_controls is off: this node's parameters are fixed at start (docs/ros_graph.md, 'Who may "
           "change the game')")


def declare_runtime_controls(node: Node, what: str) -> bool:
    """Declare ``runtime_controls`` (with the other parameters, so ``--help`` lists it); ``what``: what it
    switches off, for ``--help``."""
    return declare_bool(node, PARAMETER, True, f"Offer the run-time controls ({what}, settable parameters); "
                        "false (deployment profile, train graph): off, since any process on the domain could call "
                        "them.", read_only=True)


def lock_when_off(node: Node, on: bool, what: str) -> None:
    """When ``runtime_controls`` is off, say so at start (``what``: e.g. '/sim/reset and /sim/step are not
    offered') and refuse every later parameter change. The node then adds no on-set callback of its own: rclpy runs
    the newest first, so one that applies a change would act before this refusal."""
    if on:
        return
    node.get_logger().info(f"runtime_controls off: {what}; parameter changes are refused")
    node.add_on_set_parameters_callback(lambda parameters: SetParametersResult(successful=False, reason=REFUSED))
