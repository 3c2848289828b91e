"""Bounding what DDS itself accepts on the weights announcement and blob topics, before rclpy sees a byte.

A bounded message type (WeightsAnnouncement: every field has a maximum) is not enough on its own: rmw_fastrtps lets a
reader's history grow to any sample size, so Fast DDS reassembled a 300 MB sample of raw bytes (any process can
publish them) before the type's bound refused it — +290 MB of RSS for the reader (measured). The profiles in
``fastdds_bounded.xml`` preallocate that reader's samples at the type's bound instead, and Fast DDS drops a larger
sample as its first fragment arrives (measured: +1 MB, no pause). The blob topic's reader (chunks of at most
1 MiB, ``ros.weights_release``) is bounded the same way: a 50 MB raw sample cost its reader +48 MB without the
profile and nothing with it (measured; rclpy does not check a bounded sequence's length on reading). It starts with
one preallocated sample and grows as samples arrive: Fast DDS's default of 100 cost +90 MB once the node had
subscribed to the blob topic twice (measured). Fast DDS reads profiles only at start-up, from
the environment, so ``use_bounded_profiles`` must run before ``rclpy.init`` (the policy node's ``main`` calls it).
"""
from __future__ import annotations

import os
from collections.abc import MutableMapping
from pathlib import Path

PROFILES = Path(__file__).with_name("fastdds_bounded.xml")
PROFILE_VARIABLES = ("FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE")


def use_bounded_profiles(environ: MutableMapping[str, str] = os.environ) -> str:
    """Point Fast DDS at ``PROFILES`` unless the user chose profiles or another middleware; returns what was done
    (for the node's log). ``RMW_FASTRTPS_USE_QOS_FROM_XML=1`` makes rmw_fastrtps keep the profiles' memory policy
    instead of its own (the profiles' defaults repeat rmw_fastrtps's own choices for every other endpoint)."""
    if any(environ.get(name) for name in PROFILE_VARIABLES):
        return "your Fast DDS profiles are used (the announcement reader is bounded only if they bound it)"
    if environ.get("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp") != "rmw_fastrtps_cpp":
        return f"{environ['RMW_IMPLEMENTATION']}: the announcement reader is bounded by that middleware only"
    environ["FASTRTPS_DEFAULT_PROFILES_FILE"] = str(PROFILES)
    environ["RMW_FASTRTPS_USE_QOS_FROM_XML"] = "1"
    return f"Fast DDS profiles {PROFILES.name}: announcements above the type's bound are dropped by DDS"
