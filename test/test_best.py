"""BEST (Kruschke 2013) with PyMC: known separations are found, identical groups are not, bad input is refused.

Each sampling run is small (500 draws, 500 tune, 2 chains, one core) and there are two (a large separation, and
identical groups through the CLI): ~6-10 s each with pytensor's C cache warm, ~40 s more on a fresh cache.
"""
from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

from dynenv_ros.evaluation.best import (best, compare_evaluations, effect_size, format_result, hdi, plot_posterior,
                                        split_r_hat)
from dynenv_ros.evaluation.cli import main
from dynenv_ros.evaluation.results import FORMAT

SMALL = dict(draws=500, tune=500, chains=2, random_seed=1)
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
LOW = [-0.8, 0.3, 1.1, -0.2, -0.4]          # mean 0, sd about 0.75
HIGH = [9.2, 10.4, 10.9, 9.6, 9.9]          # mean 10


@pytest.fixture(scope="module")
def separated():
    return best(LOW, HIGH, return_samples=True, **SMALL)


def test_large_separation_is_found(separated):
    result, samples = separated
    lo, hi = result.difference_hdi
    assert 0.0 < lo < 10.0 < hi
    assert result.difference_mean == pytest.approx(10.0, abs=1.0)
    assert result.difference_median == pytest.approx(10.0, abs=1.0)
    assert result.p_improvement > 0.99
    assert result.effect_size_mean > 0 and result.effect_size_hdi[0] > 0
    assert result.n1 == result.n2 == 5 and result.max_r_hat < 1.1
    assert samples["difference"].shape == (1000,)
    assert np.allclose(samples["difference"], samples["mu2"] - samples["mu1"])
    sd = np.sqrt((samples["sigma1"] ** 2 + samples["sigma2"] ** 2) / 2)
    assert np.allclose(samples["effect_size"], samples["difference"] / sd)
    text = format_result(result, labels=("low", "high"))
    assert "P(high > low) = 1.000" in text or "P(high > low) = 0.99" in text


def test_posterior_plot_is_a_png(separated, tmp_path):
    result, samples = separated
    path = plot_posterior(result, samples, tmp_path / "best.png", labels=("low", "high"), metric="total")
    assert path.read_bytes()[:8] == PNG_MAGIC
    with Image.open(path) as image:
        image.verify()
    with Image.open(path) as image:
        assert image.format == "PNG" and image.size[0] > 400
    with pytest.raises(ValueError, match="does not exist"):
        plot_posterior(result, samples, tmp_path / "no" / "best.png")


@pytest.mark.parametrize("group1, group2, match", [([1.0], [1.0, 2.0], "at least 2 values"),
                                                   ([1.0, 2.0], [], "at least 2 values"),
                                                   ([1.0, float("nan")], [1.0, 2.0], "non-finite"),
                                                   ([3.0, 3.0], [3.0, 3.0, 3.0], "spread")])
def test_bad_groups_are_refused(group1, group2, match):
    with pytest.raises(ValueError, match=match):
        best(group1, group2, **SMALL)


def test_bad_sampler_settings_are_refused():
    with pytest.raises(ValueError, match="draws"):
        best(LOW, HIGH, draws=0)
    with pytest.raises(ValueError, match="hdi_prob"):
        best(LOW, HIGH, hdi_prob=1.5)


def test_effect_size_sign_follows_group_2_minus_group_1():
    assert effect_size(10.0, 0.0, 2.0, 2.0) == pytest.approx(-5.0)
    assert effect_size(0.0, 10.0, 2.0, 2.0) == pytest.approx(5.0)
    assert effect_size(1.0, 4.0, 1.0, np.sqrt(7.0)) == pytest.approx(3.0 / 2.0)   # sqrt((1 + 7)/2) = 2


def test_hdi_and_r_hat_helpers():
    x = np.linspace(0.0, 1.0, 1001)
    lo, hi = hdi(x, 0.95)
    assert hi - lo == pytest.approx(0.95, abs=0.002)
    rng = np.random.default_rng(0)
    lo, hi = hdi(rng.normal(size=200_000))
    assert lo == pytest.approx(-1.96, abs=0.03) and hi == pytest.approx(1.96, abs=0.03)
    skewed = rng.exponential(size=100_000)          # the HDI of a decaying density starts at its mode
    assert hdi(skewed)[0] < 0.01
    assert split_r_hat(rng.normal(size=(2, 1000))) == pytest.approx(1.0, abs=0.01)
    assert split_r_hat(np.stack([rng.normal(size=1000), rng.normal(5.0, 1.0, size=1000)])) > 1.5


def _evaluation(path, values):
    """A minimal dynenv-eval result: only per_seed matters to compare."""
    per_seed = [{"seed": i, "episodes": 1, "total": v, "win_rate": 0.0} for i, v in enumerate(values)]
    path.write_text(json.dumps({"format": FORMAT, "settings": {}, "episodes": [], "per_seed": per_seed}))
    return path


def test_identical_groups_compared_by_the_cli_give_no_difference(tmp_path, capsys):
    """Two result files with the same per-seed values: the HDIs straddle 0 and P(improvement) is near 1/2."""
    values = [1.0, 2.0, 3.0, 4.0, 5.0]
    a = _evaluation(tmp_path / "baseline.json", values)
    b = _evaluation(tmp_path / "proposal.json", list(values))
    png, out = tmp_path / "best.png", tmp_path / "best.json"
    assert main(["compare", str(a), str(b), "--metric", "total", "--png", str(png), "--out", str(out),
                 "--draws", "500", "--tune", "500", "--chains", "2", "--seed", "1"]) == 0
    assert "P(proposal > baseline)" in capsys.readouterr().out
    summary = json.loads(out.read_text())
    assert summary["metric"] == "total" and summary["n1"] == summary["n2"] == 5
    assert summary["difference_hdi"][0] < 0.0 < summary["difference_hdi"][1]
    assert summary["effect_size_hdi"][0] < 0.0 < summary["effect_size_hdi"][1]
    assert 0.2 < summary["p_improvement"] < 0.8
    assert png.read_bytes()[:8] == PNG_MAGIC


def _exit_code(argv) -> int:
    try:
        return main(argv)
    except SystemExit as stop:
        return stop.code


def test_compare_refusals_exit_2_with_one_line(tmp_path, capsys):
    good = _evaluation(tmp_path / "good.json", LOW)
    one_seed = _evaluation(tmp_path / "one.json", [1.0])
    constant = _evaluation(tmp_path / "constant.json", [0.0, 0.0, 0.0])
    foreign = tmp_path / "foreign.json"
    foreign.write_text(json.dumps({"per_seed": []}))
    cases = [[str(good), str(tmp_path / "missing.json")], [str(good), str(one_seed)], [str(good), str(foreign)],
             [str(good), str(good), "--metric", "nonsense"], [str(constant), str(constant), "--metric", "win_rate"],
             [str(good), str(good), "--png", str(tmp_path / "no" / "x.png")], [str(good)]]
    for argv in cases:
        assert _exit_code(["compare", *argv]) == 2, argv
        err = capsys.readouterr().err
        assert err.startswith("dynenv-eval") and err.count("\n") == 1 and "Traceback" not in err, err
    with pytest.raises(ValueError, match="at least 2 values"):
        compare_evaluations(good, one_seed)
