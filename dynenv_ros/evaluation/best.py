"""BEST: Kruschke's (2013) Bayesian estimation for two groups, with PyMC — the paper's significance test.

The unit is the seed: one number per seed per group (e.g. the per-seed means of ``evaluation.soccer``).
Model (Kruschke 2013, "Bayesian estimation supersedes the t test"), with ``y`` both groups pooled:

    μ₁, μ₂ ~ Normal(mean(y), 1000·sd(y))
    σ₁, σ₂ ~ Uniform(sd(y)/1000, 1000·sd(y))
    ν − 1  ~ Exponential(1/29)                     (mean of ν: 30)
    y₁ ~ StudentT(ν, μ₁, σ₁),  y₂ ~ StudentT(ν, μ₂, σ₂)

Reported: the difference of means Δμ = μ₂ − μ₁ (mean, median, 95 % HDI), the effect size
Δμ / sqrt((σ₁² + σ₂²)/2) (mean, median, 95 % HDI), and the probability of improvement P(μ₂ > μ₁) — the fraction
of posterior draws with Δμ > 0 (group 2 is the proposal, group 1 the baseline; for metrics where lower is better,
such as falls, an "improvement" is P < 0.5). The original analysis pooled 8 envs per seed as independent
samples (docs/original.md §11); here each seed counts once.
"""
from __future__ import annotations

import math
import os
import warnings
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from dynenv_ros.evaluation.results import load_evaluation
from dynenv_ros.evaluation.soccer import SEED_METRICS

HDI_PROB = 0.95


@dataclass(frozen=True)
class BestResult:
    """Posterior summaries of a BEST comparison (group 2 minus group 1)."""
    n1: int
    n2: int
    mean1: float                      # posterior mean of μ₁
    mean2: float                      # posterior mean of μ₂
    difference_mean: float            # of Δμ = μ₂ − μ₁
    difference_median: float
    difference_hdi: tuple[float, float]
    effect_size_mean: float           # of Δμ / sqrt((σ₁² + σ₂²)/2)
    effect_size_median: float
    effect_size_hdi: tuple[float, float]
    p_improvement: float              # P(μ₂ > μ₁)
    nu_median: float
    hdi_prob: float
    draws: int
    tune: int
    chains: int
    random_seed: int
    max_r_hat: float                  # over μ₁, μ₂, σ₁, σ₂, ν (split R-hat); near 1 when the chains agree
    divergences: int

    def as_dict(self) -> dict[str, Any]:
        out = asdict(self)
        out["difference_hdi"] = list(self.difference_hdi)
        out["effect_size_hdi"] = list(self.effect_size_hdi)
        return out


def hdi(samples: np.ndarray, prob: float = HDI_PROB) -> tuple[float, float]:
    """The narrowest interval holding ``prob`` of the samples (highest density interval of a unimodal posterior)."""
    x = np.sort(np.asarray(samples, float).ravel())
    n = len(x)
    if n == 0:
        raise ValueError("hdi of no samples")
    k = max(1, int(math.ceil(prob * n)))
    if k >= n:
        return float(x[0]), float(x[-1])
    widths = x[k - 1:] - x[:n - k + 1]
    i = int(np.argmin(widths))
    return float(x[i]), float(x[i + k - 1])


def _group(values: Sequence[float], name: str) -> np.ndarray:
    try:
        y = np.asarray(values, float).ravel()
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a sequence of numbers") from None
    if len(y) < 2:
        raise ValueError(f"BEST needs at least 2 values per group (one per seed); {name} has {len(y)}")
    if not np.all(np.isfinite(y)):
        raise ValueError(f"{name} holds non-finite values")
    return y


def best(group1: Sequence[float], group2: Sequence[float], *, draws: int = 1000, tune: int = 1000,
         chains: int = 2, random_seed: int = 0, hdi_prob: float = HDI_PROB,
         return_samples: bool = False) -> BestResult | tuple[BestResult, dict[str, np.ndarray]]:
    """Compare ``group2`` (proposal) with ``group1`` (baseline); one value per seed, at least 2 per group.

    NUTS with ``cores=1`` and ``random_seed``: the same call gives the same numbers. With ``return_samples`` also
    returns the flat posterior draws {"mu1", "mu2", "sigma1", "sigma2", "nu", "difference", "effect_size"}.
    """
    y1, y2 = _group(group1, "group 1"), _group(group2, "group 2")
    for name, value in (("draws", draws), ("tune", tune), ("chains", chains)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < (0 if name == "tune" else 1):
            raise ValueError(f"{name} must be a {'non-negative' if name == 'tune' else 'positive'} integer, "
                             f"got {value!r}")
    if not 0.0 < hdi_prob < 1.0:
        raise ValueError(f"hdi_prob must be in (0, 1), got {hdi_prob!r}")
    pooled = np.concatenate([y1, y2])
    mu_pooled, sd_pooled = float(pooled.mean()), float(pooled.std(ddof=1))
    if not sd_pooled > 0.0:
        raise ValueError("BEST needs some spread: every value of both groups is the same "
                         f"({pooled[0]!r}), so there is nothing to estimate")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FutureWarning)     # arviz's refactor notice at import
        import pymc as pm
    with pm.Model():
        mu1 = pm.Normal("mu1", mu=mu_pooled, sigma=1000.0 * sd_pooled)
        mu2 = pm.Normal("mu2", mu=mu_pooled, sigma=1000.0 * sd_pooled)
        sigma1 = pm.Uniform("sigma1", lower=sd_pooled / 1000.0, upper=sd_pooled * 1000.0)
        sigma2 = pm.Uniform("sigma2", lower=sd_pooled / 1000.0, upper=sd_pooled * 1000.0)
        nu_minus_one = pm.Exponential("nu_minus_one", lam=1.0 / 29.0)
        nu = pm.Deterministic("nu", nu_minus_one + 1.0)
        pm.StudentT("y1", nu=nu, mu=mu1, sigma=sigma1, observed=y1)
        pm.StudentT("y2", nu=nu, mu=mu2, sigma=sigma2, observed=y2)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            idata = pm.sample(draws=int(draws), tune=int(tune), chains=int(chains), cores=1,
                              random_seed=int(random_seed), progressbar=False,
                              compute_convergence_checks=False)
    post = idata.posterior
    s = {name: np.asarray(post[name].values, float) for name in ("mu1", "mu2", "sigma1", "sigma2", "nu")}
    diff = s["mu2"] - s["mu1"]
    effect = effect_size(s["mu1"], s["mu2"], s["sigma1"], s["sigma2"])
    divergences = int(np.asarray(idata.sample_stats["diverging"].values).sum()) \
        if "diverging" in idata.sample_stats else 0
    result = BestResult(
        n1=len(y1), n2=len(y2), mean1=float(s["mu1"].mean()), mean2=float(s["mu2"].mean()),
        difference_mean=float(diff.mean()), difference_median=float(np.median(diff)),
        difference_hdi=hdi(diff, hdi_prob), effect_size_mean=float(effect.mean()),
        effect_size_median=float(np.median(effect)), effect_size_hdi=hdi(effect, hdi_prob),
        p_improvement=float((diff > 0).mean()), nu_median=float(np.median(s["nu"])), hdi_prob=float(hdi_prob),
        draws=int(draws), tune=int(tune), chains=int(chains), random_seed=int(random_seed),
        max_r_hat=max(split_r_hat(v) for v in s.values()), divergences=divergences)
    if return_samples:
        flat = {k: v.ravel() for k, v in s.items()}
        flat.update(difference=diff.ravel(), effect_size=effect.ravel())
        return result, flat
    return result


def effect_size(mu1: np.ndarray, mu2: np.ndarray, sigma1: np.ndarray, sigma2: np.ndarray) -> np.ndarray:
    """Kruschke's effect size (μ₂ − μ₁) / sqrt((σ₁² + σ₂²)/2), per posterior draw: positive when group 2 is higher."""
    return (np.asarray(mu2) - np.asarray(mu1)) / np.sqrt((np.asarray(sigma1) ** 2 + np.asarray(sigma2) ** 2) / 2.0)


def split_r_hat(chains: np.ndarray) -> float:
    """Gelman–Rubin split R-hat of (chains, draws) samples (NaN with fewer than 4 draws)."""
    x = np.asarray(chains, float)
    half = x.shape[1] // 2
    if half < 2:
        return float("nan")
    parts = np.concatenate([x[:, :half], x[:, half:2 * half]], axis=0)
    n = parts.shape[1]
    within = parts.var(axis=1, ddof=1).mean()
    between = n * parts.mean(axis=1).var(ddof=1)
    if within == 0.0:
        return 1.0
    return float(np.sqrt(((n - 1) / n * within + between / n) / within))


def plot_posterior(result: BestResult, samples: dict[str, np.ndarray], path: str | os.PathLike[str],
                   labels: tuple[str, str] = ("group 1", "group 2"), metric: str = "") -> Path:
    """PNG: histograms of the difference of means and of the effect size (central 99 % of the draws), each with
    its HDI, its mean and zero marked."""
    from matplotlib.figure import Figure     # no pyplot: no global backend or figure state touched
    target = Path(path)
    if not target.parent.is_dir():
        raise ValueError(f"cannot write {target}: folder {target.parent} does not exist")
    fig = Figure(figsize=(10, 3.8), layout="constrained")
    axes = fig.subplots(1, 2)
    pct = f"{100 * result.hdi_prob:g}% HDI"
    panels = ((axes[0], samples["difference"], result.difference_hdi, result.difference_mean,
               f"difference of means ({labels[1]} − {labels[0]})"),
              (axes[1], samples["effect_size"], result.effect_size_hdi, result.effect_size_mean, "effect size"))
    for ax, values, (lo, hi), mean, title in panels:
        # Student-t posteriors of few seeds have long tails: show the central 99 % (and the HDI and zero).
        low, high = np.percentile(values, [0.5, 99.5])
        ax.hist(values, bins=60, range=(min(low, lo, 0.0), max(high, hi, 0.0)), color="#6a8fc8", edgecolor="white",
                linewidth=0.3)
        ax.axvline(0.0, color="black", linestyle=":", linewidth=1)
        ax.plot([lo, hi], [0, 0], color="#c03030", linewidth=5, solid_capstyle="butt", label=f"{pct} "
                f"[{lo:.3g}, {hi:.3g}]")
        ax.axvline(mean, color="#c03030", linewidth=1, label=f"mean {mean:.3g}")
        ax.set_title(title)
        ax.set_yticks([])
        ax.legend(loc="upper left", fontsize=8, frameon=False)
    fig.suptitle(f"BEST{': ' + metric if metric else ''} — P({labels[1]} > {labels[0]}) = "
                 f"{result.p_improvement:.3f}  (n = {result.n1}, {result.n2} seeds)")
    fig.savefig(target, format="png", dpi=100)
    return target


def seed_values(result: Mapping[str, Any], metric: str) -> list[float]:
    """The per-seed values of ``metric`` (one of ``soccer.SEED_METRICS``, or a driving result's) in a result: what
    ``compare_evaluations`` gives BEST."""
    rows = result["per_seed"]
    if not rows or metric not in rows[0]:
        known = ", ".join(SEED_METRICS)
        raise ValueError(f"unknown metric {metric!r}; known: {known}")
    values = [float(row[metric]) for row in rows]
    if not all(math.isfinite(v) for v in values):
        raise ValueError(f"metric {metric!r} has non-finite per-seed values")
    return values



def compare_evaluations(path1: str | os.PathLike[str], path2: str | os.PathLike[str], metric: str = "total",
                        png: str | os.PathLike[str] | None = None, **kwargs: Any) -> BestResult:
    """BEST on the per-seed values of ``metric`` in two ``dynenv-eval`` JSON results (path1 baseline, path2
    proposal); writes the posterior plot to ``png`` if given. ``kwargs`` go to ``best``."""
    a, b = load_evaluation(path1), load_evaluation(path2)
    values1, values2 = seed_values(a, metric), seed_values(b, metric)
    result, samples = best(values1, values2, return_samples=True, **kwargs)
    if png is not None:
        plot_posterior(result, samples, png, labels=(Path(path1).stem, Path(path2).stem), metric=metric)
    return result


def format_result(result: BestResult, labels: tuple[str, str] = ("group 1", "group 2"), metric: str = "") -> str:
    """Plain-text report of a comparison."""
    pct = f"{100 * result.hdi_prob:g}%"
    lo, hi = result.difference_hdi
    elo, ehi = result.effect_size_hdi
    lines = [f"BEST{' on ' + metric if metric else ''}: {labels[1]} (n={result.n2}) vs {labels[0]} (n={result.n1})",
             f"  means                {result.mean1:.4g} -> {result.mean2:.4g}",
             f"  difference of means  mean {result.difference_mean:.4g}, median {result.difference_median:.4g}, "
             f"{pct} HDI [{lo:.4g}, {hi:.4g}]",
             f"  effect size          mean {result.effect_size_mean:.3g}, median {result.effect_size_median:.3g}, "
             f"{pct} HDI [{elo:.3g}, {ehi:.3g}]",
             f"  P({labels[1]} > {labels[0]}) = {result.p_improvement:.3f}",
             f"  sampling             {result.chains} chains x {result.draws} draws (tune {result.tune}), "
             f"seed {result.random_seed}, max R-hat {result.max_r_hat:.3f}, {result.divergences} divergences"]
    return "\n".join(lines)


__all__ = ["BestResult", "best", "hdi", "effect_size", "split_r_hat", "plot_posterior", "seed_values",
           "compare_evaluations", "format_result", "HDI_PROB"]
