"""The attacker of test_action_auth_graph.py, a process of its own on the test's ROS domain, without the attacked
team's secret. For every period of ``robot`` it sees (its first frame), it publishes on ``/<robot>/action``:

- an action for the period being collected with no MAC, one with a random MAC, and one tagged with another team's
  secret (``team_b.secret`` from ``secrets_dir``: a team B robot gone rogue);
- early actions for the next periods, tagged with that other secret, with plausible learning fields (the current
  policy version it reads from ``/trainer/diagnostics``, log_prob -0.5, value 1.0);
- a replay of the last genuine action it captured on the topic (valid MAC, its nonce already used);

and on ``/<robot>/feedback`` forged feedback for this period and the next (plausible rewards of 0.5): without a
MAC, and tagged with the other team's secret. Runs ``seconds``, then prints what it sent.

``teammate MATE MATE_ID`` after those arguments: it sends nothing of its own making and uses no secret, only
replays each genuine action it captures on ``/<robot>/action`` onto the team-mate's topic ``/<MATE>/action`` at
once (so it can come before the team-mate's own action for that period), unchanged (``teammate_unchanged``: robot_id
still ``robot``'s) and with robot_id altered to ``MATE_ID`` to fit the topic (``teammate_robot_id``; MAC kept)."""
from __future__ import annotations

import copy
import os
import sys
from collections import Counter
from pathlib import Path

import rclpy
from ros_harness import spin_then_report
from diagnostic_msgs.msg import DiagnosticArray
from dynenv_msgs.msg import Action, DetectionArray, StepFeedback

from dynenv_ros.ros import topics
from dynenv_ros.ros.qos import action_stream, sim_stream
from dynenv_ros.security.action_auth import load_secret, tag_action, tag_feedback

FORGED_LOG_PROB, FORGED_VALUE, FORGED_REWARD = -0.5, 1.0, 0.5


def replay_onto_teammate(robot: str, seconds: float, mate: str, mate_id: int) -> None:
    """The ``teammate`` mode (module docstring)."""
    rclpy.init()
    node = rclpy.create_node("attacker")
    onto = node.create_publisher(Action, f"/{mate}/action", action_stream())
    sent: Counter[str] = Counter()

    def on_action(msg: Action) -> None:
        if not len(msg.mac):
            return
        onto.publish(msg)                            # unchanged: robot_id names the robot it was captured from
        sent["teammate_unchanged"] += 1
        altered = copy.deepcopy(msg)
        altered.robot_id = mate_id                   # fits the team-mate's topic; the MAC is the captured one
        onto.publish(altered)
        sent["teammate_robot_id"] += 1

    node.create_subscription(Action, f"/{robot}/action", on_action, action_stream())
    spin_then_report(node, seconds, sent)


def main(robot: str, seconds: float, secrets_dir: str) -> None:
    rclpy.init()
    node = rclpy.create_node("attacker")
    action_topic, feedback_topic = f"/{robot}/action", f"/{robot}/feedback"
    actions = node.create_publisher(Action, action_topic, action_stream())
    feedback = node.create_publisher(StepFeedback, feedback_topic, sim_stream())
    other = load_secret(Path(secrets_dir) / "team_b.secret")
    version = [1]
    sent: Counter[str] = Counter()
    mine: set[bytes] = set()
    captured: list[Action] = []

    def on_diagnostics(msg: DiagnosticArray) -> None:
        for status in msg.status:
            for value in status.values:
                if value.key == "version" and value.value.isdigit():
                    version[0] = int(value.value)

    def publish(kind: str, msg: Action) -> None:
        if len(msg.mac):
            mine.add(bytes(msg.mac))
        actions.publish(msg)
        sent[kind] += 1

    def on_action(msg: Action) -> None:
        if len(msg.mac) and bytes(msg.mac) not in mine:
            captured.append(msg)                     # the genuine policy's: a valid MAC to replay
            del captured[:-4]

    def on_frame(msg: DetectionArray) -> None:
        if msg.frame_index != 0:
            return
        target = msg.motion_period + 1
        for kind in ("no_mac", "random_mac", "other_team"):
            forged = Action(robot_id=msg.robot_id, episode_id=msg.episode_id, motion_period=target, walk=2,
                            policy_version=version[0], log_prob=FORGED_LOG_PROB, value=FORGED_VALUE)
            forged.header.stamp = msg.header.stamp
            forged.header.frame_id = f"{robot}/base_link"
            if kind == "random_mac":
                forged.mac = os.urandom(16)
            elif kind == "other_team":
                forged.mac = tag_action(forged, action_topic, other)
            publish(kind, forged)
        for ahead in (1, 2):                         # early: periods that have not run yet
            early = Action(robot_id=msg.robot_id, episode_id=msg.episode_id, motion_period=target + ahead, walk=1,
                           policy_version=version[0], log_prob=FORGED_LOG_PROB, value=FORGED_VALUE)
            early.mac = tag_action(early, action_topic, other)
            publish("early", early)
        if captured:
            publish("replay", captured[-1])
        for period in (msg.motion_period, msg.motion_period + 1):
            for kind in ("feedback_no_mac", "feedback_other_key"):
                forged = StepFeedback(robot_id=msg.robot_id, episode_id=msg.episode_id, motion_period=period,
                                      reward_primary=FORGED_REWARD, reward_auxiliary=FORGED_REWARD,
                                      reward_total=2 * FORGED_REWARD)
                if kind == "feedback_other_key":
                    forged.mac = tag_feedback(forged, feedback_topic, other)
                feedback.publish(forged)
                sent[kind] += 1

    node.create_subscription(DetectionArray, f"/{robot}/detections", on_frame, sim_stream())
    node.create_subscription(Action, action_topic, on_action, action_stream())
    node.create_subscription(DiagnosticArray, topics.TRAINER_DIAGNOSTICS, on_diagnostics, 10)
    spin_then_report(node, seconds, sent)


if __name__ == "__main__":
    if sys.argv[4:5] == ["teammate"]:
        replay_onto_teammate(sys.argv[1], float(sys.argv[2]), sys.argv[5], int(sys.argv[6]))
    else:
        main(sys.argv[1], float(sys.argv[2]), sys.argv[3])
