"""The pretraining data (``dynenv-pretrain generate``; ``cli``'s docstring says what the arrays hold): random
actions of the RL agent's discrete action space in ``SoccerVectorEnv`` worlds, written to and checked on the way
back from compressed numpy archives (no pickle)."""
from __future__ import annotations

import json
import math
import time
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np

PROG = "dynenv-pretrain"
DATA_FORMAT = "dynenv_ros.pretrain_data/1"
OBS_KEYS = ("landmarks", "landmark_mask", "objects", "object_mask", "proprioception", "game", "previous_action")
TARGET_KEYS = ("pose", "ball", "robots", "ball_seen", "robots_seen")
KNOWN_KEYS = ("ball_known", "robots_known")
ARRAY_KEYS = OBS_KEYS + TARGET_KEYS + KNOWN_KEYS + ("actions",)
SPLITS = ("train", "test")
ACTIONS_PER_SEQUENCE = 2
PERIODS_PER_ACTION = 3
OBSERVATIONS = 1 + ACTIONS_PER_SEQUENCE * PERIODS_PER_ACTION           # 7


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
