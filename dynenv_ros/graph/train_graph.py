"""The main job's ``train`` graph: live training over ROS 2 (``make run ARGS="--set graph=train"``).

``games`` simulator games in stepped mode, each in its own namespace (``/game_1`` …) with one policy node playing
both teams with the trainer's weights; one trainer node learning from all of them for ``train_minutes``; a
recorder of the experience topics (actions, feedback) and the trainer's diagnostics. The summary prints the reward
curve per policy version, the experience rate and the lag, and compares the first third of the episodes with the
last third.

The task learnt is the one a few minutes of two CPU cores can show (docs/ros_graph.md, "The train graph"): the
auxiliary reward alone (walking to the ball and moving it towards the opponent goal, ``reward_weights
[0, 0, 1, 0]``), a small network (D = 32) and short episodes — the graph demonstrates the machinery, it does not
train a team. The budget is ``train_updates`` updates, so a busy machine takes longer but learns as much;
``train_minutes`` only caps the wall time.

The verdict is held out: the policy the trainer started from and the one it ended with each play
``HELD_OUT_EPISODES`` episodes against the random team, in-process on the same simulator code, with the same
episode seeds (common random numbers); the run passes when the mean of the paired differences in auxiliary reward
is above zero by more than two standard errors. The curve of the training episodes is printed beside it, but
self-play episodes of a changing policy against itself are too noisy to decide on (two runs of the earlier
"last third above the first" rule failed here on learning that was there).
"""
from __future__ import annotations

import json
import math
import statistics
from pathlib import Path
from typing import Any

from dynenv_ros.graph.process_graph import GraphOutcome, NodeLaunch
from dynenv_ros.learning.run.checkpoints import START_POLICY
from dynenv_ros.soccer.config import robot_names
from dynenv_ros.security.action_auth import secret_path, write_game_secrets, write_team_secret
from dynenv_ros.security.frame_auth import FRAMES
from dynenv_ros.security.keys import generate_key_pair

# The trainer's settings for the demonstration (the node's defaults are the paper's).
TRAINER_SETTINGS = {"variant": "baseline", "feature_size": 32, "learning_rate": 3e-3, "gamma": 0.9,
                    "normalize_advantages": True, "entropy_coef": 0.0, "sequence_length": 5, "ppo_epochs": 4,
                    "ppo_minibatches": 1, "max_policy_lag": 3, "reward_weights": [0.0, 0.0, 1.0, 0.0],
                    "checkpoint_every_minutes": 1.0}


def train_graph(config: Any, run_dir: Path) -> list[NodeLaunch]:
    players = config.players_per_team
    # A key pair of this run (run_dir/keys): the trainer signs its weights with it, the policy nodes trust its
    # public half only, so the demonstration runs with signed weights as a deployment does (docs/ros_graph.md).
    signing_key, public_key = generate_key_pair(run_dir / "keys")
    # ... and secrets of this run (run_dir/secrets): the teams' and the simulator's, so only the policy nodes' actions
    # are run and learnt, and only the simulators' feedback (authenticated actions, docs/ros_graph.md "Who may act").
    secrets = str(write_game_secrets(run_dir / "secrets", robot_names(players)))
    # ... and frames.secret: the simulators tag their frames, the policy nodes act on and the trainer learns from
    # tagged frames only (docs/ros_graph.md, "Which frames count").
    write_team_secret(secret_path(secrets, FRAMES))
    trainer = NodeLaunch("trainer", "dynenv_ros.nodes.trainer_node", {
        **TRAINER_SETTINGS, "players_per_team": players, "run_dir": str(run_dir / "trainer"), "seed": config.seed,
        "batch_sequences": config.games * 2 * players, "max_minutes": config.train_minutes,
        "max_updates": config.train_updates,
        "signing_key": str(signing_key), "secrets_dir": secrets, "authenticated_frames": True,
        "runtime_controls": False}, ends_run=True)
    nodes: list[NodeLaunch] = []
    topics = ["/trainer/diagnostics"]
    for game in range(1, config.games + 1):
        namespace = f"/game_{game}"
        nodes.append(NodeLaunch(f"sim_game_{game}", "dynenv_ros.nodes.sim_node", {
            "players_per_team": players, "seed": config.seed + game, "perception_preset": config.perception,
            "mode": "stepped", "episode_seconds": config.episode_seconds, "auto_reset": True,
            "publish_markers": False, "wait_for_subscribers": 2, "secrets_dir": secrets,
            "authenticated_frames": True, "runtime_controls": False}, namespace=namespace))
        nodes.append(NodeLaunch(f"policy_game_{game}", "policy_node.policy_node", {
            "players_per_team": players, "seed": config.seed + 100 + game,
            "trusted_weights_keys": [str(public_key)], "secrets_dir": secrets,
            "authenticated_frames": True, "decision_deadline": STEPPED_GAME_DEADLINE, "runtime_controls": False},
            namespace=namespace))
        for team in "ab":
            for slot in range(players):
                topics += [f"{namespace}/team_{team}_{slot}/action", f"{namespace}/team_{team}_{slot}/feedback"]
    recorder = NodeLaunch("recorder", "dynenv_ros.nodes.recorder", {"output": str(run_dir / "bag"),
                                                                     "topics": topics})
    return [recorder, trainer, *nodes]


# A stepped game delivers complete periods and waits for the answers: no decision deadline (the policy node's
# default, 0.05 s on the wall clock, is for a robot's camera; a frame whose tag comes late would be cut by it).
STEPPED_GAME_DEADLINE = -1.0

# The held-out comparison: episodes per policy, their seed (no simulator game of the run uses it), the opponent.
HELD_OUT_EPISODES, HELD_OUT_SEED, HELD_OUT_OPPONENT = 80, 10_000, "random"


def held_out_auxiliary(policy: Path, config: Any) -> list[float]:
    """The auxiliary reward per episode (team mean) of ``policy`` on the held-out episodes."""
    from dynenv_ros.evaluation.soccer import evaluate
    result = evaluate(str(policy), HELD_OUT_OPPONENT, episodes=HELD_OUT_EPISODES, seeds=[HELD_OUT_SEED],
                      players_per_team=config.players_per_team, perception=config.perception,
                      env_config={"episode_seconds": config.episode_seconds})
    return [float(e["terms"]["auxiliary"]) for e in result["episodes"]]


def held_out_verdict(start: list[float], end: list[float]) -> tuple[bool, str]:
    """Paired by episode (same seeds): learnt when the mean difference exceeds two standard errors."""
    if len(start) != len(end) or len(start) < 2:
        raise ValueError(f"need two equal lists of at least 2 episodes, got {len(start)} and {len(end)}")
    gain, se = _mean_se([e - s for s, e in zip(start, end)])
    ok = gain > 2 * se
    return ok, (f"held-out episodes ({len(start)} against the {HELD_OUT_OPPONENT} team, same seeds): auxiliary "
                f"reward {statistics.fmean(end):+.3f} after training vs {statistics.fmean(start):+.3f} at the start, "
                f"gain {gain:+.3f} ± {se:.3f} — {'learnt' if ok else 'NOT clearly learnt'} (needs > 2 standard "
                f"errors)")


def _mean_se(values: list[float]) -> tuple[float, float]:
    mean = statistics.fmean(values)
    se = statistics.stdev(values) / math.sqrt(len(values)) if len(values) > 1 else float("inf")
    return mean, se


def summarise_train(outcome: GraphOutcome, run_dir: Path, config: Any) -> bool:
    path = run_dir / "trainer" / "summary.json"
    try:
        summary = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as error:
        print(f"  no trainer summary ({path}: {error})")
        return False
    diag = summary["diagnostics"]
    wall = max(float(summary.get("wall_seconds", 0.0)), 1e-9)
    print(f"  trainer: {summary['updates']} updates to version {summary['version']}, {summary['env_steps']} "
          f"robot-periods learnt in {wall:.0f} s ({summary['env_steps'] / wall:.1f}/s) from "
          f"{diag['games']} games, {diag['robots']} robots")
    print(f"  experience: {diag['sequences']} sequences; late {diag['late']}, duplicate {diag['duplicate']}, "
          f"missing {diag['missing']}, malformed {diag['malformed']}, cut {diag['cuts']}, stale "
          f"{diag.get('stale_sequences', '0')}, queue dropped {diag.get('queue_dropped', '0')}")
    print(f"  policy lag at the last update: {diag['lag_versions_mean']} versions, {diag['lag_seconds_mean']} s")
    refused = {k: diag.get(k, "0") for k in ("action_mac_missing", "action_mac_invalid", "feedback_mac_missing",
                                             "feedback_mac_invalid") if diag.get(k, "0") != "0"}
    print(f"  authenticated actions: {diag.get('action_authentication', 'off')}; refused "
          f"{', '.join(f'{k} {v}' for k, v in refused.items()) or 'none'}; rival answers "
          f"{diag.get('rival_answers', '0')} (resolved by the feedback's digest {diag.get('rivals_resolved', '0')}),"
          f" unmatched {diag.get('unmatched_action', '0')}, not run {diag.get('not_executed', '0')}")
    _print_curve(summary["episodes"])
    budget = getattr(config, "train_updates", None)
    complete = budget is None or int(summary["updates"]) >= budget
    if not complete:
        print(f"  only {summary['updates']} of {budget} updates before the wall-time cap (train_minutes)")
    machinery = (not diag["learner_error"] and int(summary["updates"]) > 0 and int(diag["malformed"]) == 0
                 and complete)
    if config is None or not machinery:     # nothing to play (tests of the printout), or failed already
        return machinery
    trainer = run_dir / "trainer"
    learnt, line = held_out_verdict(held_out_auxiliary(trainer / START_POLICY, config),
                                    held_out_auxiliary(trainer / "policy.safetensors", config))
    print(f"  {line}")
    return machinery and learnt


def _print_curve(episodes: list) -> None:
    """The training episodes' reward by policy version: how learning went (information, not the verdict)."""
    if len(episodes) < 6:
        print(f"  only {len(episodes)} whole episodes learnt from: too few for a curve")
        return
    episodes = sorted(episodes, key=lambda e: e[0])
    buckets = 6
    print("  reward learnt (auxiliary term) per episode, by the policy version that ended it:")
    size = len(episodes) / buckets
    for k in range(buckets):
        chunk = episodes[round(k * size):round((k + 1) * size)]
        mean, se = _mean_se([r for _, r in chunk])
        print(f"    versions {int(chunk[0][0]):>4}..{int(chunk[-1][0]):<4} {len(chunk):>4} episodes  "
              f"mean {mean:+.3f} ± {se:.3f}")
    third = len(episodes) // 3
    first, first_se = _mean_se([r for _, r in episodes[:third]])
    last, last_se = _mean_se([r for _, r in episodes[-third:]])
    difference, se = last - first, math.hypot(first_se, last_se)
    print(f"  last third of the training episodes vs the first: {last:+.3f} vs {first:+.3f} "
          f"({difference:+.3f} ± {se:.3f}, {third} episodes each)")
