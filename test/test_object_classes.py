"""The ROS-free enums of the core carry exactly the constants of the .msg files (one source of truth)."""
from __future__ import annotations

import re
from pathlib import Path

import pytest

from dynenv_ros.core.object_classes import ObjectClass, ObjectStatus, Sighting, Subtype, TeamRelation

MSG_DIR = Path(__file__).resolve().parent.parent / "msg_defs" / "msg"


def msg_constants(file: str, prefix: str) -> dict[str, int]:
    pattern = re.compile(rf"^\w+ {prefix}_(\w+)=(-?\d+)\s*$", re.MULTILINE)
    return {name: int(value) for name, value in pattern.findall((MSG_DIR / file).read_text())}


@pytest.mark.parametrize("file, prefix, enum", [
    ("Detection.msg", "CLASS", ObjectClass), ("Detection.msg", "TEAM", TeamRelation),
    ("Detection.msg", "SUBTYPE", Subtype), ("Detection.msg", "SIGHTING", Sighting),
    ("ObjectState.msg", "STATUS", ObjectStatus)])
def test_enum_matches_msg_constants(file, prefix, enum):
    from_enum = {member.name: int(member.value) for member in enum}  # flag enums iterate their bits only
    assert msg_constants(file, prefix) == from_enum


def test_generated_module_agrees():
    from dynenv_msgs.msg import Detection
    for member in ObjectClass:
        assert getattr(Detection, f"CLASS_{member.name}") == member.value
