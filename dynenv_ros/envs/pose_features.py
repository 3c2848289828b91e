"""The self-localization estimate as an observation: one definition for the env, the agent and the policy node.

A robot's pose estimate (``perception/localization.py``, or a real robot's localization on ROS) enters the
observation as ``pose_estimate``: 7 float32 of the period's last frame, in the robot's **team frame** (its own goal
at −x, the opponent goal at +x: team A's frame is the field frame, team B's is turned by π), so one network plays
either side as the rest of its inputs are egocentric too:

| column | unit | what |
|---|---|---|
| ``x``, ``y`` | m | the estimated position |
| ``cos_yaw``, ``sin_yaw`` | – | the estimated heading |
| ``std_x``, ``std_y`` | m | the estimate's standard deviations (turning by π keeps a covariance's diagonal) |
| ``std_yaw`` | rad | the heading's standard deviation |

Standard deviations rather than variances: they share the units of the position, and stay within the bound.
"""
from __future__ import annotations

import numpy as np

POSE_KEY = "pose_estimate"
POSE_COLUMNS = ("x", "y", "cos_yaw", "sin_yaw", "std_x", "std_y", "std_yaw")
POSE_BOUND = 50.0            # m (and rad) either way; a field is 9 x 6 m, a σ beyond this means "lost"
POSE_LOW = (-POSE_BOUND, -POSE_BOUND, -1.0, -1.0, 0.0, 0.0, 0.0)
POSE_HIGH = (POSE_BOUND, POSE_BOUND, 1.0, 1.0, POSE_BOUND, POSE_BOUND, POSE_BOUND)


def pose_features(estimate: np.ndarray, covariance: np.ndarray, teams: np.ndarray,
                  out: np.ndarray | None = None) -> np.ndarray:
    """(n, 7) rows of ``POSE_COLUMNS`` from field-frame estimates (n, 3), covariances (n, 3, 3) and teams (n,) ±1."""
    estimate = np.asarray(estimate, np.float64).reshape(-1, 3)
    covariance = np.asarray(covariance, np.float64).reshape(-1, 3, 3)
    sign = np.asarray(teams, np.float64).reshape(-1)
    if not len(estimate) == len(covariance) == len(sign):
        raise ValueError(f"pose_features: {len(estimate)} estimates, {len(covariance)} covariances, "
                         f"{len(sign)} teams")
    if not np.isin(sign, (1.0, -1.0)).all():
        raise ValueError("pose_features: teams must be +1 (A) or -1 (B)")
    rows = np.empty((len(estimate), len(POSE_COLUMNS)), np.float32) if out is None else out
    rows[:, 0] = sign * estimate[:, 0]
    rows[:, 1] = sign * estimate[:, 1]
    rows[:, 2] = sign * np.cos(estimate[:, 2])          # cos(yaw + π) = −cos(yaw)
    rows[:, 3] = sign * np.sin(estimate[:, 2])
    variances = np.diagonal(covariance, axis1=1, axis2=2)
    rows[:, 4:7] = np.sqrt(np.maximum(variances, 0.0))
    np.clip(rows, POSE_LOW, POSE_HIGH, out=rows)
    return rows


__all__ = ["POSE_KEY", "POSE_COLUMNS", "POSE_BOUND", "POSE_LOW", "POSE_HIGH", "pose_features"]
