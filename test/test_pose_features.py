"""The pose estimate as an observation (envs/pose_features.py): team frame, standard deviations, bounds."""
from __future__ import annotations

import math

import numpy as np
import pytest

from dynenv_ros.envs.pose_features import POSE_COLUMNS, pose_features


def test_team_b_sees_the_field_turned_by_pi_and_the_same_uncertainty() -> None:
    estimate = np.array([[1.0, 2.0, 0.3], [1.0, 2.0, 0.3]])
    covariance = np.stack([np.diag([0.04, 0.09, 0.01])] * 2)
    rows = pose_features(estimate, covariance, np.array([1, -1]))
    assert POSE_COLUMNS == ("x", "y", "cos_yaw", "sin_yaw", "std_x", "std_y", "std_yaw")
    # team A: the field frame; σ = √variance: 0.2 m, 0.3 m, 0.1 rad
    assert rows[0] == pytest.approx([1.0, 2.0, math.cos(0.3), math.sin(0.3), 0.2, 0.3, 0.1], abs=1e-6)
    # team B: (−x, −y, yaw + π)
    assert rows[1] == pytest.approx([-1.0, -2.0, -math.cos(0.3), -math.sin(0.3), 0.2, 0.3, 0.1], abs=1e-6)


def test_a_lost_robots_deviation_is_clipped_to_the_bound() -> None:
    rows = pose_features(np.zeros((1, 3)), np.diag([1e6, 0.0, 1e6])[None], np.array([1]))
    assert rows[0, 4:] == pytest.approx([50.0, 0.0, 50.0])


@pytest.mark.parametrize("teams, message", [(np.array([0]), "teams"), (np.array([1, 1]), "estimates")])
def test_bad_teams_or_counts_are_refused(teams, message) -> None:
    with pytest.raises(ValueError, match=message):
        pose_features(np.zeros((1, 3)), np.zeros((1, 3, 3)), teams)
