"""What the policy node tells a trainer (Action's learning fields) and how it takes a trainer's weights
(PolicyWeights on /trainer/weights: swapped in between decisions, refused with a reason and the old weights kept
playing, delivered at once to a node that starts late)."""
from __future__ import annotations

import hashlib
import math

import pytest
import torch
from dynenv_msgs.msg import PolicyWeights
from rclpy.parameter import Parameter

from dynenv_ros.agent.checkpoint import policy_bytes, save_policy
from dynenv_ros.agent.network import DynEnvAgent
from dynenv_ros.ros import topics
from dynenv_ros.ros.qos import latched
from ros_harness import spin_until
from test_policy_node_faults import Feeder, _policy_node

# Logits of each action head (walk 5, turn 3, kick 3, head 2·3+1 discrete steps of 37.5°/3) and the critic's output,
# set as the heads' biases with zero weights, so the policy's distribution does not depend on what it sees.
LOGITS = {"walk_head": [0.5, -1.0, 2.0, 0.0, 0.3], "turn_head": [1.0, 0.0, -0.5], "kick_head": [-2.0, 0.4, 0.1],
          "head_head": [0.0, 0.2, -0.3, 1.1, 0.0, -1.0, 0.6]}
VALUE = 2.5
HEAD_STEP = math.radians(37.5) / 3


def _fixed_policy() -> DynEnvAgent:
    torch.manual_seed(11)
    agent = DynEnvAgent()
    with torch.no_grad():
        for name, logits in LOGITS.items():
            layer = getattr(agent, name)
            layer.weight.zero_()
            layer.bias.copy_(torch.tensor(logits))
        agent.critic[-1].weight.zero_()
        agent.critic[-1].bias.fill_(VALUE)
    return agent.eval()


def _log_softmax(logits: list[float], index: int) -> float:
    return logits[index] - math.log(sum(math.exp(v) for v in logits))


def test_actions_carry_the_behaviour_log_probability_value_and_version(make_node, executor, tmp_path):
    path = tmp_path / "fixed.safetensors"
    save_policy(_fixed_policy(), path, {"updates": 41})
    policy = _policy_node(make_node, executor, checkpoint=str(path))
    feeder = Feeder(make_node, executor)
    feeder.wait_for()
    for period in range(6):
        action = feeder.act(period)["team_a_0"]
        head_index = round(action.head_yaw_delta / HEAD_STEP) + 3
        expected = (_log_softmax(LOGITS["walk_head"], action.walk) + _log_softmax(LOGITS["turn_head"], action.turn)
                    + _log_softmax(LOGITS["kick_head"], action.kick)
                    + _log_softmax(LOGITS["head_head"], head_index))
        assert action.policy_version == 42                     # 1 + the 41 updates the file records
        assert action.log_prob == pytest.approx(expected, abs=1e-5)
        assert action.value == pytest.approx(VALUE, abs=1e-5)
    assert policy.policy_version == 42


class WeightsSource:
    """A stand-in trainer: publishes PolicyWeights latched, as the trainer node does."""

    def __init__(self, make_node, executor):
        self.node = make_node("fake_trainer")
        self.pub = self.node.create_publisher(PolicyWeights, topics.WEIGHTS, latched(1))
        executor.add_node(self.node)

    def publish(self, data: bytes, version: int, run_id: str = "run", sha256: str | None = None) -> None:
        msg = PolicyWeights(version=version, run_id=run_id, data=data,
                            sha256=hashlib.sha256(data).hexdigest() if sha256 is None else sha256)
        self.pub.publish(msg)


def test_weights_from_the_trainer_are_swapped_in_and_bad_ones_refused(make_node, executor):
    source = WeightsSource(make_node, executor)
    policy = _policy_node(make_node, executor)
    feeder = Feeder(make_node, executor)
    feeder.wait_for()
    assert spin_until(executor, lambda: source.pub.get_subscription_count() >= 1, 10.0)
    assert feeder.act(0)["team_a_0"].policy_version == 0           # untrained smoke-test weights: not learnt from
    good = policy_bytes(_fixed_policy(), {"updates": 6})
    source.publish(good, version=7)
    assert spin_until(executor, lambda: policy.policy_version == 7, 10.0), policy.counts
    assert policy.checkpoint_sha256 == hashlib.sha256(good).hexdigest()
    action = feeder.act(1)["team_a_0"]
    assert action.policy_version == 7 and action.value == pytest.approx(VALUE, abs=1e-5)

    wide = DynEnvAgent(head_max=math.radians(80.0))       # beyond the simulator's head bound
    bad = {"damaged": (good[:-10] + b"0123456789", None, "cannot be read safely"),
           "checksum": (good, "0" * 64, "differs from the message's"),
           "empty": (b"", None, "0 bytes"),
           "not a policy": (b"\x00" * 64, None, "cannot be read safely"),
           "head bound": (policy_bytes(wide), None, "head_max")}
    for number, (name, (data, digest, reason)) in enumerate(bad.items()):
        refused = policy.counts["weights_refused"]
        source.publish(data, version=8 + number, sha256=digest)
        assert spin_until(executor, lambda: policy.counts["weights_refused"] == refused + 1, 10.0), name
        assert reason in policy.weights_refusal, (name, policy.weights_refusal)
        assert policy.policy_version == 7
        assert feeder.act(2 + number)["team_a_0"].policy_version == 7       # still playing the old weights
    assert policy.diagnostics()["weights_refused"] == str(len(bad))


def test_a_policy_node_that_starts_late_gets_the_latest_weights_at_once(make_node, executor):
    source = WeightsSource(make_node, executor)
    data = policy_bytes(_fixed_policy())
    source.publish(data, version=3, run_id="first")
    source.publish(data, version=5, run_id="first")          # depth 1: only this one is kept for late joiners
    policy = _policy_node(make_node, executor, weights_run_id="first")
    assert spin_until(executor, lambda: policy.policy_version == 5, 10.0), policy.counts
    assert policy.counts["weights_loaded"] == 1
    other = policy.counts["weights_other_run"]
    source.publish(policy_bytes(DynEnvAgent()), version=9, run_id="second")   # another run: ignored
    assert spin_until(executor, lambda: policy.counts["weights_other_run"] == other + 1, 10.0)
    assert policy.policy_version == 5


def test_a_node_with_weights_topic_empty_never_follows_a_trainer(make_node, executor):
    source = WeightsSource(make_node, executor)
    source.publish(policy_bytes(_fixed_policy()), version=4)
    policy = _policy_node(make_node, executor, weights_topic="")
    assert policy.weights_sub is None
    assert not spin_until(executor, lambda: policy.policy_version != 0, 1.0)
