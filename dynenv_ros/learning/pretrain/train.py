"""``dynenv-pretrain train``: the encoder trained on localization + reconstruction alone, the best model by
validation score kept, evaluated on the test set and written as a policy file (``cli``'s docstring)."""
from __future__ import annotations

import copy
import json
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import torch

from dynenv_ros.learning.algo.networks import make_agent
from dynenv_ros.learning.config import TrainConfig
from dynenv_ros.learning.pretrain.data import SPLITS, Split
from dynenv_ros.learning.pretrain.evaluate import evaluate_policy, format_table, validation_score
from dynenv_ros.learning.pretrain.model import PoseSeeder, _batch, forward, losses, robot_sequences

POLICY_KIND = "dynenv_ros.pretrained_encoder/1"
ENCODER_PREFIXES = ("localization.", "pose_head.", "objects.", "reconstruction.")


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
    agent = make_agent(TrainConfig(feature_size=cfg.feature_size))      # the RL trainer's soccer agent
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
