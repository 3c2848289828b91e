"""An emulated self-localization: the pose estimate (x, y, yaw) with a covariance that a real SPL robot's
self-locator publishes (B-Human's ``RobotPose``; docs/spl_localization.md), stepped once per vision
frame. ROS-free; docs/perception.md, "Self-localization".

No particle filter runs here. The estimate is the true pose plus an error ``e`` that is drawn so that it always
follows the covariance reported with it (error/σ ~ N(0, 1) per axis): whatever the rules below do to the covariance
``P`` (diagonal, per axis x, y, yaw in the field frame), they do to ``e`` in distribution.

Rules, per robot and frame, in this order:

1. **Odometry drift** — the estimate moves with the robot's true displacement plus noise whose variance grows with
   the distance walked, the angle turned and the time passed (a random walk, so the result does not depend on the
   frame rate); ``P`` grows by the same variance. Why: walking NAOs slip, odometry errors pile up between sightings.
2. **Fall** — the variance of a fall is added to ``e`` and ``P`` (kidnapping-like: the robot is shoved and turned).
3. **Resets** — kickoff placement (episode start, after a goal): ``e`` ~ N(0, placement²), the flip cleared: robots
   are placed at known spots. Penalty (and re-entry after it): the touchline prior, σ large along the touchline,
   small across it and in heading, the flip cleared: a robot knows it re-enters on its own half's touchline facing
   into the field, not where along it. Both restart the cue clock (an asymmetric game-state prior).
4. **Landmarks** — with k = min(sightings this frame, cap) > 0, a per-axis Kalman update with measurement variance
   R/k: K = P/(P + R/k), P ← (1 − K)P, e ← (1 − K)e + K·η, η ~ N(0, R/k), which keeps ``e`` ~ N(0, P). Why: each
   sighting constrains the pose; sightings of one frame share the camera's pose error, so beyond the cap they add
   nothing. If the position σ before the update exceeded ``lost_xy_std`` the robot was lost and now re-localizes:
   onto the mirror pose (−x, −y, yaw + π) of the point-symmetric field with ``flip_probability_cue`` within
   ``cue_seconds`` of a cue, else ``flip_probability``. A flipped estimate tracks the mirror pose (with its usual
   error) until the next reset or the next re-localization from lost.

A penalized robot's estimate holds (no drift, no sightings). Mode ``none``: the true pose, zero covariance.
"""
from __future__ import annotations

import math

import numba
import numpy as np

from dynenv_ros.perception.params import LocalizationParams

# Events between the previous frame and this one, per (frame, robot), as bit flags (``SoccerVision`` maps the
# world's GameEvents onto them).
KICKOFF, FALL, PENALTY, RETURN = 1, 2, 4, 8
_TAU = 2.0 * math.pi


@numba.njit(cache=True, inline="always")
def _wrap(a: float) -> float:
    """An angle in [−π, π)."""
    return (a + math.pi) % _TAU - math.pi


@numba.njit(cache=True)
def _step_frames(pose: np.ndarray, landmarks: np.ndarray, events: np.ndarray, penalized: np.ndarray, prev: np.ndarray,
                 err: np.ndarray, var: np.ndarray, flipped: np.ndarray, cue_age: np.ndarray, z: np.ndarray,
                 u: np.ndarray, q: np.ndarray, out_est: np.ndarray, out_var: np.ndarray, out_flip: np.ndarray) -> None:
    """The rules of the module docstring for F frames of n robots. pose (F, n, 3) true; landmarks (F, n) int;
    events (F, n) flags; penalized (F, n) bool; prev (n, 3) the previous frame's true pose, err and var (n, 3),
    flipped (n,), cue_age (n,) updated in place; z (F, n, 4, 3) standard normals (odometry, fall, reset, sighting),
    u (F, n) uniforms; q the parameters (``Localization._table``); out_* (F, n, 3), (F, n, 3), (F, n)."""
    dt = q[0]
    frames, n = landmarks.shape
    for f in range(frames):
        for i in range(n):
            cue_age[i] += dt
            ev = events[f, i]
            pen = penalized[f, i]
            if not pen:
                dx, dy = pose[f, i, 0] - prev[i, 0], pose[f, i, 1] - prev[i, 1]
                d = math.sqrt(dx * dx + dy * dy)
                turn = abs(_wrap(pose[f, i, 2] - prev[i, 2]))
                q_xy = q[1] * d + q[4] * dt
                q_yaw = q[2] * turn + q[3] * d + q[5] * dt
                for a in range(3):
                    qa = q_xy if a < 2 else q_yaw
                    err[i, a] += math.sqrt(qa) * z[f, i, 0, a]
                    var[i, a] += qa
                if ev & FALL:
                    for a in range(3):
                        qa = q[9] if a < 2 else q[10]
                        err[i, a] += math.sqrt(qa) * z[f, i, 1, a]
                        var[i, a] += qa
            for a in range(3):
                prev[i, a] = pose[f, i, a]
            if (ev & KICKOFF and not pen) or ev & (PENALTY | RETURN):
                base = 15 if ev & (PENALTY | RETURN) else 12     # touchline prior, else placement
                for a in range(3):
                    va = q[base + a]
                    err[i, a] = math.sqrt(va) * z[f, i, 2, a]
                    var[i, a] = va
                flipped[i] = False
                cue_age[i] = 0.0
            k = min(landmarks[f, i], q[8])
            if not pen and k > 0:
                if var[i, 0] > q[11] or var[i, 1] > q[11]:
                    p = q[19] if cue_age[i] <= q[20] else q[18]
                    flipped[i] = u[f, i] < p
                for a in range(3):
                    r = (q[6] if a < 2 else q[7]) / k
                    gain = var[i, a] / (var[i, a] + r)
                    err[i, a] = (1.0 - gain) * err[i, a] + gain * math.sqrt(r) * z[f, i, 3, a]
                    var[i, a] = (1.0 - gain) * var[i, a]
            sign = -1.0 if flipped[i] else 1.0
            out_est[f, i, 0] = sign * pose[f, i, 0] + err[i, 0]
            out_est[f, i, 1] = sign * pose[f, i, 1] + err[i, 1]
            out_est[f, i, 2] = _wrap(pose[f, i, 2] + (math.pi if flipped[i] else 0.0) + err[i, 2])
            for a in range(3):
                out_var[f, i, a] = var[i, a]
            out_flip[f, i] = flipped[i]


def _wrapped(a: np.ndarray) -> np.ndarray:
    """Angles in [−π, π) (numpy; ``_wrap`` is the kernel's)."""
    return (a + math.pi) % _TAU - math.pi


class Localization:
    """Every robot's pose estimate. ``reset`` at an episode start, then ``step`` once per batch of vision frames
    (a motion period's, or one). After each call: ``estimate`` (n, 3) x, y, yaw in the field frame (metres, radians,
    yaw in [−π, π)), ``covariance`` (n, 3, 3), ``flipped`` (n,) bool — at the last frame; ``estimates`` (F, n, 3),
    ``variances`` (F, n, 3) and ``flips`` (F, n) for every frame of the last step.

    ``rng``: the generator every draw comes from (its own: never the perception's or the world's). Mode ``none``
    draws nothing."""

    def __init__(self, params: LocalizationParams, n_robots: int, frame_seconds: float,
                 rng: np.random.Generator | None = None) -> None:
        if frame_seconds <= 0:
            raise ValueError(f"frame_seconds must be positive, got {frame_seconds}")
        self.params = params
        self.n_robots = n_robots
        self.frame_seconds = frame_seconds
        self.rng = rng if rng is not None else np.random.default_rng()
        p = params
        # The parameters in the slots _step_frames reads (variances: σ²): 0 frame seconds; 1–3 odometry xy per m, yaw
        # per rad, yaw per m; 4–5 drift xy, yaw per s; 6–7 sighting R xy, yaw; 8 cap; 9–10 fall xy, yaw; 11 lost;
        # 12–14 placement x, y, yaw; 15–17 touchline x (along), y (across), yaw; 18–19 flip P without, with cue;
        # 20 cue seconds.
        self._table = np.array([
            frame_seconds, p.odometry_xy_per_m ** 2, p.odometry_yaw_per_rad ** 2, p.odometry_yaw_per_m ** 2,
            p.drift_xy_per_s ** 2, p.drift_yaw_per_s ** 2, p.landmark_xy_std ** 2, p.landmark_yaw_std ** 2,
            float(p.landmark_cap), p.fall_xy_std ** 2, p.fall_yaw_std ** 2, p.lost_xy_std ** 2,
            p.placement_xy_std ** 2, p.placement_xy_std ** 2, p.placement_yaw_std ** 2,
            p.touchline_along_std ** 2, p.touchline_across_std ** 2, p.touchline_yaw_std ** 2,
            p.flip_probability, p.flip_probability_cue, p.cue_seconds], float)
        self.exact = p.mode == "none"
        self.reset(np.zeros((n_robots, 3)))

    def reset(self, pose: np.ndarray) -> None:
        """Episode start: every robot placed at a known spot (``pose`` (n, 3) true x, y, yaw)."""
        pose = np.asarray(pose, float)
        n = self.n_robots
        self._prev = pose.copy()
        self.cue_age = np.zeros(n)
        self._flipped = np.zeros(n, bool)
        if self.exact:
            self._err, self._var = np.zeros((n, 3)), np.zeros((n, 3))
        else:
            p = self.params
            std = np.array([p.placement_xy_std, p.placement_xy_std, p.placement_yaw_std])
            self._err = self.rng.standard_normal((n, 3)) * std
            self._var = np.broadcast_to(std ** 2, (n, 3)).copy()
        est = pose + self._err
        est[:, 2] = _wrapped(est[:, 2])
        self._publish(est[None], self._var[None].copy(), self._flipped[None].copy())

    def step(self, pose: np.ndarray, landmarks: np.ndarray, events: np.ndarray | None = None,
             penalized: np.ndarray | None = None) -> None:
        """Advance over F frames: ``pose`` (F, n, 3) true poses, ``landmarks`` (F, n) landmark sightings truly
        made (``SoccerVision.landmarks_seen``), ``events`` (F, n) flags (KICKOFF, FALL, PENALTY, RETURN: what
        happened since the previous frame), ``penalized`` (F, n) bool."""
        pose = np.asarray(pose, float)
        frames, n = pose.shape[:2]
        if n != self.n_robots or pose.shape[2:] != (3,):
            raise ValueError(f"pose must be (frames, {self.n_robots}, 3), got {pose.shape}")
        if self.exact:
            self._prev = pose[-1].copy()
            est = pose.copy()
            est[..., 2] = _wrapped(est[..., 2])
            self._publish(est, np.zeros((frames, n, 3)), np.zeros((frames, n), bool))
            return
        events = np.zeros((frames, n), np.uint8) if events is None else np.asarray(events, np.uint8)
        penalized = np.zeros((frames, n), bool) if penalized is None else np.asarray(penalized, bool)
        landmarks = np.asarray(landmarks, np.int64)
        z = self.rng.standard_normal((frames, n, 4, 3))
        u = self.rng.random((frames, n))
        est, var, flips = np.empty((frames, n, 3)), np.empty((frames, n, 3)), np.empty((frames, n), bool)
        _step_frames(pose, landmarks, events, penalized, self._prev, self._err, self._var, self._flipped,
                     self.cue_age, z, u, self._table, est, var, flips)
        self._publish(est, var, flips)

    def _publish(self, estimates: np.ndarray, variances: np.ndarray, flips: np.ndarray) -> None:
        self.estimates, self.variances, self.flips = estimates, variances, flips
        self._covariance: np.ndarray | None = None

    @property
    def estimate(self) -> np.ndarray:
        """(n, 3) x, y, yaw estimated at the last frame, field frame."""
        estimate: np.ndarray = self.estimates[-1]
        return estimate

    @property
    def covariance(self) -> np.ndarray:
        """(n, 3, 3) the estimate's covariance at the last frame (diagonal: x, y, yaw), m² and rad²."""
        if self._covariance is None:
            cov = np.zeros((self.n_robots, 3, 3))
            idx = np.arange(3)
            cov[:, idx, idx] = self.variances[-1]
            self._covariance = cov
        return self._covariance

    @property
    def flipped(self) -> np.ndarray:
        """(n,) whether each estimate tracks the mirror pose (−x, −y, yaw + π) at the last frame."""
        flipped: np.ndarray = self.flips[-1]
        return flipped

    def error(self, pose: np.ndarray) -> np.ndarray:
        """(n, 3) the estimate minus ``pose`` (the true pose at the last frame), yaw wrapped to [−π, π)."""
        e: np.ndarray = self.estimate - np.asarray(pose, float)
        e[:, 2] = _wrapped(e[:, 2])
        return e
