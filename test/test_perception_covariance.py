"""The covariance handed to standard vision messages is the spread the error model really gives correct detections:
compared with the empirical covariance of 20,000 sampled reports of one ball, element by element, within five
standard errors of the sample estimate."""
import numpy as np
import pytest

from dynenv_ros.core.object_classes import ObjectClass, Sighting
from dynenv_ros.perception.covariance import position_covariance, yaw_variance
from dynenv_ros.perception.params import load_preset
from test_perception_model import perceive

BALL = ObjectClass.BALL
VIEWS = 20000


@pytest.mark.parametrize("preset,mode,magnitude,x,y", [("realistic", "realistic", 1.0, 3.0, 1.5),
                                                       ("realistic", "realistic", 2.0, 1.0, -0.5),
                                                       ("realistic", "random", 2.0, 2.0, 1.0),
                                                       ("dynenv", "realistic", 2.0, 2.0, 1.0),
                                                       ("dynenv", "random", 2.0, 2.0, 1.0)])
def test_model_covariance_matches_the_sampled_spread(preset, mode, magnitude, x, y):
    params = load_preset(preset, mode=mode, noise_magnitude=magnitude)
    rows = perceive(params, [(BALL, x, y, np.nan, 0, False)], VIEWS).detections
    rows = rows[(rows["true_id"] == 1) & (rows["class_id"] == BALL)]
    samples = np.stack([rows["x"].astype(float), rows["y"].astype(float)], axis=1)
    n = len(samples)
    assert n > VIEWS // 2
    empirical = np.cov(samples.T)
    sighting = int(np.bincount(rows["sighting"]).argmax())     # one place: one sighting state (none here)
    model = position_covariance(params, np.array(x), np.array(y), np.array(params.classes[BALL].near_range),
                                np.array(sighting))
    for i, j in ((0, 0), (1, 1), (0, 1)):
        # standard error of a sample (co)variance: sqrt((s_ii s_jj + s_ij²) / n)
        se = np.sqrt((empirical[i, i] * empirical[j, j] + empirical[i, j] ** 2) / n)
        assert model[i, j] == pytest.approx(empirical[i, j], abs=5 * se), (i, j, model, empirical)
    assert model[0, 1] == model[1, 0]


def test_polar_covariance_is_radial_and_tangential_in_the_documented_sizes():
    """docs "Error model": radial σ = m·(0.01 + 0.0175·d²), bearing σ = m·0.0175 rad → tangential σ·d."""
    params = load_preset("realistic", noise_magnitude=1.0)
    d = 4.0
    cov = position_covariance(params, np.array(0.0), np.array(d), np.array(5.0), np.array(0))
    assert cov[1, 1] == pytest.approx((0.01 + 0.0175 * d * d) ** 2)     # along the line of sight (+y)
    assert cov[0, 0] == pytest.approx((0.0175 * d) ** 2)                # across it
    assert cov[0, 1] == pytest.approx(0.0, abs=1e-15)


def test_exact_perception_has_zero_covariance_and_yaw_variance():
    params = load_preset("none")
    assert not position_covariance(params, np.ones(3), np.ones(3), np.ones(3), np.zeros(3, int)).any()
    assert yaw_variance(params) == 0.0
    # docs/perception.md: realistic yaw_std 0.15 rad per unit magnitude
    assert yaw_variance(load_preset("realistic", noise_magnitude=2.0)) == pytest.approx((2.0 * 0.15) ** 2)


def test_uniform_model_widens_with_the_sighting_factor():
    params = load_preset("dynenv", noise_magnitude=1.0)
    plain, partial = (position_covariance(params, np.array(2.0), np.array(0.0), np.array(4.16), np.array(s))[0, 0]
                      for s in (0, int(Sighting.PARTIAL)))
    assert partial == pytest.approx(plain * 4.0 ** 2)     # partial_factor 4 on the width, squared on the variance
