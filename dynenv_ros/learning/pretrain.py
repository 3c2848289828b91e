"""dynenv-pretrain: the reconstruction/localization pretraining of the DynEnv agent's encoder (docs/original.md §9.7),
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
localization + reconstruction loss (``algorithms.self_supervised_losses``, weights 1; no RL), Adam lr 1e-3 with
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
import copy
import json
import math
import sys
import time
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, NoReturn, Sequence

import numpy as np
import torch

PROG = "dynenv-pretrain"
DATA_FORMAT = "dynenv_ros.pretrain_data/1"
POLICY_KIND = "dynenv_ros.pretrained_encoder/1"
OBS_KEYS = ("landmarks", "landmark_mask", "objects", "object_mask", "proprioception", "game", "previous_action")
TARGET_KEYS = ("pose", "ball", "robots", "ball_seen", "robots_seen")
KNOWN_KEYS = ("ball_known", "robots_known")
ARRAY_KEYS = OBS_KEYS + TARGET_KEYS + KNOWN_KEYS + ("actions",)
SPLITS = ("train", "test")
ACTIONS_PER_SEQUENCE = 2
PERIODS_PER_ACTION = 3
OBSERVATIONS = 1 + ACTIONS_PER_SEQUENCE * PERIODS_PER_ACTION           # 7
ENCODER_PREFIXES = ("localization.", "pose_head.", "objects.", "reconstruction.")
PAPER_TABLE3 = {"localization": (83.0, 100.0, 100.0), "reconstruction": (54.0, 70.0, 92.0)}
UNIT_METRES = 5.2                    # DynEnv's normalised unit (520 px at 1 px = 1 cm)
SEED_NOISE = 0.02                    # DynEnv's pose-seeding noise, in its normalised units


# ------------------------------------------------------------------------------------------------------------------
# Data

@dataclass
class Split:
    """One data file in memory: ``arrays`` (``ARRAY_KEYS`` → numpy, (S, T, A, …)) and its ``meta``."""
    arrays: dict[str, np.ndarray]
    meta: dict[str, Any]
    path: str = ""

    @property
    def sequences(self) -> int:
        return int(self.arrays["pose"].shape[0])

    @property
    def robots(self) -> int:
        return int(self.arrays["pose"].shape[2])

    def subset(self, sequences: np.ndarray) -> "Split":
        return Split({k: v[sequences] for k, v in self.arrays.items()}, dict(self.meta), self.path)


def _trim_slots(arrays: dict[str, np.ndarray], rows: str, mask: str) -> None:
    """Cut a stream's slot axis to its last slot used anywhere in the split (at least 1)."""
    used = np.flatnonzero(arrays[mask].reshape(-1, arrays[mask].shape[-1]).any(0))
    keep = int(used[-1]) + 1 if used.size else 1
    arrays[rows] = np.ascontiguousarray(arrays[rows][..., :keep, :])
    arrays[mask] = np.ascontiguousarray(arrays[mask][..., :keep])


def generate_split(count: int, seed: np.random.SeedSequence, players_per_team: int = 2, perception: str = "realistic",
                   worlds_per_batch: int = 32, workers: int = 1) -> dict[str, np.ndarray]:
    """``count`` sequences (module docstring) as arrays with leading (S, T, A) axes (``actions``: (S, T−1, A, 4))."""
    from dynenv_ros.envs.vector import SoccerVectorEnv
    from dynenv_ros.soccer.config import SoccerConfig

    if count < 1:
        raise ValueError(f"a split needs at least 1 sequence, got {count}")
    config = SoccerConfig.from_mapping({"players_per_team": players_per_team, "head_mode": "discrete"})
    sizes = np.array([5, 3, 3, 2 * config.motion.head_units + 1])
    worlds = min(worlds_per_batch, count)
    batches = math.ceil(count / worlds)
    backend = "inprocess" if workers <= 1 else "subprocess"
    parts: list[dict[str, np.ndarray]] = []
    with SoccerVectorEnv(worlds, backend=backend, workers=workers if workers > 1 else None, config=config,
                         perception=perception, targets=True) as env:
        A = config.n_robots
        for child in seed.spawn(batches):
            world_seed, action_seed = child.spawn(2)
            rng = np.random.default_rng(action_seed)
            choice = rng.integers(0, sizes, size=(ACTIONS_PER_SEQUENCE, worlds, A, 4))
            obs = env.reset(seed=int(world_seed.generate_state(1, np.uint64)[0]))
            steps = [(obs, env.targets)]
            actions = []
            for t in range(ACTIONS_PER_SEQUENCE * PERIODS_PER_ACTION):
                action = choice[t // PERIODS_PER_ACTION]
                result = env.step(action)
                if (result.terminated | result.truncated).any():
                    raise RuntimeError("an episode ended inside a pretraining sequence (episode too short)")
                actions.append(action)
                steps.append((result.observations, result.targets))
            part = {k: np.stack([o[k] for o, _ in steps], axis=1) for k in OBS_KEYS}
            part.update({k: np.stack([g[k] for _, g in steps], axis=1) for k in TARGET_KEYS})
            part["actions"] = np.stack(actions, axis=1).astype(np.int64)
            parts.append(part)
    arrays = {k: np.concatenate([p[k] for p in parts])[:count] for k in parts[0]}
    for k in OBS_KEYS + TARGET_KEYS:
        arrays[k] = arrays[k].astype(np.float32, copy=False)
    arrays["ball_known"] = np.maximum.accumulate(arrays["ball_seen"], axis=1)
    arrays["robots_known"] = np.maximum.accumulate(arrays["robots_seen"], axis=1)
    _trim_slots(arrays, "landmarks", "landmark_mask")
    _trim_slots(arrays, "objects", "object_mask")
    return arrays


def generate(out: str | Path, train: int = 1024, test: int = 256, seed: int = 0, players_per_team: int = 2,
             perception: str = "realistic", worlds_per_batch: int = 32, workers: int = 1,
             log: Any = None) -> dict[str, Any]:
    """Write ``out/train.npz`` and ``out/test.npz``; returns {split: {path, sequences, seconds}}."""
    if seed < 0:
        raise ValueError(f"--seed must be non-negative, got {seed}")
    if worlds_per_batch < 1 or workers < 1:
        raise ValueError("worlds per batch and workers must be at least 1")
    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    children = np.random.SeedSequence(seed).spawn(len(SPLITS))
    report: dict[str, Any] = {}
    for split, count, child in zip(SPLITS, (train, test), children):
        started = time.perf_counter()
        arrays = generate_split(count, child, players_per_team, perception, worlds_per_batch, workers)
        meta = {"format": DATA_FORMAT, "split": split, "sequences": count, "seed": seed,
                "seed_sequence_child": SPLITS.index(split), "players_per_team": players_per_team,
                "perception": perception, "worlds_per_batch": worlds_per_batch, "head_mode": "discrete",
                "observations_per_sequence": OBSERVATIONS, "actions_per_sequence": ACTIONS_PER_SEQUENCE,
                "periods_per_action": PERIODS_PER_ACTION, "start": "kick-off",
                "shapes": {k: list(v.shape) for k, v in arrays.items()}}
        path = folder / f"{split}.npz"
        tmp = folder / f".{split}.tmp.npz"
        np.savez_compressed(tmp, meta=np.array(json.dumps(meta, sort_keys=True)), **arrays)
        tmp.replace(path)
        seconds = time.perf_counter() - started
        report[split] = {"path": str(path), "sequences": count, "seconds": seconds}
        if log:
            log(f"{split}: {count} sequences in {seconds:.1f} s -> {path} ({path.stat().st_size / 1e6:.1f} MB)")
    return report


def load_split(path: str | Path) -> Split:
    """A data file written by ``generate``, checked (keys, dtypes, shapes, finite values); ValueError saying what
    is wrong otherwise."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"data file {path} does not exist")
    try:
        with np.load(path, allow_pickle=False) as archive:
            missing = [k for k in ARRAY_KEYS + ("meta",) if k not in archive.files]
            if missing:
                raise ValueError(f"data file {path} lacks {', '.join(missing)} (not written by {PROG} generate?)")
            arrays = {k: archive[k] for k in ARRAY_KEYS}
            meta = json.loads(str(archive["meta"]))
    except ValueError as error:
        if str(error).startswith(f"data file {path}"):
            raise
        raise ValueError(f"data file {path} is corrupt: {str(error).splitlines()[0] if str(error) else error!r}") \
            from None
    except (OSError, EOFError, zipfile.BadZipFile, zlib.error, KeyError, json.JSONDecodeError) as error:
        raise ValueError(f"data file {path} is corrupt: {type(error).__name__}: {error}") from None
    if not isinstance(meta, dict) or meta.get("format") != DATA_FORMAT:
        raise ValueError(f"data file {path} is not a {DATA_FORMAT} file")
    pose = arrays["pose"]
    if pose.ndim != 4 or pose.shape[1] != OBSERVATIONS or pose.shape[-1] != 6 or pose.shape[0] < 1:
        raise ValueError(f"data file {path}: pose has shape {pose.shape}, expected (S, {OBSERVATIONS}, A, 6)")
    S, T, A = pose.shape[:3]
    for key, value in arrays.items():
        lead = (S, T - 1, A) if key == "actions" else (S, T, A)
        if value.shape[:3] != lead:
            raise ValueError(f"data file {path}: {key} has shape {value.shape}, expected leading axes {lead}")
        if key != "actions" and value.dtype != np.float32:
            raise ValueError(f"data file {path}: {key} has dtype {value.dtype}, expected float32")
        if key != "actions" and not np.isfinite(value).all():
            raise ValueError(f"data file {path}: {key} holds non-finite values")
    if arrays["robots"].shape[3:] != (A - 1, 6) or arrays["robots_known"].shape[3:] != (A - 1,):
        raise ValueError(f"data file {path}: robots has shape {arrays['robots'].shape}, expected (S, T, A, A-1, 6)")
    return Split(arrays, meta, str(path))


def load_data(folder: str | Path, splits: Sequence[str] = SPLITS) -> dict[str, Split]:
    folder = Path(folder)
    if not folder.is_dir():
        raise ValueError(f"data folder {folder} does not exist")
    return {split: load_split(folder / f"{split}.npz") for split in splits}


# ------------------------------------------------------------------------------------------------------------------
# Model, batches, losses

def make_agent(feature_size: int = 64):
    """The agent as the RL trainer builds it (discrete head with the soccer config's units and largest turn)."""
    from dynenv_ros.agent.network import DynEnvAgent
    from dynenv_ros.soccer.config import SoccerConfig

    motion = SoccerConfig().motion
    return DynEnvAgent(feature_size, "discrete", motion.head_units, motion.head_max_delta)


class PoseSeeder(torch.nn.Module):
    """DynEnv's ``LSTMLayer.set_state``: the localization LSTM's cell state c = tanh(Linear(6→D)(pose))."""

    def __init__(self, feature_size: int = 64) -> None:
        super().__init__()
        self.linear = torch.nn.Linear(6, feature_size)

    def forward(self, pose: torch.Tensor) -> torch.Tensor:
        return torch.tanh(self.linear(pose))

    def to_meta(self) -> dict[str, Any]:
        return {"weight": self.linear.weight.detach().tolist(), "bias": self.linear.bias.detach().tolist()}

    @classmethod
    def from_meta(cls, value: Mapping[str, Any]) -> "PoseSeeder":
        weight = torch.tensor(value["weight"], dtype=torch.float32)
        seeder = cls(weight.shape[0])
        with torch.no_grad():
            seeder.linear.weight.copy_(weight)
            seeder.linear.bias.copy_(torch.tensor(value["bias"], dtype=torch.float32))
        return seeder


def seeding_noise(shape: Sequence[int], generator: torch.Generator) -> torch.Tensor:
    """DynEnv's N(0, 0.02²) in its normalised units, in ours: σ = 0.104 m on x, y, 0.02 on cos/sin."""
    scale = torch.tensor([SEED_NOISE * UNIT_METRES] * 2 + [SEED_NOISE] * 4)
    return torch.randn(tuple(shape), generator=generator) * scale


def robot_sequences(split: Split) -> dict[str, torch.Tensor]:
    """Every array as a tensor with leading (T, B) axes, B = S·A robot-sequences (sequence-major)."""
    out = {}
    for key, value in split.arrays.items():
        moved = np.moveaxis(value, 1, 0)                            # (T, S, A, ...)
        out[key] = torch.from_numpy(np.ascontiguousarray(moved.reshape(moved.shape[0], -1, *moved.shape[3:])))
    return out


def _batch(data: Mapping[str, torch.Tensor], rows: torch.Tensor) -> tuple[dict, dict]:
    obs = {k: data[k][:, rows] for k in OBS_KEYS}
    targets = {k: data[k][:, rows] for k in ("pose", "ball", "robots", "ball_known", "robots_known")}
    return obs, targets


def initial_state(agent: Any, pose0: torch.Tensor, seeder: PoseSeeder | None,
                  generator: torch.Generator | None) -> tuple[torch.Tensor, ...]:
    """The zero recurrent state of B robots; with a seeder, the localization cell seeded from the noisy pose."""
    state = list(agent.initial_state(pose0.shape[0]))
    if seeder is not None:
        noise = seeding_noise(pose0.shape, generator) if generator is not None else 0.0
        state[1] = seeder(pose0 + noise)
    return tuple(state)


def forward(agent: Any, obs: Mapping[str, torch.Tensor], pose0: torch.Tensor, seeder: PoseSeeder | None,
            generator: torch.Generator | None) -> Any:
    from dynenv_ros.learning.algorithms import run_sequence

    T, B = obs["game"].shape[:2]
    state = initial_state(agent, pose0, seeder, generator)
    return run_sequence(agent, obs, state, torch.zeros(T, B, dtype=torch.bool))


def losses(out: Any, targets: Mapping[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    from dynenv_ros.learning.algorithms import self_supervised_losses

    parts = self_supervised_losses(out, targets, use_localization=True, use_reconstruction=True)
    parts["loss"] = parts["localization"] + parts["reconstruction"]
    return parts


# ------------------------------------------------------------------------------------------------------------------
# Evaluation

@torch.no_grad()
def predict(agent: Any, split: Split, seeder: PoseSeeder | None = None, batch: int = 256,
            noise_seed: int = 12345) -> dict[str, np.ndarray]:
    """The model's outputs over a split, (T, B, …) numpy (B = S·A), plus the mean losses."""
    data = robot_sequences(split)
    T, B = data["pose"].shape[:2]
    generator = torch.Generator().manual_seed(noise_seed) if seeder is not None else None
    keys = ("pose", "ball", "ball_confidence", "robots", "robot_confidence")
    pieces: dict[str, list[np.ndarray]] = {k: [] for k in keys}
    totals: dict[str, float] = {}
    was_training = agent.training
    agent.eval()
    for rows in torch.arange(B).split(batch):
        obs, targets = _batch(data, rows)
        out = forward(agent, obs, targets["pose"][0], seeder, generator)
        for k in keys:
            pieces[k].append(getattr(out, k).numpy())
        for name, value in losses(out, targets).items():
            totals[name] = totals.get(name, 0.0) + float(value) * len(rows)
    agent.train(was_training)
    result = {k: np.concatenate(v, axis=1) for k, v in pieces.items()}
    result.update({f"loss_{name}": np.float64(value / B) for name, value in totals.items()})
    return result


def _sigmoid(x: np.ndarray) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-np.asarray(x, np.float64)))


def _assigned_slots(targets: np.ndarray, known: np.ndarray) -> np.ndarray:
    """(N, M) anchor slot of each robot target (``losses.assign_slots``, as the reconstruction loss)."""
    from dynenv_ros.agent.losses import ANCHORS, assign_slots

    anchors = np.asarray(ANCHORS, np.float64)
    out = np.zeros(known.shape, np.int64)
    for n in np.flatnonzero(known.any(-1)):
        out[n] = assign_slots(anchors, targets[n], known[n]).numpy()
    return out


def metrics_of(prediction: Mapping[str, np.ndarray], split: Split) -> dict[str, Any]:
    """Localization and reconstruction metrics (``reconstruction_metrics``) over every step ("all"), the last
    step ("last") and each step ("per_step"), plus the mean losses."""
    from dynenv_ros.learning import reconstruction_metrics as rm

    data = {k: np.moveaxis(v, 1, 0).reshape(v.shape[1], -1, *v.shape[3:]) for k, v in split.arrays.items()
            if k in ("pose", "ball", "robots", "ball_known", "robots_known")}           # (T, B, ...)
    T = data["pose"].shape[0]
    assigned = np.stack([_assigned_slots(data["robots"][t], data["robots_known"][t] > 0.5) for t in range(T)])

    def block(steps: slice | int) -> dict[str, Any]:
        def pick(x: np.ndarray) -> np.ndarray:
            x = x[steps] if isinstance(steps, slice) else x[steps:steps + 1]
            return x.reshape(-1, *x.shape[2:])
        pose, true_pose = pick(prediction["pose"]), pick(data["pose"])
        localization = rm.localization_fractions(pose[:, :2], true_pose[:, :2], rm.THRESHOLDS)
        original_localization = rm.localization_fractions(pose[:, :2], true_pose[:, :2],
                                                          rm.ORIGINAL_LOCALIZATION_THRESHOLDS)
        ball_known = pick(data["ball_known"]) > 0.5
        classes = {
            "ball": {"pred_xy": pick(prediction["ball"])[:, None, :2],
                     "confidence": _sigmoid(pick(prediction["ball_confidence"]))[:, None],
                     "true_xy": pick(data["ball"])[:, None, :2], "known": ball_known[:, None],
                     "assigned": np.zeros((len(ball_known), 1), np.int64)},
            "robots": {"pred_xy": pick(prediction["robots"])[..., :2],
                       "confidence": _sigmoid(pick(prediction["robot_confidence"])),
                       "true_xy": pick(data["robots"])[..., :2], "known": pick(data["robots_known"]) > 0.5,
                       "assigned": pick(assigned)},
        }
        report = rm.reconstruction_report(classes)
        return {"localization": localization, "localization_original_thresholds": original_localization,
                "reconstruction_ap": report["ap"], "reconstruction_ap_ignore_unknown": report["ap_ignore_unknown"],
                "original_ap": report["original"],
                "robot_steps": int(len(pose)), "known_balls": int(ball_known.sum()),
                "known_robots": int(classes["robots"]["known"].sum())}

    result = {"all": block(slice(None)), "last": block(T - 1), "per_step": [block(t) for t in range(T)]}
    result["losses"] = {k[5:]: float(v) for k, v in prediction.items() if k.startswith("loss_")}
    return result


def validation_score(metrics: Mapping[str, Any]) -> float:
    """(mean localization fraction at 25/50/100 cm + mean reconstruction AP at 25/50/100 cm)/2, every step."""
    loc = float(np.mean(list(metrics["all"]["localization"].values())))
    ap = [v for v in metrics["all"]["reconstruction_ap"]["mean"].values() if np.isfinite(v)]
    return (loc + (float(np.mean(ap)) if ap else 0.0)) / 2


def evaluate_policy(agent: Any, split: Split, seeder: PoseSeeder | None = None) -> dict[str, Any]:
    return metrics_of(predict(agent, split, seeder), split)


def _pct(x: float) -> str:
    return f"{'n/a' if x is None or not np.isfinite(x) else f'{100 * x:.1f}':>7s}"


def format_table(metrics: Mapping[str, Any], title: str = "test set") -> str:
    """The Table-3-style summary (percent)."""
    lines = [f"{title}: {metrics['all']['robot_steps']} robot-steps ({metrics['last']['robot_steps']} at the last "
             f"step); known balls {metrics['all']['known_balls']}, known robots {metrics['all']['known_robots']}"]
    header = f"{'':44s}{'25cm':>7s}{'50cm':>7s}{'1m':>7s}   {'25cm':>7s}{'50cm':>7s}{'1m':>7s}"
    lines += [f"{'':44s}{'every step':^21s}   {'last step':^21s}", header]

    def row(label: str, get) -> None:
        values = [get(metrics[w]) for w in ("all", "last")]
        lines.append(f"{label:44s}" + "".join(_pct(v) for v in values[0]) + "   "
                     + "".join(_pct(v) for v in values[1]))

    row("localization (error < 25/50/100 cm)", lambda m: list(m["localization"].values()))
    row("localization (26/52/104 cm, DynEnv's)", lambda m: list(m["localization_original_thresholds"].values()))
    for name in ("ball", "robots", "mean"):
        row(f"reconstruction AP, {name}", lambda m, n=name: list(m["reconstruction_ap"][n].values()))
    for name in ("ball", "robots", "mean"):
        row(f"  AP, unseen objects ignored, {name}",
            lambda m, n=name: list(m["reconstruction_ap_ignore_unknown"][n].values()))
    for name in ("ball", "robots", "mean"):
        row(f"DynEnv (P+R)/2 @52/104/208cm, {name}",
            lambda m, n=name: [v["ap"] for v in m["original_ap"][n].values()])
    row("  its precision, mean", lambda m: [v["precision"] for v in m["original_ap"]["mean"].values()])
    row("  its recall, mean", lambda m: [v["recall"] for v in m["original_ap"]["mean"].values()])
    loc, rec = PAPER_TABLE3["localization"], PAPER_TABLE3["reconstruction"]
    lines.append(f"{'paper Table 3: localization':44s}" + "".join(_pct(v / 100) for v in loc))
    lines.append(f"{'paper Table 3: reconstruction (P+R)/2':44s}" + "".join(_pct(v / 100) for v in rec))
    return "\n".join(lines)


# ------------------------------------------------------------------------------------------------------------------
# Training

@dataclass
class PretrainConfig:
    epochs: int = 30
    batch: int = 16                    # robot-sequences per minibatch
    learning_rate: float = 1e-3
    final_learning_rate: float = 1e-4
    seed: int = 0
    privileged_seeding: bool = False
    validation_fraction: float = 0.125
    feature_size: int = 64
    threads: int = 1

    def check(self) -> None:
        if self.epochs < 1:
            raise ValueError(f"--epochs must be at least 1, got {self.epochs}")
        if self.batch < 1:
            raise ValueError(f"--batch must be at least 1, got {self.batch}")
        if not (self.learning_rate > 0 and self.final_learning_rate > 0):
            raise ValueError("learning rates must be positive")
        if not 0.0 <= self.validation_fraction < 1.0:
            raise ValueError(f"--validation-fraction must be in [0, 1), got {self.validation_fraction}")
        if self.seed < 0:
            raise ValueError(f"--seed must be non-negative, got {self.seed}")
        if self.threads < 1:
            raise ValueError(f"--threads must be at least 1, got {self.threads}")


def split_validation(train: Split, fraction: float, seed: int) -> tuple[Split, Split | None]:
    """Whole sequences held out of the training file (a seeded permutation); None when fraction is 0."""
    if fraction <= 0:
        return train, None
    S = train.sequences
    held = max(1, int(round(fraction * S)))
    if held >= S:
        raise ValueError(f"{S} training sequences cannot spare {held} for validation")
    order = np.random.default_rng(np.random.SeedSequence([seed, 1])).permutation(S)
    return train.subset(np.sort(order[held:])), train.subset(np.sort(order[:held]))


def pretrain(data: Mapping[str, Split], out: str | Path, cfg: PretrainConfig, log: Any = print) -> dict[str, Any]:
    """Train, keep the best model by validation score, evaluate it on the test set; write
    ``out/pretrained.safetensors`` and ``out/metrics.json``. Returns the metrics dict."""
    from dynenv_ros.agent.checkpoint import save_policy

    cfg.check()
    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(cfg.threads)
    train, validation = split_validation(data["train"], cfg.validation_fraction, cfg.seed)
    validation_name = "held-out training sequences"
    if validation is None:
        validation, validation_name = data["test"], "the test set (as DynEnv; test figures optimistic)"
    seeds = np.random.SeedSequence(cfg.seed).spawn(2)
    torch.manual_seed(int(seeds[0].generate_state(1)[0]))
    agent = make_agent(cfg.feature_size)
    seeder = PoseSeeder(cfg.feature_size) if cfg.privileged_seeding else None
    generator = torch.Generator().manual_seed(int(seeds[1].generate_state(1)[0]))
    parameters = [p for name, p in agent.named_parameters() if name.startswith(ENCODER_PREFIXES)]
    if seeder is not None:
        parameters += list(seeder.parameters())
    optimizer = torch.optim.Adam(parameters, lr=cfg.learning_rate)
    scheduler = torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, T_max=cfg.epochs,
                                                           eta_min=cfg.final_learning_rate)
    tensors = robot_sequences(train)
    B = tensors["pose"].shape[1]
    log(f"training on {train.sequences} sequences ({B} robot-sequences), validating on {validation.sequences} "
        f"({validation_name}); {cfg.epochs} epochs of {math.ceil(B / cfg.batch)} minibatches of {cfg.batch}"
        f"{'; privileged pose seeding' if seeder else ''}")
    history: list[dict[str, Any]] = []
    best: dict[str, Any] = {"score": -math.inf}
    started = time.perf_counter()
    for epoch in range(1, cfg.epochs + 1):
        epoch_started = time.perf_counter()
        agent.train()
        sums: dict[str, float] = {}
        lr = optimizer.param_groups[0]["lr"]
        for rows in torch.randperm(B, generator=generator).split(cfg.batch):
            obs, targets = _batch(tensors, rows)
            out_ = forward(agent, obs, targets["pose"][0], seeder, generator)
            parts = losses(out_, targets)
            optimizer.zero_grad(set_to_none=True)
            parts["loss"].backward()
            optimizer.step()
            for name, value in parts.items():
                sums[name] = sums.get(name, 0.0) + float(value.detach()) * len(rows)
        scheduler.step()
        train_seconds = time.perf_counter() - epoch_started
        val_metrics = evaluate_policy(agent, validation, seeder)
        score = validation_score(val_metrics)
        entry = {"epoch": epoch, "learning_rate": lr, "train_seconds": train_seconds,
                 "validation_seconds": time.perf_counter() - epoch_started - train_seconds,
                 "train": {name: value / B for name, value in sums.items()},
                 "validation": {"score": score, "losses": val_metrics["losses"],
                                "localization": val_metrics["all"]["localization"],
                                "reconstruction_ap": val_metrics["all"]["reconstruction_ap"]["mean"]}}
        history.append(entry)
        if score > best["score"]:
            best = {"score": score, "epoch": epoch, "agent": copy.deepcopy(agent.state_dict()),
                    "seeder": copy.deepcopy(seeder.state_dict()) if seeder else None}
        log(f"epoch {epoch:3d}/{cfg.epochs}  lr {lr:.2e}  train loss {entry['train']['loss']:.4f} "
            f"(loc {entry['train']['localization']:.4f}, recon {entry['train']['reconstruction']:.4f})  "
            f"val loss {val_metrics['losses']['loss']:.4f}  val score {score:.4f}"
            f"{' *' if best['epoch'] == epoch else ''}  {train_seconds:.1f}+{entry['validation_seconds']:.1f} s")
    agent.load_state_dict(best["agent"])
    if seeder is not None:
        seeder.load_state_dict(best["seeder"])
    agent.eval()
    test_started = time.perf_counter()
    test_metrics = evaluate_policy(agent, data["test"], seeder)
    test_seconds = time.perf_counter() - test_started
    summary = {"localization": test_metrics["all"]["localization"],
               "reconstruction_ap_mean": test_metrics["all"]["reconstruction_ap"]["mean"],
               "reconstruction_ap_ignore_unknown_mean": test_metrics["all"]["reconstruction_ap_ignore_unknown"]["mean"],
               "original_ap_mean": {k: v["ap"] for k, v in test_metrics["all"]["original_ap"]["mean"].items()}}
    meta = {"kind": POLICY_KIND,
            "description": "DynEnv encoder pretrained on localization + reconstruction only (no RL): the "
                           "localization stream, pose head, object stream and reconstruction head are trained; "
                           "the actor and critic heads are untrained initial weights.",
            "trained_prefixes": list(ENCODER_PREFIXES), "privileged_seeding": cfg.privileged_seeding,
            "config": vars(cfg).copy(), "best_epoch": best["epoch"], "validation_score": best["score"],
            "validation": validation_name, "data": {s: data[s].meta for s in SPLITS}, "test_summary": summary}
    if seeder is not None:
        meta["pose_seeder"] = seeder.to_meta()
    policy_path = folder / "pretrained.safetensors"
    save_policy(agent, policy_path, meta)
    result = {"kind": POLICY_KIND, "policy": str(policy_path), "config": vars(cfg).copy(),
              "validation": validation_name, "best_epoch": best["epoch"], "best_validation_score": best["score"],
              "history": history, "test": test_metrics, "test_summary": summary,
              "seconds": {"training_total": time.perf_counter() - started, "test_evaluation": test_seconds,
                          "mean_train_epoch": float(np.mean([h["train_seconds"] for h in history]))},
              "data": {s: data[s].meta for s in SPLITS}}
    (folder / "metrics.json").write_text(json.dumps(_jsonable(result), indent=2) + "\n")
    log(format_table(test_metrics, f"test set, best epoch {best['epoch']}"))
    return result


def _jsonable(value: Any) -> Any:
    """NaN → None and numpy scalars → Python, recursively (strict JSON)."""
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, (np.floating, float)):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    return value


def load_pretrained(path: str | Path) -> tuple[Any, PoseSeeder | None, dict[str, Any]]:
    """(agent, pose seeder or None, meta) of a policy file written by ``train`` (any policy file works: no
    seeder then)."""
    from dynenv_ros.agent.checkpoint import load_policy

    agent, meta = load_policy(path)
    seeder = None
    if meta.get("privileged_seeding") and "pose_seeder" in meta:
        try:
            seeder = PoseSeeder.from_meta(meta["pose_seeder"])
        except (KeyError, TypeError, ValueError, RuntimeError) as error:
            raise ValueError(f"policy file {path}: bad pose_seeder in its meta ({error})") from None
        if seeder.linear.out_features != agent.feature_size:
            raise ValueError(f"policy file {path}: pose_seeder does not fit the agent's feature size")
    return agent, seeder, meta


# ------------------------------------------------------------------------------------------------------------------
# CLI

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
