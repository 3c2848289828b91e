"""The catalogue of dynenv_msgs interfaces, reproducible sample instances, and field-by-field comparison.

Used by the graph self-check (the main job before the simulator exists) and by the interface tests, so both
exercise every field of every type with the same data.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from rosidl_parser.definition import AbstractNestedType, AbstractSequence, AbstractString, Array, NamespacedType

from dynenv_msgs import msg as dynenv_msg
from dynenv_msgs import srv as dynenv_srv

PACKAGE = "dynenv_msgs"
MESSAGE_NAMES = ("Detection", "DetectionArray", "ObjectState", "WorldState", "Action", "StepFeedback",
                 "WeightsAnnouncement", "OperatorSignature")
SERVICE_NAMES = ("ResetSimulation", "StepSimulation", "LoadPolicy", "FetchWeights", "AcceptOlderWeights")
# Sequences in samples get 0..MAX_SAMPLE_SEQUENCE elements, so empty and several-element lists are both covered.
MAX_SAMPLE_SEQUENCE = 4

_INTEGER_RANGES = {
    "int8": (-2**7, 2**7 - 1), "uint8": (0, 2**8 - 1), "int16": (-2**15, 2**15 - 1), "uint16": (0, 2**16 - 1),
    "int32": (-2**31, 2**31 - 1), "uint32": (0, 2**32 - 1), "int64": (-2**63, 2**63 - 1),
    "uint64": (0, 2**64 - 1), "octet": (0, 255), "byte": (0, 255), "char": (0, 255),
}


@dataclass(frozen=True)
class InterfaceType:
    """One message type, or one half (request/response) of a service."""
    name: str          # e.g. "dynenv_msgs/msg/Detection", "dynenv_msgs/srv/StepSimulation_Request"
    cls: type

    @property
    def short_name(self) -> str:
        return self.name.rsplit("/", 1)[1]


def message_types() -> list[InterfaceType]:
    return [InterfaceType(f"{PACKAGE}/msg/{n}", getattr(dynenv_msg, n)) for n in MESSAGE_NAMES]


def service_types() -> dict[str, type]:
    return {n: getattr(dynenv_srv, n) for n in SERVICE_NAMES}


def all_interface_types() -> list[InterfaceType]:
    """Every message plus every service request and response: all that ever crosses the wire."""
    types = message_types()
    for name, srv in service_types().items():
        types.append(InterfaceType(f"{PACKAGE}/srv/{name}_Request", srv.Request))
        types.append(InterfaceType(f"{PACKAGE}/srv/{name}_Response", srv.Response))
    return types


def interface_share_dir() -> Path:
    """share/dynenv_msgs of the installed interface package (holds the .msg/.srv and the type-hash JSON)."""
    from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
    try:
        return Path(get_package_share_directory(PACKAGE))
    except (PackageNotFoundError, KeyError, ValueError, OSError):  # OSError: AMENT_PREFIX_PATH unset (venv)
        candidate = Path(sys.prefix) / "share" / PACKAGE
        if candidate.is_dir():
            return candidate
        raise FileNotFoundError(f"{PACKAGE} is not installed: run `make test` or `make run` to build msg_defs") from None


def generated_type_hash(name: str) -> str:
    """RIHS01 hash rosidl generated for ``name`` (read from the installed type-description JSON)."""
    package, kind, type_name = name.split("/")
    base = type_name.split("_")[0] if kind == "srv" else type_name
    description = json.loads((interface_share_dir() / kind / f"{base}.json").read_text())
    for entry in description["type_hashes"]:
        if entry["type_name"] == name:
            return entry["hash_string"]
    raise KeyError(f"no generated hash for {name}")


def _seed_for(label: str, seed: int) -> int:
    return int.from_bytes(hashlib.sha256(f"{label}:{seed}".encode()).digest()[:8], "little")


def sample_message(cls: type, seed: int) -> Any:
    """A message of type ``cls`` with every field set to a non-default, reproducible value.

    Floats are float32-representable where the field is float32, so the sample survives CDR exactly.
    """
    return _fill(cls, np.random.default_rng(_seed_for(cls.__name__, seed)))


def _fill(cls: type, rng: np.random.Generator) -> Any:
    message = cls()
    for field_name, slot in zip(cls.get_fields_and_field_types(), cls.SLOT_TYPES):
        setattr(message, field_name, _value(slot, rng))
    return message


def _value(slot: Any, rng: np.random.Generator) -> Any:
    if isinstance(slot, AbstractNestedType):
        length = slot.size if isinstance(slot, Array) else int(rng.integers(0, MAX_SAMPLE_SEQUENCE + 1))
        if isinstance(slot, AbstractSequence) and slot.has_maximum_size():
            length = min(length, slot.maximum_size)
        return [_value(slot.value_type, rng) for _ in range(length)]
    if isinstance(slot, NamespacedType):
        module = __import__(".".join(slot.namespaces), fromlist=[slot.name])
        return _fill(getattr(module, slot.name), rng)
    if isinstance(slot, AbstractString):
        length = int(rng.integers(1, 24))
        if slot.has_maximum_size():          # bounded strings (string<=16) stay within their bound
            length = min(length, slot.maximum_size)
        return "".join(rng.choice(list("abcdefghijklmnopqrstuvwxyz_/ 0123456789"), size=length))
    typename = slot.typename
    if typename == "boolean":
        return bool(rng.integers(0, 2))
    if typename in ("float", "double"):
        value = float(rng.uniform(-100.0, 100.0))
        return float(np.float32(value)) if typename == "float" else value
    if typename in _INTEGER_RANGES:
        low, high = _INTEGER_RANGES[typename]
        value = int(rng.integers(low, high, endpoint=True, dtype=np.int64 if low < 0 else np.uint64))
        return bytes([value]) if typename in ("octet", "byte") else value
    raise TypeError(f"unsupported field type {typename}")


def as_plain(value: Any) -> Any:
    """Nested dicts/lists/floats of an rclpy or rosbags message, so messages from both libraries compare equal."""
    if hasattr(value, "get_fields_and_field_types"):  # rclpy message
        return {name: as_plain(getattr(value, name)) for name in value.get_fields_and_field_types()}
    if dataclasses.is_dataclass(value):  # rosbags message: skip its constants (upper case) and __msgtype__
        return {field.name: as_plain(getattr(value, field.name)) for field in dataclasses.fields(value)
                if not field.name.startswith("_") and not field.name.isupper()}
    if isinstance(value, (list, tuple)) or isinstance(value, np.ndarray) or type(value).__name__ == "array":
        return [as_plain(v) for v in value]
    if isinstance(value, (bytes, bytearray)):
        return list(value)
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value)
    return value


def field_differences(expected: Any, actual: Any, path: str = "") -> list[str]:
    """Every field where two messages differ, as 'path: expected != actual' (empty when equal).

    NaN equals NaN here: a float field carrying NaN ("undefined") must round-trip as NaN.
    """
    return list(_differences(as_plain(expected), as_plain(actual), path or "<msg>"))


def _differences(a: Any, b: Any, path: str) -> Iterator[str]:
    if isinstance(a, dict) and isinstance(b, dict):
        if a.keys() != b.keys():
            yield f"{path}: fields {sorted(a)} != {sorted(b)}"
            return
        for key in a:
            yield from _differences(a[key], b[key], f"{path}.{key}")
    elif isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            yield f"{path}: length {len(a)} != {len(b)}"
            return
        for index, (x, y) in enumerate(zip(a, b)):
            yield from _differences(x, y, f"{path}[{index}]")
    elif isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return
    elif a != b or type(a) is not type(b):
        yield f"{path}: {a!r} != {b!r}"
