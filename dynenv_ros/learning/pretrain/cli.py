"""``dynenv-pretrain``: the reconstruction/localization pretraining of the DynEnv agent's encoder (docs/original.md §9.7),
done with the RL agent's own action space, without privileged pose seeding by default, and with real metrics.

    dynenv-pretrain generate --out DIR --train 1024 --test 256 --seed 0
    dynenv-pretrain train --data DIR --out DIR --epochs 30 --seed 0 [--privileged-seeding]
    dynenv-pretrain evaluate --data DIR --policy FILE [--json FILE]

**generate** writes ``DIR/train.npz`` and ``DIR/test.npz`` (compressed numpy archives, no pickled object: they
load with ``allow_pickle=False``). Each sequence is one world of ``SoccerVectorEnv`` (2 v 2, realistic perception,
kick-off start) reset, then stepped by two uniformly random actions of the DISCRETE action space the RL agent uses
(walk 5, turn 3, kick 3, head 2·units+1 — DynEnv pretrained with a continuous head, a distribution shift, §12.16),
each held for 3 motion periods: 7 observations per sequence (reset + 6 steps), every robot's. Worlds run in
batches of ``worlds_per_batch``; batch b of a split is reset with a seed and draws its actions from a generator,
both from ``SeedSequence(seed)`` (child 0 train, 1 test; grandchild b), so the files are a function of
(seed, counts, worlds_per_batch) alone. Arrays (S sequences, T = 7 observations, A = 4 robots), float32 unless said:

- ``landmarks``, ``landmark_mask``, ``objects``, ``object_mask``, ``proprioception``, ``game``,
  ``previous_action`` (S, T, A, …): the padded observation (``envs.padded_layout``), e.g. landmarks
  (S, T, A, 5, L, 19); the slot axes L, O are cut to the split's last used slot (padding only: the agent's outputs
  do not depend on trailing padding);
- ``pose`` (S, T, A, 6), ``ball`` (S, T, A, 3), ``robots`` (S, T, A, R, 6), ``ball_seen`` (S, T, A),
  ``robots_seen`` (S, T, A, R), R = 3: ``env.targets`` of each observation (team frame, metres;
  ``envs.learning_targets``);
- ``ball_known`` (S, T, A), ``robots_known`` (S, T, A, R): seen at least once since the reset (the cumulative max
  of the seen flags over T);
- ``actions`` (S, T−1, A, 4) int64: the action every robot took at each step;
- ``meta`` () str: JSON with the format, seeds, counts and settings.

**train** trains the agent's localization stream, pose head, object stream and reconstruction head on
localization + reconstruction loss (``algo.auxiliary.self_supervised_losses``, weights 1; no RL), Adam lr 1e-3 with
cosine annealing to 1e-4 over the epochs, minibatches of whole robot-sequences (default 16 = DynEnv's 4 sequences ×
4 robots), each robot-sequence starting from the zero recurrent state. A validation split of whole sequences is
held out of train.npz (``--validation-fraction``, default 1/8; 0 validates on the test set, as DynEnv did — then
the test figures are optimistic); the model with the best validation score, (mean localization fraction at
25/50/100 cm + mean reconstruction AP at 25/50/100 cm)/2 over every step, is kept, written as a policy file
(``save_policy``, ``DIR/pretrained.safetensors``; the trainer's ``pretrained_encoder`` takes it) and evaluated on
the test set: ``DIR/metrics.json`` and a printed table.

``--privileged-seeding`` reproduces DynEnv: the localization LSTM's cell state at the first observation is
tanh(Linear(6→64)(true pose + noise)) (its ``set_state``), the noise N(0, 0.02²) in DynEnv's normalised units
(1 unit = 5.2 m: σ = 0.104 m on x, y; 0.02 on the cos/sin components). The seeder's weights ride in the policy
file's meta (``pose_seeder``), so ``evaluate`` runs the model the way it was trained (with a fixed noise seed).

**evaluate** prints the test-set table of a policy file: localization fractions, real reconstruction AP
(``reconstruction_metrics.detection_ap``) and DynEnv's (P + R)/2 "AP" at its actual thresholds (52/104/208 cm)
beside the paper's Table 3 — at every step of the sequences and at the last step only.

Bad arguments and missing or corrupt data or policy files exit with code 2 and a one-line reason.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import NoReturn, Sequence

import torch

from dynenv_ros.learning.pretrain.data import PROG, generate, load_data
from dynenv_ros.learning.pretrain.evaluate import evaluate_policy, format_table
from dynenv_ros.learning.pretrain.train import PretrainConfig, _jsonable, load_pretrained, pretrain


class _Parser(argparse.ArgumentParser):
    """Errors as one line on stderr and exit code 2 (no usage block)."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{PROG}: error: {message}\n")


def _parser() -> argparse.ArgumentParser:
    parser = _Parser(prog=PROG, description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True, metavar="{generate,train,evaluate}")
    g = sub.add_parser("generate", help="generate the train and test sequences")
    g.add_argument("--out", required=True, type=Path, help="folder for train.npz and test.npz")
    g.add_argument("--train", type=int, default=1024, help="training sequences (default 1024)")
    g.add_argument("--test", type=int, default=256, help="test sequences (default 256)")
    g.add_argument("--seed", type=int, default=0)
    g.add_argument("--perception", default="realistic", choices=("realistic", "dynenv", "none"))
    g.add_argument("--worlds-per-batch", type=int, default=32, help="worlds stepped together (default 32)")
    g.add_argument("--workers", type=int, default=1, help="worker processes (default 1: in this process)")
    t = sub.add_parser("train", help="pretrain on generated data")
    t.add_argument("--data", required=True, type=Path, help="folder with train.npz and test.npz")
    t.add_argument("--out", required=True, type=Path, help="folder for pretrained.safetensors and metrics.json")
    t.add_argument("--epochs", type=int, default=30)
    t.add_argument("--seed", type=int, default=0)
    t.add_argument("--batch", type=int, default=16, help="robot-sequences per minibatch (default 16)")
    t.add_argument("--lr", type=float, default=1e-3, help="initial learning rate (default 1e-3)")
    t.add_argument("--final-lr", type=float, default=1e-4, help="cosine annealing floor (default 1e-4)")
    t.add_argument("--validation-fraction", type=float, default=0.125,
                   help="training sequences held out for model selection (default 0.125; 0 = the test set)")
    t.add_argument("--privileged-seeding", action="store_true",
                   help="seed the localization LSTM from the true initial pose + noise (DynEnv's setting)")
    t.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    e = sub.add_parser("evaluate", help="test-set metrics of a policy file")
    e.add_argument("--data", required=True, type=Path, help="folder with test.npz")
    e.add_argument("--policy", required=True, type=Path, help="policy file (.safetensors)")
    e.add_argument("--json", type=Path, help="also write the metrics here")
    e.add_argument("--threads", type=int, default=1)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = _parser().parse_args(argv)

    def log(message: str) -> None:
        print(message, flush=True)

    try:
        if args.command == "generate":
            if args.train < 1 or args.test < 1:
                raise ValueError(f"--train and --test must be at least 1, got {args.train} and {args.test}")
            generate(args.out, args.train, args.test, args.seed, 2, args.perception, args.worlds_per_batch,
                     args.workers, log)
        elif args.command == "train":
            cfg = PretrainConfig(epochs=args.epochs, batch=args.batch, learning_rate=args.lr,
                                 final_learning_rate=args.final_lr, seed=args.seed,
                                 privileged_seeding=args.privileged_seeding,
                                 validation_fraction=args.validation_fraction, threads=args.threads)
            cfg.check()
            pretrain(load_data(args.data), args.out, cfg, log)
        else:
            if args.threads < 1:
                raise ValueError(f"--threads must be at least 1, got {args.threads}")
            torch.set_num_threads(args.threads)
            test = load_data(args.data, ("test",))["test"]
            agent, seeder, meta = load_pretrained(args.policy)
            metrics = evaluate_policy(agent, test, seeder)
            log(format_table(metrics, f"{args.policy} on {test.path}"))
            if args.json:
                args.json.write_text(json.dumps(_jsonable({"policy": str(args.policy), "meta": meta,
                                                           "test": metrics}), indent=2) + "\n")
    except (ValueError, OSError) as error:
        print(f"{PROG}: error: {str(error).splitlines()[0] if str(error) else type(error).__name__}",
              file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
