"""The graph self-check: one node publishes and serves every interface, another verifies what arrives.

The expected data are reproducible (``sample_message`` with known seeds), so the receiving side needs no copy of
what was sent: it regenerates it. Service responses are a deterministic function of the request.
"""
from __future__ import annotations

import json
import zlib
from dataclasses import dataclass, field
from typing import Any

from dynenv_ros.ros.interfaces import InterfaceType, as_plain, field_differences, message_types, sample_message

TOPIC_PREFIX = "selfcheck"


def topic_for(interface: InterfaceType) -> str:
    return f"{TOPIC_PREFIX}/{interface.short_name}"


def service_name_for(service: str) -> str:
    snake = "".join(f"_{c.lower()}" if c.isupper() else c for c in service).lstrip("_")
    return f"{TOPIC_PREFIX}/{snake}"


def service_check_name(service: str) -> str:
    return f"dynenv_msgs/srv/{service}"


def sample_seed(base_seed: int, index: int) -> int:
    return base_seed * 100_003 + index


def expected_message(interface: InterfaceType, base_seed: int, index: int) -> Any:
    return sample_message(interface.cls, sample_seed(base_seed, index))


def expected_response(service_cls: type, request: Any) -> Any:
    """The self-check server's answer: a sample seeded by the request's field values.

    Not by its CDR bytes: rclpy leaves padding bytes uninitialised, so equal requests can serialise differently.
    """
    return sample_message(service_cls.Response, zlib.crc32(json.dumps(as_plain(request), sort_keys=True).encode()))


@dataclass
class InterfaceCheck:
    """What the verifier saw of one interface."""
    name: str
    expected: int
    received: int = 0
    problems: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return self.received == self.expected and not self.problems

    def record(self, expected: Any, actual: Any) -> None:
        differences = field_differences(expected, actual)
        if differences:
            self.problems.append(f"#{self.received}: " + "; ".join(differences[:5]))
        self.received += 1


def message_checks(samples_per_type: int) -> dict[str, InterfaceCheck]:
    return {t.name: InterfaceCheck(t.name, samples_per_type) for t in message_types()}


def build_report(checks: list[InterfaceCheck], hash_problems: list[str], timed_out: bool,
                 elapsed_s: float) -> dict[str, Any]:
    ok = all(c.ok for c in checks) and not hash_problems and not timed_out
    return {"ok": ok, "timed_out": timed_out, "elapsed_s": elapsed_s, "hash_problems": hash_problems,
            "interfaces": {c.name: {"ok": c.ok, "received": c.received, "expected": c.expected,
                                    "problems": c.problems} for c in checks}}


def format_report(report: dict[str, Any]) -> str:
    """The report as the table the listener logs and the main job prints."""
    interfaces = report["interfaces"]
    lines = [f"{'interface':<34} {'received':>9}  result"]
    for name, entry in interfaces.items():
        result = "ok" if entry["ok"] else ("; ".join(entry["problems"][:1]) or "MISSING")
        lines.append(f"{name:<34} {entry['received']:>4}/{entry['expected']:<4}  {result}")
    lines += [f"type hash problem: {problem}" for problem in report["hash_problems"]]
    if report["timed_out"]:
        lines.append("timed out before every sample arrived")
    verified = sum(e["ok"] for e in interfaces.values())
    lines.append(f"interfaces verified: {verified}/{len(interfaces)}; type hashes "
                 f"{'match' if not report['hash_problems'] else 'DIFFER'}; took {report['elapsed_s']:.2f} s")
    return "\n".join(lines)
