"""The soccer world seen through each robot's vision pipeline: records the world at every vision instant of a
motion period, then perceives all robots' frames in one vectorised pass and scores what they truly saw."""
from __future__ import annotations

import math

import numpy as np

from dynenv_ros.core.object_classes import ObjectClass
from dynenv_ros.perception.localization import FALL, KICKOFF, PENALTY, RETURN, Localization
from dynenv_ros.perception.model import Perception, Perceiver
from dynenv_ros.perception.params import PerceptionParams
from dynenv_ros.perception.scene import SceneFrames, SceneObjects, Views
from dynenv_ros.soccer.robot import BODY_RADIUS
from dynenv_ros.soccer.world import SoccerWorld

GOALPOST_ID, PENALTY_MARK_ID, CROSSING_ID, CENTER_CIRCLE_ID = 1000, 1100, 1200, 1300
_PROPRIOCEPTION_FIELDS = np.array((5, 3, 4, 6))   # of a robot's recorded values: head yaw, fallen, penalized, kicking
# The world's GameEvents that move a robot's pose estimate (perception/localization.py); a goal means a kickoff.
_LOCALIZATION_EVENTS = {"fall": FALL, "penalty": PENALTY, "return": RETURN}


def soccer_scene(world: SoccerWorld) -> SceneObjects:
    """Robots (ids 0..n-1), the ball (id n), then goalposts, penalty marks and line crossings (ids from 1000)."""
    f, n = world.config.field, world.n_robots
    ball_d = 2 * world.config.ball.radius
    crossings = f.line_crossings
    classes = ([ObjectClass.ROBOT] * n + [ObjectClass.BALL] + [ObjectClass.GOALPOST] * len(f.goalposts)
               + [ObjectClass.PENALTY_CROSS] * len(f.penalty_marks) + [ObjectClass.LINE_CROSSING] * len(crossings)
               + [ObjectClass.CENTER_CIRCLE])
    ids = (list(range(n + 1)) + [GOALPOST_ID + i for i in range(len(f.goalposts))]
           + [PENALTY_MARK_ID + i for i in range(len(f.penalty_marks))]
           + [CROSSING_ID + i for i in range(len(crossings))] + [CENTER_CIRCLE_ID])
    size = ([2 * BODY_RADIUS] * n + [ball_d] + [2 * f.goalpost_radius] * len(f.goalposts)
            + [f.penalty_mark_size] * len(f.penalty_marks) + [0.1] * len(crossings) + [2 * f.center_circle_radius])
    team = [r.team for r in world.robots] + [0] * (len(classes) - n)
    subtype = [0] * (n + 1 + len(f.goalposts) + len(f.penalty_marks)) + [int(c.shape) for c in crossings] + [0]
    total = len(classes)
    return SceneObjects(
        class_id=np.array(classes, np.uint8), object_id=np.array(ids, np.int32), size_x=np.array(size),
        size_y=np.array(size), team=np.array(team, np.int8), subtype=np.array(subtype, np.uint8),
        occluder=np.arange(total) < n, dynamic=np.arange(total) <= n, lines=np.asarray(f.lines, float))


class SoccerVision:
    """Attach to a world: call ``frame`` at each vision instant (``world.step(..., on_frame=vision.frame)``), then
    ``perceive`` once per period.

    ``localization=True`` also steps every robot's emulated self-pose estimate once per frame
    (``perception/localization.py``, parameters ``params.localization``): after each ``perceive``, ``estimate``
    (n, 3) x, y, yaw in the field frame, ``covariance`` (n, 3, 3) and ``flipped`` (n,) at the period's last frame
    (``localization.estimates`` etc. for every frame). Its draws come from its own generator, a child spawned from the
    world's seed sequence at each ``reset`` (``world.rng.spawn``, which leaves the world's stream untouched), so
    switching it on changes no other outcome. Off by default: nothing of it runs."""

    def __init__(self, world: SoccerWorld, params: PerceptionParams, localization: bool = False) -> None:
        self.world = world
        self.params = params
        self.localization: Localization | None = None
        self._localize = localization
        self.reset()

    def reset(self) -> None:
        """Call after ``world.reset`` (the scene's robots are the world's)."""
        world = self.world
        self.objects = soccer_scene(world)
        self.perceiver = Perceiver(self.objects, self.params)
        # robots out of play for the episode (an attack start without defenders): nobody sees them, they earn nothing
        self._absent = np.array([r.index for r in world.robots if r.rules.absent], np.intp)
        if len(self._absent):
            self.perceiver.leave_out(self._absent)
        frames = world.config.rates.frames_per_period
        n, total = world.n_robots, len(self.objects.class_id)
        f = world.config.field
        static = np.vstack([f.goalposts, f.penalty_marks, [[c.x, c.y] for c in f.line_crossings], [[0.0, 0.0]]])
        self._x = np.zeros((frames, total))
        self._y = np.zeros((frames, total))
        self._x[:, n + 1:], self._y[:, n + 1:] = static[:, 0], static[:, 1]
        self._yaw = np.full((frames, total), np.nan)
        self._fallen = np.zeros((frames, total), bool)
        self._penalized = np.zeros((frames, total), bool)
        self._head = np.zeros((frames, n))
        self._values: list[float] = []      # recorded this period, flat (see ``frame``)
        self._recorded = 0
        self._views: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        self.teams = np.array([r.team for r in world.robots], np.int8)
        self._landmark_index = np.flatnonzero(self.perceiver.is_landmark)
        if self._localize:
            self._reset_localization()

    def _reset_localization(self) -> None:
        world = self.world
        rates = world.config.rates
        self.localization = Localization(self.params.localization, world.n_robots,
                                         rates.vision_period_ticks * rates.tick_seconds, world.rng.spawn(1)[0])
        self.localization.reset([(r.x, r.y, r.yaw) for r in world.robots])
        self._events = np.zeros((len(self._x), world.n_robots), np.uint8)   # per frame of the period, per robot
        self._event_list: list | None = None                                # the world's list read so far ...
        self._event_cursor = 0                                              # ... up to here

    def _record_events(self, slot: int) -> None:
        """Flag the world's events since the last frame (``world.events`` is a new list every period)."""
        world = self.world
        if world.events is not self._event_list:
            self._event_list, self._event_cursor = world.events, 0
        flags = self._events[slot]
        for event in world.events[self._event_cursor:]:
            if event.kind == "goal":
                flags |= KICKOFF
            elif event.kind in _LOCALIZATION_EVENTS and event.robot is not None:
                flags[event.robot] |= _LOCALIZATION_EVENTS[event.kind]
        self._event_cursor = len(world.events)

    @property
    def estimate(self) -> np.ndarray:
        """(n, 3) every robot's self-pose estimate (x, y m, yaw rad, field frame) at the last perceived frame."""
        return self._located().estimate

    @property
    def covariance(self) -> np.ndarray:
        """(n, 3, 3) the estimates' covariance (x, y, yaw; m², rad²) at the last perceived frame."""
        return self._located().covariance

    @property
    def flipped(self) -> np.ndarray:
        """(n,) bool: the estimate tracks the mirror pose (−x, −y, yaw + π) at the last perceived frame."""
        return self._located().flipped

    def _located(self) -> Localization:
        if self.localization is None:
            raise RuntimeError("self-localization is off: make the vision with SoccerVision(..., localization=True)")
        return self.localization

    def frame(self, index: int) -> None:
        """Record the world at this vision instant."""
        if self._recorded >= len(self._x):
            raise RuntimeError("more vision frames than a motion period holds; call perceive() every period")
        # Plain Python floats in one flat list now, one numpy conversion per period in perceive(): per robot
        # (x, y, yaw, fallen, penalized, head yaw, kicking), the ball as a row of the same shape, then the game.
        world = self.world
        values = self._values
        # Within SoccerWorld.step the world has just read every position (``instant_positions``); else read them.
        positions, ball = world.instant_positions or ([r.body.position for r in world.robots], world.ball.position)
        for r, (x, y) in zip(world.robots, positions):
            values += (x, y, r.body.angle, r.rules.fallen, r.rules.penalized, r.head_yaw, r.kick is not None)
        if self.localization is not None:
            self._record_events(self._recorded)
        x, y = ball
        state = world.state
        # What the GameController broadcasts: ball owner (absolute team), seconds of it left, game seconds left.
        values += (x, y, math.nan, 0, 0, 0, 0, state.ball_owner,
                   max(0.0, state.ball_owner_remaining) if state.ball_owner else 0.0, world.time_remaining)
        self._recorded += 1

    def positions(self, frame: int) -> tuple[np.ndarray, np.ndarray]:
        """Field positions of the scene's objects at a frame of the last perceived period (for drawing)."""
        return self._x[frame], self._y[frame]

    def robot_states(self, frame: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every robot's body yaw (field frame), head yaw (relative to the body) and fallen flag at a frame of the
        last perceived period (views, no copy)."""
        n = self.world.n_robots
        return self._yaw[frame, :n], self._head[frame], self._fallen[frame, :n]

    def frames_recorded(self) -> int:
        return self._recorded

    def perceive(self) -> Perception:
        """All robots' detections for the recorded frames (view index = frame · n_robots + robot)."""
        frames, n = self._recorded, self.world.n_robots
        values = np.array(self._values, np.float64).reshape(frames, 7 * (n + 1) + 3)
        table = values[:, :7 * (n + 1)].reshape(frames, n + 1, 7)          # robots, then the ball
        game = values[:, 7 * (n + 1):]
        self._values = []
        self._recorded = 0
        # Each robot's own state per frame: head yaw, fallen, penalized, kicking (what it knows of itself).
        self.proprioception = table[:, :n].take(_PROPRIOCEPTION_FIELDS, axis=2).astype(np.float32)
        # What the GameController tells each robot per frame, (F, n, 3): ball ownership relative to the robot's team
        # (+1 own, -1 opponents, 0 free), seconds left of that ownership (0 when free), game seconds left.
        controller = np.empty((frames, n, 3), np.float32)
        controller[:] = game[:, None]
        controller[:, :, 0] *= self.teams                 # ±1 and 0 times a float32: exact, as in float64
        self.game_controller = controller
        self._x[:frames, :n + 1], self._y[:frames, :n + 1] = table[:, :, 0], table[:, :, 1]
        self._yaw[:frames, :n] = table[:, :n, 2]
        self._fallen[:frames, :n] = table[:, :n, 3] > 0
        self._penalized[:frames, :n] = table[:, :n, 4] > 0
        self._head[:frames] = table[:, :n, 5]
        if frames not in self._views:
            self._views[frames] = (np.repeat(np.arange(frames), n), np.tile(np.arange(n), frames),
                                   np.tile(self.teams, frames))
        frame_of_view, observer, team = self._views[frames]
        views = Views(frame=frame_of_view, observer=observer, head_yaw=self._head[:frames].ravel())
        scene = SceneFrames(self._x[:frames], self._y[:frames], self._yaw[:frames], self._fallen[:frames],
                            self._penalized[:frames])
        perception = self.perceiver.perceive(scene, views, self.world.rng, team)
        if self.localization is not None:
            events = self._events[:frames]
            self.localization.step(table[:, :n, :3], self.landmarks_seen(perception), events,
                                   self._penalized[:frames, :n])
            events[:] = 0
        return perception

    def landmarks_seen(self, perception: Perception) -> np.ndarray:
        """(frames, n_robots): landmarks (posts, marks, crossings, lines) each robot truly saw in each frame."""
        n = self.world.n_robots
        frames = len(perception) // n
        seen = perception.seen.reshape(frames, n, -1)
        return seen[:, :, self.perceiver.is_landmark].sum(axis=2) + perception.lines_seen.reshape(frames, n)

    def observation_rewards(self, perception: Perception) -> np.ndarray:
        """(n_robots,) DynEnv's reward for looking around, from what each robot truly saw this period."""
        # Frames in which each observer truly saw each object (integer counts, so their sums are exact in any
        # order); per observer: other robots seen (each at most robot_cap frames), landmarks and lines a frame on
        # average (at most landmark_cap), the ball (at most ball_cap frames), weighted. One compiled pass
        # (soccer_kernels.observation_rewards): the same float operations as the numpy expression it replaced.
        w = self.world.config.rewards
        rewards: np.ndarray = self.perceiver._kernels.observation_rewards(
            perception.seen, perception.lines_seen, self.world.n_robots, self._landmark_index,
            w.observation_robot_cap, float(w.observation_landmark_cap), w.observation_ball_cap, w.observation_robot,
            w.observation_landmark, w.observation_ball)
        rewards[self._absent] = 0.0
        return rewards
