"""The ROS interface inventory (issue 43 item 1): every service, topic and parameter of every node, from the nodes
themselves, each with its class and how it is protected.

``observe(node)`` lists what a running node offers (rclpy's graph API: its publishers, subscriptions, services;
its declared parameters), with robot names folded to ``<robot>``, a signing key's id at the end of a name to
``<key_id>`` (the trainer's fetch service) and the node's own name to ``~``. ``CLASSES`` (the
committed table, ``inventory_table.py``) gives each entry a class and a protection; ``render`` writes the table of
docs/ros_graph.md, "Inventory". test/test_inventory.py starts every node and fails on an entry without a class (a
node gained a service, topic or parameter nobody classified) or a class without an entry.

    .venv/bin/python -m dynenv_ros.graph.inventory            # print the Markdown table (docs/ros_graph.md)
"""
from __future__ import annotations

import re
from typing import Any

from dynenv_ros.graph.inventory_table import CLASSES, KINDS, LABELS, NODES

_ROBOT = re.compile(r"/(team_[ab]_\d+|car_\d+)(?=/|$)")
_KEY_ID = re.compile(r"_[0-9a-f]{16}$")


def _fold(name: str, node_name: str) -> str:
    name = _KEY_ID.sub("_<key_id>", _ROBOT.sub("/<robot>", name))
    own = f"/{node_name}/"
    return "~/" + name[len(own):] if name.startswith(own) else name


def observe(node: Any) -> dict[str, set[str]]:
    """What ``node`` offers now: {"publishes", "subscribes", "services", "parameters"} -> folded names."""
    name, namespace = node.get_name(), node.get_namespace()
    publishes = {_fold(t, name) for t, _ in node.get_publisher_names_and_types_by_node(name, namespace)}
    subscribes = {_fold(t, name) for t, _ in node.get_subscriber_names_and_types_by_node(name, namespace)}
    services = {_fold(s, name) for s, _ in node.get_service_names_and_types_by_node(name, namespace)}
    return {"publishes": publishes, "subscribes": subscribes, "services": services,
            "parameters": set(node._parameters)}


def differences(node_name: str, observed: dict[str, set[str]]) -> list[str]:
    """Entries observed without a class, and classes of entries not observed (both: the table is out of date)."""
    table = CLASSES[node_name]
    problems = []
    for kind in KINDS:
        known = set(table.get(kind, {}))
        problems += [f"{node_name} {kind} {n}: no class (add it to dynenv_ros/graph/inventory_table.py)"
                     for n in sorted(observed[kind] - known)]
        problems += [f"{node_name} {kind} {n}: classified but not offered" for n in sorted(known - observed[kind])]
    return problems


def render() -> str:
    """The Markdown table of docs/ros_graph.md's inventory, from the committed classes."""
    lines = ["| node | kind | name | class | protection |", "|---|---|---|---|---|"]
    for node_name in NODES:
        for kind in KINDS:
            for name, (klass, protection) in sorted(CLASSES[node_name].get(kind, {}).items()):
                lines.append(f"| `{node_name}` | {kind} | `{name}` | {LABELS[klass]} | {protection} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    import argparse
    parser = argparse.ArgumentParser(prog="python -m dynenv_ros.graph.inventory",
                                     description="Print the inventory table of docs/ros_graph.md (Markdown).")
    parser.parse_args(argv)
    print(render(), end="")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
