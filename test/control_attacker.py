"""The attacker of test_runtime_controls.py, a process of its own on the test's ROS domain with no key and no
secret: for ``seconds`` it looks for the simulator's /sim/reset and /sim/step and calls them (a reset with seed 99,
one step), and asks /sim_node, /trainer_node and /policy_node to change settable parameters (missing_action hold,
auto_reset false, learning_rate 1.0, greedy false, use_sim_time true). Prints one JSON line of what each call
answered ("absent": the service never appeared; "no answer": it was listed but answered none of three calls)."""
from __future__ import annotations

import json
import sys

import rclpy
from dynenv_msgs.srv import ResetSimulation, StepSimulation
from rcl_interfaces.srv import SetParameters
from rclpy.parameter import Parameter

CHANGES = {"/sim_node": [Parameter("missing_action", value="hold"), Parameter("auto_reset", value=False),
                         Parameter("use_sim_time", value=True)],
           "/trainer_node": [Parameter("learning_rate", value=1.0), Parameter("use_sim_time", value=True)],
           "/policy_node": [Parameter("greedy", value=False), Parameter("use_sim_time", value=True)]}


def call(node, client, request, wait_s: float):
    """The service's answer, "absent" (never on the graph) or "no answer". A call is tried up to three times: a
    service seen on the graph may answer before its response writer has matched this client's reader, and Fast DDS
    then drops the answer ("failed to send response (timeout)"), which the full suite met on a busy machine. A
    service that answers none of the three is a ghost: the graph still lists the server of a process an earlier
    test killed until its participant's lease runs out (the full suite met it for /policy_node)."""
    if not client.wait_for_service(timeout_sec=wait_s):
        return "absent"
    for _ in range(3):
        future = client.call_async(request)
        rclpy.spin_until_future_complete(node, future, timeout_sec=5.0)
        if future.done():
            return future.result()
        client.remove_pending_request(future)
    return "no answer"


def main(seconds: float) -> None:
    rclpy.init()
    node = rclpy.create_node("control_attacker")
    wait_s = seconds / 4
    result: dict[str, object] = {}
    reset = call(node, node.create_client(ResetSimulation, "/sim/reset"),
                 ResetSimulation.Request(use_seed=True, seed=99), wait_s)
    result["reset"] = reset if isinstance(reset, str) else {"success": reset.success, "message": reset.message}
    step = call(node, node.create_client(StepSimulation, "/sim/step"), StepSimulation.Request(ticks=0), wait_s)
    result["step"] = step if isinstance(step, str) else {"success": step.success, "message": step.message}
    for target, parameters in CHANGES.items():
        answer = call(node, node.create_client(SetParameters, f"{target}/set_parameters"),
                      SetParameters.Request(parameters=[p.to_parameter_msg() for p in parameters]), wait_s)
        result[target] = answer if isinstance(answer, str) else [
            {"name": p.name, "successful": r.successful, "reason": r.reason}
            for p, r in zip(parameters, answer.results)]
    print(json.dumps(result), flush=True)
    node.destroy_node()
    rclpy.shutdown()


if __name__ == "__main__":
    main(float(sys.argv[1]))
