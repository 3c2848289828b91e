#!/usr/bin/env python3
"""Where a soccer policy disagrees with a scripted teacher: agreement per action head, by situation.

Usage::

    .venv/bin/python tools/teacher_agreement.py runs/results/ppo_pred-teacher_s0 [--teacher chaser]
        [--opponent scripted] [--periods 960] [--worlds 8] [--seed 0] [--perception realistic] [--json out.json]

Why: a training run logs one agreement figure (``train/teacher_agreement``); whether the misses come from states
where the ball is out of sight (a limit of what the robot can know) or from states where it is in front of the
robot (a limit of the learner) decides what to try next. The policy (a ``policy.safetensors``, or a run or
checkpoint folder) plays team A, stochastically as in ``dynenv-eval``, against ``--opponent`` (``scripted``: the
keeper-and-chasers team; ``self``: the policy on both teams, as in self-play training) for ``--periods`` motion
periods in each of ``--worlds`` worlds; in every state where a learning robot can act, its most likely action is
compared with the action the teacher (``envs.teacher``) would take there. Rows: all states; the ball seen in the
period or not; the true ball distance in bands. The teacher's label frequencies and the policy's greedy ones are
printed below the table.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any, Sequence

import numpy as np

HEADS = ("walk", "turn", "kick", "head")
DISTANCE_BANDS = ((0.0, 0.5), (0.5, 1.5), (1.5, 3.0), (3.0, np.inf))   # m


def agreement_rows(greedy: np.ndarray, teacher: np.ndarray, ball_seen: np.ndarray, ball_distance: np.ndarray
                   ) -> list[dict[str, Any]]:
    """(N, 4) greedy and teacher actions of N acting states, with the ball seen flag and distance (m) of each →
    one row per situation: its name, count, joint agreement (all four heads) and agreement per head (None where
    the situation never occurred)."""
    same = np.asarray(greedy) == np.asarray(teacher)
    seen = np.asarray(ball_seen, bool)
    distance = np.asarray(ball_distance, float)
    situations = [("all", np.ones(len(same), bool)), ("ball seen", seen), ("ball not seen", ~seen)]
    situations += [(f"ball {lo:g}-{hi:g} m", (distance >= lo) & (distance < hi)) for lo, hi in DISTANCE_BANDS]
    rows = []
    for name, mask in situations:
        picked = same[mask]
        count = int(mask.sum())
        rows.append({"situation": name, "count": count,
                     "joint": float(picked.all(-1).mean()) if count else None,
                     **{h: float(picked[:, k].mean()) if count else None for k, h in enumerate(HEADS)}})
    return rows


def frequencies(actions: np.ndarray) -> list[dict[int, float]]:
    """Per head, the share of each action index."""
    out = []
    for k in range(actions.shape[1]):
        values, counts = np.unique(actions[:, k], return_counts=True)
        out.append({int(v): round(float(c) / len(actions), 3) for v, c in zip(values, counts)})
    return out


def collect(policy: str, teacher: str, opponent: str, periods: int, worlds: int, seed: int, perception: str
            ) -> tuple[np.ndarray, ...]:
    """Play and label; (greedy, teacher, ball_seen, ball_distance) over the acting states of the learning robots."""
    import torch

    from dynenv_ros.envs.vector import SoccerVectorEnv
    from dynenv_ros.evaluation.episodes import load_evaluated_policy
    from dynenv_ros.learning.algo.policy import run_sequence
    from dynenv_ros.learning.sampling.opponents import SCRIPTED_TEAM, WorldScriptedOpponent
    from dynenv_ros.learning.sampling.collector import RolloutCollector
    from dynenv_ros.learning.algo.policy import head_outputs

    torch.set_num_threads(1)
    agent, _ = load_evaluated_policy(policy)
    agent.eval()
    env = SoccerVectorEnv(worlds, backend="inprocess", observation="padded", perception=perception, targets=True,
                          scripted_team_b=SCRIPTED_TEAM if opponent == "scripted" else None, teacher=teacher)
    n = env.config.players_per_team
    learning = np.arange(n) if opponent == "scripted" else np.arange(2 * n)
    collector = RolloutCollector(env, agent, learning, WorldScriptedOpponent() if opponent == "scripted" else None,
                                 torch.Generator().manual_seed(seed), seed=seed)
    parts: list[list[np.ndarray]] = [[], [], [], []]
    steps = 32
    try:
        for _ in range(max(1, periods // steps)):
            rollout = collector.collect(steps)
            tensors = rollout.as_tensors()
            with torch.no_grad():
                out = head_outputs(run_sequence(agent, tensors["obs"], tensors["initial_state"], tensors["starts"]),
                                   steps=steps)
                greedy = torch.stack([getattr(out, h).argmax(-1) for h in HEADS], -1).numpy()
            acting = rollout.can_act[:steps]
            pose, ball = rollout.targets["pose"][:steps], rollout.targets["ball"][:steps]
            parts[0].append(greedy[acting])
            parts[1].append(rollout.teacher_actions[acting])
            parts[2].append(rollout.targets["ball_seen"][:steps][acting] > 0)
            parts[3].append(np.hypot(*(ball[..., :2] - pose[..., :2]).transpose(2, 0, 1))[acting])
    finally:
        env.close()
    return tuple(np.concatenate(p) for p in parts)


def format_rows(rows: Sequence[dict[str, Any]]) -> str:
    lines = ["| situation | states | all four heads | " + " | ".join(HEADS) + " |",
             "|---|---:|---:|" + "---:|" * len(HEADS)]
    for r in rows:
        cells = ["–" if r[k] is None else f"{r[k]:.2f}" for k in ("joint", *HEADS)]
        lines.append(f"| {r['situation']} | {r['count']} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("policy", help="policy.safetensors, or a run or training checkpoint folder")
    parser.add_argument("--teacher", default="chaser", help="chaser (default) or eager_chaser")
    parser.add_argument("--opponent", default="scripted", choices=("scripted", "self"))
    parser.add_argument("--periods", type=int, default=960, help="motion periods per world (default 960)")
    parser.add_argument("--worlds", type=int, default=8)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--perception", default="realistic")
    parser.add_argument("--json", type=Path, default=None, help="also write the rows and frequencies here")
    args = parser.parse_args(argv)
    if args.periods < 1 or args.worlds < 1 or args.seed < 0:
        parser.error("--periods and --worlds must be positive, --seed non-negative")
    try:
        greedy, teacher, seen, distance = collect(args.policy, args.teacher, args.opponent, args.periods,
                                                  args.worlds, args.seed, args.perception)
    except (OSError, ValueError) as error:
        print(f"teacher_agreement: {error}", file=sys.stderr)
        return 2
    rows = agreement_rows(greedy, teacher, seen, distance)
    print(format_rows(rows))
    for k, head in enumerate(HEADS):
        print(f"{head}: teacher {frequencies(teacher)[k]}  greedy {frequencies(greedy)[k]}")
    if args.json is not None:
        args.json.write_text(json.dumps({"rows": rows, "teacher": frequencies(teacher),
                                         "greedy": frequencies(greedy)}, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
