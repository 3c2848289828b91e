"""Helpers of the signed-weights tests: a key pair in a test's folder and a stand-in trainer that signs, announces
and serves weights exactly as the trainer node does (``ros.weights_release``), without learning."""
from __future__ import annotations

from pathlib import Path

from dynenv_ros.ros.weights_release import WeightsRelease
from dynenv_ros.security.keys import generate_key_pair, load_private_key
from dynenv_ros.security.weights_signing import Announcement


def key_pair(folder: Path) -> tuple[Path, Path]:
    """(trainer.key, trainer.pub) in ``folder`` (made once; the same pair on a second call)."""
    private, public = folder / "trainer.key", folder / "trainer.pub"
    if not private.exists():
        generate_key_pair(folder)
    return private, public


def network_metadata(agent) -> str:
    """The announcement's metadata_json of ``agent``, as the trainer node writes it."""
    import json

    from dynenv_ros.agent.checkpoint import FORMAT, agent_config
    return json.dumps({"format": FORMAT, "config": agent_config(agent), "updates": 0}, sort_keys=True)


class SignedTrainer:
    """A plain node publishing signed announcements and their bytes, and serving them (``WeightsRelease``);
    ``blob=False``: served on the fetch service only."""

    def __init__(self, make_node, executor, private_key: Path, run_id: str = "run", name: str = "fake_trainer",
                 blob: bool = True):
        self.node = make_node(name)
        self.weights = WeightsRelease(self.node, load_private_key(private_key), run_id, blob=blob)
        executor.add_node(self.node)

    def release(self, data: bytes, version: int, metadata_json: str) -> Announcement:
        return self.weights.release(version, data, metadata_json)
