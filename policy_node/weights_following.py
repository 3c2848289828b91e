"""Weights from a trainer (``ros.weights_follower``; docs/ros_graph.md, "Who may change the weights"): taken only when
signed by a key in ``trusted_weights_keys`` and newer than those acting, announced on ``/trainer/weights_announcement``,
their bytes taken from ``/trainer/weights_blob`` (every sample checked, so another writer cannot displace them) or
fetched in chunks from the service the announcement names, without blocking decisions, checked against the signed
digests and, like any policy, by a trial
decision before they are swapped in between two decisions. A mixin of ``PolicyNode``: ``_validate`` and ``_swap``
are the node's.
"""
from __future__ import annotations

import json

import torch
from rclpy.exceptions import ParameterException

from dynenv_ros.agent.checkpoint import agent_config, check_agent_config, policy_from_bytes
from dynenv_ros.agent.export import TorchPolicy
from dynenv_ros.agent.network import DynEnvAgent
from dynenv_ros.ros import topics
from dynenv_ros.ros.weights_follower import WeightsFollower
from dynenv_ros.security.keys import KeyFileError, load_trusted_keys
from dynenv_ros.security.weights_order import ReleaseOrder
from dynenv_ros.security.weights_signing import Announcement
from policy_node.batch_policy import one_line as _one_line


class WeightsFollowing:
    """``_follow_weights`` at start; ``_announced_network`` and ``_install_weights`` for the follower."""

    def _follow_weights(self, topic: str, key_paths: list[str], max_bytes: int, state_file: str,
                        report_s: float) -> WeightsFollower:
        """Signed weights from a trainer (``ros.weights_follower``): only releases a trusted key signed, newer than
        the one acting, fitting this node, fetched without blocking decisions."""
        try:
            trusted = load_trusted_keys(key_paths)
        except KeyFileError as error:
            raise ParameterException(str(error), ["trusted_weights_keys"]) from None
        try:
            order = ReleaseOrder(state_file or None)
        except ValueError as error:
            raise ParameterException(str(error), ["weights_state_file"]) from None
        if trusted:       # the first shape check on torch's meta device imports ~70 MB of torch (2-3 s): now, not
            with torch.device("meta"):          # as a stall of the decisions when the first weights arrive
                DynEnvAgent(feature_size=1)
        return WeightsFollower(self, topic=topic, blob_topic=topics.weights_blob(topic),
                               accept_service="~/accept_older_weights",
                               trusted=trusted, max_bytes=max_bytes, order=order, fits=self._announced_network,
                               install=self._install_weights, counts=self.counts, operator=self.operator,
                               note=lambda text: setattr(self, "weights_refusal", text), run_filter=self.weights_run,
                               report_period_s=report_s)

    def _announced_network(self, metadata_json: str) -> None:
        """ValueError unless an announced network (its signed metadata: the policy file's config) can play here:
        checked before the weights are fetched."""
        if self.runtime_name != "torch":
            raise ValueError(f"weights need the torch runtime; this node runs {self.runtime_name}")
        try:
            meta = json.loads(metadata_json)
            config = check_agent_config(meta["config"])
        except (ValueError, KeyError, TypeError) as error:
            raise ValueError(f"metadata_json does not describe a network: {_one_line(error)}") from None
        problem = self.scenario.network_problem(config, self.action_mode)
        if problem:
            raise ValueError(problem)

    def _install_weights(self, data: bytes, announcement: Announcement) -> str:
        """Swap in fetched weights whose bytes matched the signed SHA-256, after the checks a policy file gets and
        the check that they are the network announced; ValueError with the reason otherwise (the current weights
        keep playing). Returns the file's SHA-256."""
        try:
            agent, _ = policy_from_bytes(data, "weights")
            policy = TorchPolicy(agent)
        except ValueError as error:
            raise ValueError(_one_line(error)) from None
        except Exception as error:           # anything else hostile bytes provoke: refused, not fatal
            raise ValueError(f"{type(error).__name__}: {_one_line(error)}") from None
        if agent_config(agent) != json.loads(announcement.metadata_json)["config"]:
            raise ValueError(f"the file's network {agent_config(agent)} is not the one announced")
        self._validate(policy)
        self._swap(policy, announcement.sha256, int(announcement.version))
        self.weights_acting = (announcement.run_id, int(announcement.version))
        return announcement.sha256
