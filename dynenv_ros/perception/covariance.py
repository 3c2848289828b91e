"""The position uncertainty the error model gives a correct detection, as a covariance a standard consumer can use
(vision_msgs' PoseWithCovariance; docs/perception.md, "Covariances").

It is the model's own spread around the true position, evaluated at the reported one: the polar model's radial σ
grows with d² and its bearing σ becomes a tangential σ·d; the uniform model's per-axis width w gives w²/12.
False positives and confusions are not drawn from it (they are the failures a covariance cannot describe).
"""
from __future__ import annotations

import numpy as np

from dynenv_ros.core.object_classes import Sighting
from dynenv_ros.perception.params import PerceptionParams

UNIFORM_YAW_VARIANCE = float(np.pi ** 2 / 3)   # a heading the detection does not carry: uniform on the circle


def position_covariance(params: PerceptionParams, x: np.ndarray, y: np.ndarray, near_range: np.ndarray,
                        sighting: np.ndarray) -> np.ndarray:
    """(..., 2, 2) covariance of (x, y) in the observer's camera frame, m²."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    out = np.zeros(x.shape + (2, 2))
    m = params.noise_magnitude
    if params.mode == "none" or m <= 0.0:
        return out
    p = params.position
    d = np.hypot(x, y)
    if p.model == "uniform":
        if params.mode == "realistic":
            bits = np.asarray(sighting, int)
            factor = np.where(bits & Sighting.PARTIAL, params.miss.partial_factor,
                              np.where(bits & Sighting.DISTANT, params.miss.distant_factor,
                                       np.where(bits & Sighting.NEARBY, params.miss.nearby_factor, 1.0)))
            mult = (params.miss.range_offset + params.miss.range_slope * (d / np.asarray(near_range)) ** 2) * factor
        else:
            mult = 4.0
        variance = (m * p.uniform_scale * mult) ** 2 / 12.0
        out[..., 0, 0] = out[..., 1, 1] = variance
        return out
    if params.mode == "random":
        out[..., 0, 0] = out[..., 1, 1] = (m * p.random_std) ** 2
        return out
    radial = (m * (p.radial_base + p.radial_per_m2 * d * d)) ** 2
    tangential = (m * p.bearing_std * d) ** 2
    bearing = np.arctan2(y, x)
    c, s = np.cos(bearing), np.sin(bearing)
    out[..., 0, 0] = c * c * radial + s * s * tangential
    out[..., 1, 1] = s * s * radial + c * c * tangential
    out[..., 0, 1] = out[..., 1, 0] = c * s * (radial - tangential)
    return out


def yaw_variance(params: PerceptionParams) -> float:
    """Variance of a robot detection's heading (rad²)."""
    if params.mode == "none" or params.noise_magnitude <= 0.0:
        return 0.0
    return float((params.noise_magnitude * params.position.yaw_std) ** 2)
