#!/usr/bin/env python3
"""``ros2 service call`` for the venv: the PyPI wheels have rclpy but no ros2cli.

Usage (the arguments of ``ros2 service call``)::

    .venv/bin/python tools/ros2_service_call.py /sim/step dynenv_msgs/srv/StepSimulation "{ticks: 0}"
    .venv/bin/python tools/ros2_service_call.py /sim/reset dynenv_msgs/srv/ResetSimulation "{use_seed: true, seed: 7}"

(The policy node's services want an operator's signature: ``dynenv-keys call`` signs and calls, issue 43.)

VALUES is YAML, as for ros2cli: a mapping of request fields (nested mappings for nested messages). The call waits
for the service (``--timeout``), prints the response's fields as YAML and exits 0; a service that does not appear or
answer exits 1, a type or field that does not exist exits 2, each with a one-line reason. It joins the ROS domain
of ``ROS_DOMAIN_ID``, like every node here.
"""
from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))      # run from a checkout: the package beside it
from dynenv_ros.ros.service_call import CallError, as_plain, call, request_from_yaml  # noqa: E402


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="ros2_service_call.py", description=__doc__.splitlines()[0])
    parser.add_argument("service", help="service name, e.g. /policy_node/load_policy")
    parser.add_argument("type", help="service type, e.g. dynenv_msgs/srv/LoadPolicy")
    parser.add_argument("values", nargs="?", default="{}", help="request fields as YAML (default: {})")
    parser.add_argument("--timeout", type=float, default=10.0, help="seconds to wait for the service and its answer")
    args = parser.parse_args(argv)
    try:
        kind, request = request_from_yaml(args.type, args.values)
    except CallError as error:
        print(f"ros2_service_call.py: {error}", file=sys.stderr)
        return 2
    print(f"requester: making request: {request}")
    response, why = call(args.service, kind, request, args.timeout)
    if response is None:
        print(f"ros2_service_call.py: {why}", file=sys.stderr)
        return 1
    print("response:")
    print(yaml.safe_dump(as_plain(response), sort_keys=False).rstrip())
    return 0


if __name__ == "__main__":
    sys.exit(main())
