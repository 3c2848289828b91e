"""The cost of authenticated actions (issue 27 item 2; goal: under 50 µs per action): what each side adds per
Action and StepFeedback (``security.action_auth``), on real rclpy messages.

- policy node: tag each Action it sends (canonical bytes + HMAC-SHA256);
- simulator: verify the Action's MAC and its nonce (``ReplayGuard``), then the digest of the one it runs, and tag
  the feedback naming it;
- trainer: verify the Action's MAC and digest it (its candidate), verify the feedback's MAC.

Each figure is µs per action of CPU time, the median and [min, max] of ``--repeat`` runs (``benchmarks/timing.py``).
"""
from __future__ import annotations

import json
import os

from benchmarks.timing import format_stat, measure, stat

COUNT = 20_000                    # actions per run
TOPIC, FEEDBACK_TOPIC = "/game_1/team_a_0/action", "/game_1/team_a_0/feedback"


def _messages():
    from dynenv_msgs.msg import Action, StepFeedback
    action = Action(robot_id=0, episode_id=3, motion_period=7, walk=1, turn=2, head_yaw_delta=0.2181662,
                    policy_version=12, log_prob=-2.75, value=0.4)
    action.header.stamp.sec, action.header.stamp.nanosec = 12, 500_000_000
    action.header.frame_id = "team_a_0/base_link"
    feedback = StepFeedback(robot_id=0, episode_id=3, motion_period=7, reward_auxiliary=0.02, reward_total=0.02,
                            seen_object_ids=[1, 3, 4], landmarks_seen=6.0, action_digest=bytes(16))
    return action, feedback


def run(args) -> int:
    from dynenv_ros.security import action_auth as auth

    team, simulator = os.urandom(auth.SECRET_BYTES), os.urandom(auth.SECRET_BYTES)
    action, feedback = _messages()
    action.mac = auth.tag_action(action, TOPIC, team)
    feedback.mac = auth.tag_feedback(feedback, FEEDBACK_TOPIC, simulator)

    def policy_side() -> int:
        for _ in range(COUNT):
            action.mac = auth.tag_action(action, TOPIC, team)
        return COUNT

    def simulator_side() -> int:
        guard = auth.ReplayGuard()
        for period in range(COUNT):
            assert auth.check_action(action, TOPIC, team) == ""
            guard.used((0, 3, period))
            guard.use((0, 3, period))
            feedback.action_digest = auth.action_digest(action, TOPIC)
            feedback.mac = auth.tag_feedback(feedback, FEEDBACK_TOPIC, simulator)
        return COUNT

    def trainer_side() -> int:
        for _ in range(COUNT):
            assert auth.check_action(action, TOPIC, team) == ""
            auth.action_digest(action, TOPIC)
            assert auth.check_feedback(feedback, FEEDBACK_TOPIC, simulator) == ""
        return COUNT

    figures: dict = {"actions_per_run": COUNT, "repeat": args.repeat}
    for name, work in (("tag_action", policy_side), ("simulator", simulator_side), ("trainer", trainer_side)):
        runs = measure(work, args.repeat)
        figures[name] = {"us_per_action_cpu": stat((1e6 * r.cpu_s / r.items for r in runs), 2),
                         "us_per_action_wall": stat((1e6 * r.wall_s / r.items for r in runs), 2)}
    for name, call in (("verify_action", lambda: auth.check_action(action, TOPIC, team)),
                       ("digest_action", lambda: auth.action_digest(action, TOPIC))):
        runs = measure(lambda call=call: [call() for _ in range(COUNT)] and COUNT, args.repeat)
        figures[name] = {"us_per_action_cpu": stat((1e6 * r.cpu_s / r.items for r in runs), 2),
                         "us_per_action_wall": stat((1e6 * r.wall_s / r.items for r in runs), 2)}
    if args.json:
        print(json.dumps(figures))
        return 0
    labels = {"tag_action": "policy node: tag an Action",
              "verify_action": "verify an Action's MAC",
              "digest_action": "digest an Action",
              "simulator": "simulator: verify + nonce + digest + tag the feedback",
              "trainer": "trainer: verify + digest the Action, verify the feedback"}
    print(f"authenticated actions, µs per action (CPU; wall in brackets), median [min–max] of {args.repeat} runs "
          f"of {COUNT:,}; goal < 50 µs")
    for name, label in labels.items():
        cpu, wall = (format_stat(figures[name][key], "{:.1f}") for key in ("us_per_action_cpu", "us_per_action_wall"))
        print(f"  {label:<58} {cpu}   (wall {wall})")
    return 0
