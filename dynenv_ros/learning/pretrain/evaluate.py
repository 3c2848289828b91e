"""The test-set figures of a pretrained policy: localization fractions, real reconstruction AP and DynEnv's
(P + R)/2 "AP" beside the paper's Table 3 (``dynenv-pretrain evaluate``), and the validation score that picks
the kept model."""
from __future__ import annotations

from typing import Any, Mapping

import numpy as np
import torch

from dynenv_ros.learning.pretrain.data import Split
from dynenv_ros.learning.pretrain.model import PoseSeeder, _batch, forward, losses, robot_sequences

PAPER_TABLE3 = {"localization": (83.0, 100.0, 100.0), "reconstruction": (54.0, 70.0, 92.0)}


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
    from dynenv_ros.learning.pretrain import reconstruction_metrics as rm

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
