"""The emulated self-localization (perception/localization.py, docs/perception.md "Self-localization"): steady-state
error while landmarks are seen, odometry drift, calibration, mirror flips with and without a cue, the touchline prior
after a penalty, the world's events hooked in, the exact `none` preset, bad parameters, seeding, and that switching
it on changes no existing observation.

Expected numbers come from the documented realistic parameters, written out here: odometry 0.1 m per √m walked,
0.1 rad per √rad turned, 0.05 rad per √m walked, floor 0.01 m and 0.01 rad per √s; one sighting σ 0.2 m / 0.1 rad,
at most 4 per frame; fall 0.5 m / 0.5 rad; lost above 0.3 m; flips 0.05 without a cue, 0.005 within 30 s of one;
placement 0.05 m / 0.05 rad; touchline 1.0 m along, 0.1 m across, 0.1 rad. Frames are 0.1 s apart.
Statistical checks allow 5 standard errors of their sample.
"""
import math

import numpy as np
import pytest

from dynenv_ros.envs.robocup_v0 import parallel_env
from dynenv_ros.envs.soccer_session import SoccerSession
from dynenv_ros.perception.localization import FALL, KICKOFF, PENALTY, RETURN, Localization
from dynenv_ros.perception.params import LocalizationParams, load_preset
from dynenv_ros.soccer.actions import SoccerAction, Walk
from dynenv_ros.soccer.config import SoccerConfig
from dynenv_ros.soccer.vision import SoccerVision
from soccer_helpers import IDLE, assert_identical, make_world

DT = 0.1
REALISTIC = dict(mode="emulated", odometry_xy_per_m=0.1, odometry_yaw_per_rad=0.1, odometry_yaw_per_m=0.05,
                 drift_xy_per_s=0.01, drift_yaw_per_s=0.01, landmark_xy_std=0.2, landmark_yaw_std=0.1,
                 landmark_cap=4, fall_xy_std=0.5, fall_yaw_std=0.5, lost_xy_std=0.3, flip_probability=0.05,
                 flip_probability_cue=0.005, cue_seconds=30.0, placement_xy_std=0.05, placement_yaw_std=0.05,
                 touchline_along_std=1.0, touchline_across_std=0.1, touchline_yaw_std=0.1)


def _params():
    return load_preset("realistic").localization


def _wrap(a):
    return (np.asarray(a) + math.pi) % (2 * math.pi) - math.pi


def _errors(loc, truth, frame=-1):
    """(n, 3) estimate − truth at a frame of the last step, against the mirror pose where flipped."""
    flips = loc.flips[frame]
    target = np.array(truth, float)
    target[flips, :2] *= -1
    target[flips, 2] += math.pi
    e = loc.estimates[frame] - target
    e[:, 2] = _wrap(e[:, 2])
    return e


def _walk(n, frames, step, turn, start=None):
    """(frames, n, 3) poses of robots walking ``step`` m per frame along their heading, turning ``turn`` rad."""
    pose = np.zeros((n, 3)) if start is None else start.copy()
    out = np.empty((frames, n, 3))
    for f in range(frames):
        pose[:, 0] += step * np.cos(pose[:, 2])
        pose[:, 1] += step * np.sin(pose[:, 2])
        pose[:, 2] += turn
        out[f] = pose
    return out


def test_presets_carry_the_documented_parameters():
    assert load_preset("realistic").localization == LocalizationParams(**REALISTIC)
    assert load_preset("dynenv").localization == LocalizationParams(**REALISTIC)
    assert load_preset("none").localization.mode == "none"
    assert LocalizationParams() == LocalizationParams(**REALISTIC)       # the dataclass defaults are realistic's


def _riccati(q, r):
    """Steady-state posterior variance of a per-axis Kalman filter with process variance q per frame and
    measurement variance r: the positive root of P² + qP − qr = 0."""
    return (-q + math.sqrt(q * q + 4 * q * r)) / 2


@pytest.mark.parametrize("step,landmarks", [(0.0, 4), (0.0, 7), (0.011, 4), (0.011, 1)])
def test_steady_state_error_while_landmarks_are_seen_is_a_few_centimetres(step, landmarks):
    n, rng = 10000, np.random.default_rng(1)
    loc = Localization(_params(), n, DT, rng)
    start = np.column_stack([rng.uniform(-4, 4, n), rng.uniform(-3, 3, n), rng.uniform(-3, 3, n)])
    loc.reset(start)
    pose = start
    for _ in range(40):                                          # 400 frames: converged (K ≈ 0.03 a frame)
        poses = _walk(n, 10, step, 0.0, pose)
        loc.step(poses, np.full((10, n), landmarks))
        pose = poses[-1]
    k = min(landmarks, 4)
    q_xy = 0.1 ** 2 * step + 0.01 ** 2 * DT
    q_yaw = 0.05 ** 2 * step + 0.01 ** 2 * DT
    expected = np.array([_riccati(q_xy, 0.2 ** 2 / k)] * 2 + [_riccati(q_yaw, 0.1 ** 2 / k)])
    np.testing.assert_allclose(loc.variances[-1], np.broadcast_to(expected, (n, 3)), rtol=1e-6)
    e = _errors(loc, pose)
    assert np.all(np.abs(e.mean(axis=0)) < 5 * np.sqrt(expected / n))
    np.testing.assert_allclose(e.var(axis=0), expected, rtol=5 * math.sqrt(2 / n))
    # B-Human's "a few centimetres": 1.8 cm standing with 4 sightings a frame, 3.2 cm walking, 4.6 cm with one.
    assert 0.01 < math.sqrt(expected[0]) < 0.05
    assert loc.covariance.shape == (n, 3, 3) and np.all(loc.covariance[:, 0, 1] == 0)
    assert not loc.flipped.any()


def test_odometry_drift_grows_the_error_as_documented_without_landmarks():
    n, frames, step, turn = 20000, 50, 0.011, 0.02
    loc = Localization(_params(), n, DT, np.random.default_rng(2))
    loc.reset(np.zeros((n, 3)))
    before = _errors(loc, np.zeros((n, 3)))
    poses = _walk(n, frames, step, turn)
    loc.step(poses, np.zeros((frames, n), int))
    # per frame: xy 0.1²·0.011 + 0.01²·0.1 = 1.2e-4 m²; yaw 0.1²·0.02 + 0.05²·0.011 + 0.01²·0.1 = 2.375e-4 rad²
    growth = np.array([1.2e-4, 1.2e-4, 2.375e-4])
    start = np.array([0.05 ** 2, 0.05 ** 2, 0.05 ** 2])
    for f in (0, 24, 49):
        np.testing.assert_allclose(loc.variances[f], np.broadcast_to(start + (f + 1) * growth, (n, 3)), rtol=1e-9)
    e = _errors(loc, poses[-1])
    expected = start + frames * growth
    np.testing.assert_allclose(e.var(axis=0), expected, rtol=5 * math.sqrt(2 / n))
    # the error added by walking is independent of the error before it: the variances add
    np.testing.assert_allclose((e - before).var(axis=0), frames * growth, rtol=5 * math.sqrt(2 / n))
    # the estimate moves with the true displacement: on average it walked the 0.55 m the robot did
    assert np.mean(loc.estimate[:, 0] - before[:, 0]) == pytest.approx(poses[-1, 0, 0], abs=5 * math.sqrt(
        expected[0] / n))


def test_the_reported_covariance_is_calibrated_in_a_mixed_history():
    n, rng = 20000, np.random.default_rng(3)
    loc = Localization(_params(), n, DT, np.random.default_rng(4))
    pose = np.column_stack([rng.uniform(-4, 4, n), rng.uniform(-3, 3, n), rng.uniform(-3, 3, n)])
    loc.reset(pose)
    for _ in range(6):
        poses = np.empty((10, n, 3))
        for f in range(10):
            speed, turn = rng.uniform(0, 0.02, n), rng.uniform(-0.05, 0.05, n)
            pose = pose + np.column_stack([speed * np.cos(pose[:, 2]), speed * np.sin(pose[:, 2]), turn])
            poses[f] = pose
        landmarks = np.where(rng.random((10, n)) < 0.5, 0, rng.integers(1, 7, (10, n)))
        events = np.where(rng.random((10, n)) < 0.02, FALL, 0) | np.where(rng.random((10, n)) < 0.01, RETURN, 0)
        loc.step(poses, landmarks, events.astype(np.uint8))
    z = _errors(loc, pose) / np.sqrt(loc.variances[-1])
    # the history mixes tracking, drifting, falls, re-entries and flips: the last frame's σ ranges from cm to m
    sigma = np.sqrt(loc.variances[-1, :, 0])
    assert sigma.min() < 0.05 and sigma.max() > 0.5 and loc.flipped.any()
    assert np.all(np.abs(z.mean(axis=0)) < 5 / math.sqrt(n))
    np.testing.assert_allclose(z.var(axis=0), 1.0, atol=5 * math.sqrt(2 / n))


def _one_relocalization(n, frame_seconds, seed):
    """Every robot falls (lost: σ 0.5 m > 0.3 m) and sees 4 landmarks in the same frame."""
    loc = Localization(_params(), n, frame_seconds, np.random.default_rng(seed))
    truth = np.column_stack([np.full(n, 2.0), np.full(n, 1.0), np.full(n, 0.5)])
    loc.reset(truth)
    loc.step(truth[None], np.full((1, n), 4), np.full((1, n), FALL, np.uint8))
    return loc, truth


@pytest.mark.parametrize("frame_seconds,probability", [(0.1, 0.005), (40.0, 0.05)])
def test_flip_rate_on_relocalizing_from_lost_with_and_without_a_cue(frame_seconds, probability):
    # a frame of 0.1 s after the kickoff placement is within the 30 s cue; a frame of 40 s is not
    n = 200000
    loc, truth = _one_relocalization(n, frame_seconds, 5)
    flips = np.count_nonzero(loc.flipped)
    assert abs(flips - n * probability) < 5 * math.sqrt(n * probability * (1 - probability))
    # a flipped estimate lies at the mirror pose (−2, −1, 0.5 + π) with its usual error
    e = _errors(loc, truth)
    sigma = np.sqrt(loc.variances[-1])
    assert np.all(np.abs(e) < 6 * sigma)
    flipped = loc.flipped
    assert np.all(np.abs(loc.estimate[flipped, :2] - [-2.0, -1.0]) < 6 * sigma[flipped, :2])


def test_a_flip_needs_being_lost_persists_while_tracking_and_is_cleared_by_a_kickoff():
    n = 50000
    loc = Localization(_params(), n, 40.0, np.random.default_rng(6))
    truth = np.tile([2.0, 1.0, 0.5], (n, 1))
    loc.reset(truth)
    loc.step(truth[None], np.full((1, n), 4))                  # not lost (σ ≈ 0.07 m): no flip even without a cue
    assert not loc.flipped.any()
    loc.step(truth[None], np.full((1, n), 4), np.full((1, n), FALL, np.uint8))
    flipped = loc.flipped.copy()
    assert 0.04 * n < flipped.sum() < 0.06 * n
    poses = _walk(n, 20, 0.011, 0.0, truth)
    loc.step(poses, np.full((20, n), 4))                       # tracking, not lost (σ ≈ 7 cm): stays as it was
    assert np.array_equal(loc.flipped, flipped)
    mirrored = -poses[-1, flipped, :2]
    assert np.allclose(loc.estimate[flipped, :2], mirrored, atol=0.4)
    loc.step(poses[-1:], np.full((1, n), 4), np.full((1, n), KICKOFF, np.uint8))
    assert not loc.flipped.any()
    np.testing.assert_allclose(loc.estimate[:, :2], poses[-1, :, :2], atol=6 * 0.05)


def test_penalty_and_reentry_reset_to_the_touchline_prior():
    n = 20000
    loc = Localization(_params(), n, DT, np.random.default_rng(7))
    spot = np.tile([-2.4, 3.0, -math.pi / 2], (n, 1))           # team A's touchline spot, facing into the field
    loc.reset(np.zeros((n, 3)))
    # penalized: moved to the touchline, then standing there seeing landmarks: the estimate holds the prior
    penalized = np.ones((3, n), bool)
    events = np.zeros((3, n), np.uint8)
    events[0] = PENALTY
    loc.step(np.broadcast_to(spot, (3, n, 3)), np.full((3, n), 4), events, penalized)
    prior = np.array([1.0 ** 2, 0.1 ** 2, 0.1 ** 2])            # along (x), across (y) the touchline, heading
    for f in range(3):
        np.testing.assert_allclose(loc.variances[f], np.broadcast_to(prior, (n, 3)), rtol=1e-12)
    assert np.array_equal(loc.estimates[0], loc.estimates[2])
    # re-entry without a landmark in that frame: the prior, sampled consistently
    loc.step(spot[None], np.zeros((1, n), int), np.full((1, n), RETURN, np.uint8))
    np.testing.assert_allclose(loc.covariance[0], np.diag(prior), rtol=1e-12)
    e = _errors(loc, spot)
    np.testing.assert_allclose(e.std(axis=0), [1.0, 0.1, 0.1], rtol=5 * math.sqrt(1 / (2 * n)))
    assert not loc.flipped.any()
    # lost along the line (σ 1 m > 0.3 m): the first sightings re-localize, the re-entry cue keeping flips rare
    loc.step(spot[None], np.full((1, n), 4))
    assert loc.flipped.sum() < 0.005 * n + 5 * math.sqrt(0.005 * n)
    assert np.all(np.sqrt(loc.variances[-1, :, 0]) < 0.11)


def _spy(vision):
    """Record the events each localization step is given."""
    seen = []
    step = vision.localization.step

    def recording(pose, landmarks, events, penalized):
        seen.append(np.array(events))
        step(pose, landmarks, events, penalized)
    vision.localization.step = recording
    return seen


def test_the_worlds_falls_goals_penalties_and_reentries_reach_the_localization():
    world = make_world(players_per_team=2, falls={"enabled": True, "p_walk": 1.0, "p_fall_again": 0.0})
    world.place_robot(0, -2.0, 0.0, 0.0)
    vision = SoccerVision(world, load_preset("realistic"), localization=True)
    seen = _spy(vision)
    forward = SoccerAction(walk=Walk.FORWARD)
    world.step([forward, IDLE, IDLE, IDLE], on_frame=vision.frame)     # robot 0 falls as the period starts
    vision.perceive()
    assert seen[-1][0].tolist() == [FALL, 0, 0, 0] and not seen[-1][1:].any()
    # robot 3 leaves the field: penalized at the next vision instant, placed at the touchline
    world.place_robot(3, 0.0, 10.0, 0.0)
    world.step([IDLE] * 4, on_frame=vision.frame)
    vision.perceive()
    assert seen[-1][0].tolist() == [0, 0, 0, PENALTY] and not seen[-1][1:].any()
    np.testing.assert_allclose(vision.covariance[3], np.diag([1.0, 0.01, 0.01]), rtol=1e-12)
    # a goal: every robot on the field is placed for the kickoff (robot 3, penalized, is not)
    world.place_ball(4.3, 0.1, 1.5, 0.0)
    world.step([IDLE] * 4, on_frame=vision.frame)
    vision.perceive()
    frame = next(k for k in range(5) if seen[-1][k].any())
    assert seen[-1][frame].tolist() == [KICKOFF] * 4
    assert np.all(vision.localization.variances[frame, :3, 0] <= 0.05 ** 2 + 1e-12)
    assert not vision.flipped.any()
    # the first penalty lasts 20 s (40 periods): then the return
    returned = None
    for _period in range(45):
        world.step([IDLE] * 4, on_frame=vision.frame)
        vision.perceive()
        if seen[-1][:, 3].any():
            returned = seen[-1][:, 3]
            break
    assert returned is not None and RETURN in returned.tolist()
    assert not vision.flipped[3]


def test_the_none_preset_gives_the_exact_pose_and_zero_covariance():
    world = make_world(players_per_team=2)
    vision = SoccerVision(world, load_preset("none"), localization=True)
    rng = np.random.default_rng(8)
    for _ in range(10):
        actions = [SoccerAction(walk=Walk(int(rng.integers(3))), turn=int(rng.integers(3))) for _ in range(4)]
        world.step(actions, on_frame=vision.frame)
        vision.perceive()
        truth = np.array([(r.x, r.y, _wrap(r.yaw)) for r in world.robots])
        assert np.array_equal(vision.estimate, truth)
        assert np.array_equal(vision.covariance, np.zeros((4, 3, 3)))
        assert not vision.flipped.any()


@pytest.mark.parametrize("override,message", [
    ({"flip_probability": 1.5}, "localization.flip_probability must be a probability"),
    ({"landmark_xy_std": -0.1}, "localization.landmark_xy_std must not be negative"),
    ({"landmark_yaw_std": 0.0}, "must be positive"),
    ({"landmark_cap": 0}, "localization.landmark_cap must be a whole number >= 1"),
    ({"landmark_cap": 2.5}, "localization.landmark_cap must be a whole number >= 1"),
    ({"cue_seconds": float("nan")}, "localization.cue_seconds must be finite"),
    ({"fall_xy_std": "big"}, "localization.fall_xy_std must be a number"),
    ({"mode": "particles"}, "localization.mode must be one of"),
    ({"flip_probability_cue": 0.2}, "flip_probability_cue must not exceed flip_probability"),
    ({"particles": 12}, "localization: unknown setting(s) ['particles']"),
])
def test_bad_parameters_are_refused_with_the_key_named(override, message):
    with pytest.raises(ValueError) as info:
        load_preset("realistic", localization={**REALISTIC, **override})
    assert message in str(info.value)


def _session_estimates(seed, localization=True, periods=6):
    session = SoccerSession(SoccerConfig(players_per_team=2), load_preset("realistic"), seed=seed,
                            localization=localization)
    session.reset(seed=seed)
    session.initial()
    out = [session.vision.estimate.copy()]
    for _ in range(periods):
        session.step()
        out.append((session.vision.estimate.copy(), session.vision.covariance.copy(), session.vision.flipped.copy()))
    return out


def test_a_seed_gives_the_same_estimates_and_another_seed_others():
    a, b, c = _session_estimates(3), _session_estimates(3), _session_estimates(4)
    assert_identical(a, b)
    assert not np.array_equal(a[-1][0], c[-1][0])


def test_estimates_need_the_switch():
    world = make_world()
    with pytest.raises(RuntimeError, match="localization=True"):
        _ = SoccerVision(world, load_preset("realistic")).estimate


@pytest.mark.parametrize("observation", ["partial", "padded"])
def test_switching_localization_on_leaves_every_observation_and_reward_bit_identical(observation):
    runs = []
    for on in (False, True):
        env = parallel_env(players_per_team=2, observation=observation)
        env.observations.localization = on
        obs, _ = env.reset(seed=11)
        for k, agent in enumerate(env.possible_agents):
            env.action_space(agent).seed(12 + k)
        record = [obs]
        for _ in range(25):
            actions = {a: env.action_space(a).sample() for a in env.agents}
            obs, rewards, terms, truncs, _ = env.step(actions)
            record.append((obs, rewards, terms, truncs))
        record.append(env.state())
        runs.append(record)
        assert (env.observations.vision.localization is not None) == on
    assert_identical(runs[0], runs[1])


def test_in_a_game_the_estimate_is_centimetres_off_while_landmarks_are_seen():
    session = SoccerSession(SoccerConfig.from_mapping({"players_per_team": 2, "falls": {"enabled": False}}),
                            load_preset("realistic"),
                            seed=13, localization=True)
    session.reset(seed=13)
    session.initial()
    errors = []
    for _ in range(60):
        session.step()
        truth = np.array([(r.x, r.y) for r in session.world.robots])
        flipped = session.vision.flipped
        target = np.where(flipped[:, None], -truth, truth)
        errors += np.hypot(*(session.vision.estimate[:, :2] - target).T).tolist()
    assert np.median(errors) < 0.08
