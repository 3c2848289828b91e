"""A rosbags typestore that knows dynenv_msgs, built from the .msg/.srv sources rather than generated code.

Bags can then be written and read on machines without the interface package built, and the RIHS01 hashes rosbags
computes are checked against rosidl's in test/test_interfaces_cdr.py.
"""
from __future__ import annotations

import sys
from functools import lru_cache
from pathlib import Path

from rosbags.typesys import Stores, get_typestore, get_types_from_msg
from rosbags.typesys.store import Typestore

PACKAGE = "dynenv_msgs"
_SERVICE_SEPARATOR = "\n---\n"


def interface_source_dirs() -> list[Path]:
    """Where the .msg/.srv files are: the repository's msg_defs (source tree) or an installed share dir."""
    candidates = [Path(__file__).resolve().parents[2] / "msg_defs", Path(sys.prefix) / "share" / PACKAGE]
    return [c for c in candidates if (c / "msg").is_dir()]


def interface_definitions(source: Path) -> dict[str, str]:
    """Message definitions by full type name; a service gives its _Request and _Response halves."""
    definitions: dict[str, str] = {}
    for path in sorted((source / "msg").glob("*.msg")):
        definitions[f"{PACKAGE}/msg/{path.stem}"] = path.read_text()
    for path in sorted((source / "srv").glob("*.srv")):
        text = path.read_text()
        if _SERVICE_SEPARATOR not in "\n" + text:
            raise ValueError(f"{path}: a service needs a '---' line between request and response")
        request, response = ("\n" + text).split(_SERVICE_SEPARATOR, 1)
        definitions[f"{PACKAGE}/srv/{path.stem}_Request"] = request
        definitions[f"{PACKAGE}/srv/{path.stem}_Response"] = response
    return definitions


# Rebuilt from msg_defs/upstream and missing from rosbags' Jazzy store (tf2_msgs is in it).
UPSTREAM_PACKAGES = ("vision_msgs", "soccer_vision_attribute_msgs", "soccer_vision_3d_msgs",
                     "game_controller_spl_interfaces")


def upstream_definitions() -> dict[str, str]:
    """The definitions of ``UPSTREAM_PACKAGES`` (what msg_defs/upstream rebuilds), from the source tree or the
    venv."""
    definitions: dict[str, str] = {}
    for package in UPSTREAM_PACKAGES:
        candidates = [Path(__file__).resolve().parents[2] / "msg_defs" / "upstream" / package,
                      Path(sys.prefix) / "share" / package]
        found = next((c / "msg" for c in candidates if (c / "msg").is_dir()), None)
        for path in sorted(found.glob("*.msg")) if found else ():
            definitions[f"{package}/msg/{path.stem}"] = path.read_text()
    return definitions


@lru_cache(maxsize=4)
def dynenv_typestore(source: Path | None = None) -> Typestore:
    """The ROS 2 Jazzy typestore plus every dynenv_msgs type and the rebuilt upstream ones (``UPSTREAM_PACKAGES``)."""
    if source is None:
        sources = interface_source_dirs()
        if not sources:
            raise FileNotFoundError(f"no {PACKAGE} .msg sources found (looked in msg_defs/ and share/{PACKAGE})")
        source = sources[0]
    store = get_typestore(Stores.ROS2_JAZZY)
    types: dict = {}
    for name, text in {**upstream_definitions(), **interface_definitions(source)}.items():
        parsed = get_types_from_msg(text, name)
        # rosbags files a "pkg/srv/X_Request" definition as "pkg/srv/msg/X_Request"; keep rosidl's name.
        types.update({name if key.endswith("/" + name.rsplit("/", 1)[1]) else key: value
                      for key, value in parsed.items()})
    store.register(types)
    return store
