"""The RoboCup SPL world: physics, robot motions and the referee, one motion period per ``step``.

ROS-free. A period runs its ticks in chunks between vision instants (and kick strokes); contacts are handled in
pymunk callbacks and resolved right after the tick they happen in, so per tick the only Python work is
``Space.step``. Positional rules, timers and approach shaping run at vision instants (10 Hz by default).
"""
from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np
import pymunk

from dynenv_ros.core.object_classes import ObjectClass, ObjectStatus
from dynenv_ros.sim.ground_truth import BodyState, WorldSnapshot
from dynenv_ros.sim.physics import PhysicsWorld
from dynenv_ros.sim.reward_terms import RewardLedger, RewardTerm
from dynenv_ros.sim.scenario import FrameCallback, GameEvent, PeriodResult
from dynenv_ros.soccer.actions import IDLE, Kick, SoccerAction, parse_action
from dynenv_ros.soccer.config import SCENARIO_SOCCER as SCENARIO_SOCCER   # its home is the config's, kept here too
from dynenv_ros.soccer.config import SoccerConfig
from dynenv_ros.soccer.placement import absent_spot, attack_scene, free_spot, kickoff_poses, sideline_spots
from dynenv_ros.soccer.referee import GameState, Phase, decide_out
from dynenv_ros.soccer.rewards import share_ball_value
from dynenv_ros.soccer.robot import BODY_RADIUS, Category, CollisionType, Robot

TEAM_A, TEAM_B = 1, -1
_EPS = 1e-9


class SoccerWorld:
    """Two teams, one ball, 100 Hz physics; ``step`` advances one motion period of high-level actions."""

    scenario = SCENARIO_SOCCER

    def __init__(self, config: SoccerConfig | None = None, seed: int | None = None) -> None:
        self.config = config or SoccerConfig()
        self.rng = np.random.default_rng(seed)
        self.episode_id = 0
        self._build(None)

    # -- episode -----------------------------------------------------------------------------------------------
    def reset(self, seed: int | None = None, kickoff_team: int | None = None,
              config: SoccerConfig | None = None) -> None:
        """A fresh episode. A seed re-seeds the world's only random generator. ``kickoff_team``: the team that starts
        with the ball (None: team A at a kickoff; at an attack start, team A in even episodes and team B in odd ones,
        so the two teams attack by turns). ``config``: the settings from this episode on, e.g. a curriculum's next
        start (``config.start``) or episode length; the number of robots stays."""
        if kickoff_team is not None and kickoff_team not in (TEAM_A, TEAM_B):
            raise ValueError(f"kickoff_team must be 1 (team A) or -1 (team B), got {kickoff_team!r}")
        if config is not None:
            if config.players_per_team != self.config.players_per_team:
                raise ValueError(f"reset(config=...) keeps the world's {self.config.players_per_team} robots a "
                                 f"side, got players_per_team={config.players_per_team}")
            self.config = config
        if seed is not None:
            self.rng = np.random.default_rng(seed)
        self.episode_id += 1
        self._build(kickoff_team)

    def _build(self, kickoff_team: int | None) -> None:
        c = self.config
        attack = c.start.kind == "attack"
        if attack and c.start.kickoff_share > 0.0:     # drawn only then: other settings keep their random streams
            attack = bool(self.rng.random() >= c.start.kickoff_share)
        self.start_kind = "attack" if attack else "kickoff"     # how this episode started
        if kickoff_team is None:
            kickoff_team = TEAM_B if attack and self.episode_id % 2 else TEAM_A
        self._tick_seconds = c.rates.tick_seconds
        self._vision_seconds = c.rates.vision_period_ticks * self._tick_seconds
        self._period_seconds = c.period_seconds
        self._episode_seconds = c.episode_periods * self._period_seconds
        self.physics = PhysicsWorld(self._tick_seconds)
        space = self.physics.space
        self.tick = 0
        self.instant_positions: tuple[list, Any] | None = None   # see _approach_rewards
        self.period = 0
        self.state = GameState(kickoff_team=kickoff_team)
        self.ledger = RewardLedger(c.n_robots)
        self.events: list[GameEvent] = []
        self._pending: list[tuple[Any, ...]] = []
        self._contacts: set[tuple[int, int]] = set()
        self._progress_anchor: float | None = None
        self.robots = [Robot(i, TEAM_A if i < c.players_per_team else TEAM_B, i % c.players_per_team, c)
                       for i in range(c.n_robots)]
        # What each robot was told to do last period (a robot knows its own command; observations carry it).
        self.last_actions: list[SoccerAction] = [IDLE] * c.n_robots
        self._robot_of_shape: dict[pymunk.Shape, Robot] = {r.shape: r for r in self.robots}
        for robot in self.robots:
            robot.add_to(space)
        self._add_goalposts(space)
        self._add_ball(space)
        self._add_out_sensors(space)
        self._add_handlers(space)
        if attack:
            self._attack_start(kickoff_team)
        else:
            self._kickoff(kickoff_team)

    def _add_goalposts(self, space: pymunk.Space) -> None:
        f = self.config.field
        for x, y in f.goalposts:
            post = pymunk.Circle(space.static_body, f.goalpost_radius, (float(x), float(y)))
            post.elasticity = 0.95
            post.friction = 0.5
            post.collision_type = CollisionType.GOALPOST
            post.filter = pymunk.ShapeFilter(categories=Category.GOALPOST, mask=Category.ROBOT | Category.BALL)
            space.add(post)

    def _add_ball(self, space: pymunk.Space) -> None:
        b = self.config.ball
        self.ball = pymunk.Body(b.mass, pymunk.moment_for_circle(b.mass, 0.0, b.radius))
        shape = pymunk.Circle(self.ball, b.radius)
        shape.elasticity = b.elasticity
        shape.friction = b.friction
        shape.collision_type = CollisionType.BALL
        shape.filter = pymunk.ShapeFilter(categories=Category.BALL)
        space.add(self.ball, shape)
        self.physics.add_floor_friction(self.ball, b.deceleration, b.spin_deceleration)

    def _add_out_sensors(self, space: pymunk.Space) -> None:
        """Sensors whose edge lies two ball radii past each line: touched when the ball is wholly over it."""
        f, r = self.config.field, self.config.ball.radius
        hx, hy, far = f.half_length + 2 * r, f.half_width + 2 * r, 50.0
        boxes = [(-far, hy, far, far), (-far, -far, far, -hy), (hx, -hy, far, hy), (-far, -hy, -hx, hy)]
        for x0, y0, x1, y1 in boxes:
            sensor = pymunk.Poly(space.static_body, [(x0, y0), (x1, y0), (x1, y1), (x0, y1)])
            sensor.sensor = True
            sensor.collision_type = CollisionType.BALL_OUT
            sensor.filter = pymunk.ShapeFilter(categories=Category.SENSOR, mask=Category.BALL)
            space.add(sensor)

    def _add_handlers(self, space: pymunk.Space) -> None:
        space.on_collision(CollisionType.ROBOT, CollisionType.BALL, begin=self._on_ball_touch)
        space.on_collision(CollisionType.KICK_FOOT, CollisionType.BALL, begin=self._on_ball_touch)
        space.on_collision(CollisionType.BALL, CollisionType.BALL_OUT, begin=self._on_ball_out)
        space.on_collision(CollisionType.ROBOT, CollisionType.ROBOT, begin=self._on_robot_contact,
                           post_solve=self._on_robot_pressing, separate=self._on_robot_separate)
        space.on_collision(CollisionType.ROBOT, CollisionType.GOALPOST, post_solve=self._on_post_pressing,
                           separate=self._on_post_separate)

    # -- public view -------------------------------------------------------------------------------------------
    @property
    def n_robots(self) -> int:
        return len(self.robots)

    @property
    def game_time(self) -> float:
        return self.tick * self._tick_seconds

    @property
    def time_remaining(self) -> float:
        return max(0.0, self._episode_seconds - self.game_time)

    @property
    def ball_xy(self) -> tuple[float, float]:
        p = self.ball.position
        return (p.x, p.y)

    def parse_actions(self, actions: Sequence[Any], names: Sequence[str] | None = None) -> list[SoccerAction]:
        """Validate every robot's action before anything moves; ValueError names the robot and the field."""
        names = names or [f"robot {i}" for i in range(self.n_robots)]
        if len(actions) != self.n_robots:
            raise ValueError(f"expected {self.n_robots} actions (one per robot), got {len(actions)}")
        m = self.config.motion
        return [parse_action(name, raw, head_mode=self.config.head_mode, head_step=m.head_step,
                             head_units=m.head_units) for name, raw in zip(names, actions)]

    def snapshot(self) -> WorldSnapshot:
        objects = [self._robot_state(r) for r in self.robots]
        v = self.ball.velocity
        ball_d = 2 * self.config.ball.radius
        objects.append(BodyState(id=self.n_robots, class_id=ObjectClass.BALL, x=self.ball.position.x,
                                 y=self.ball.position.y, vx=v.x, vy=v.y, yaw_rate=self.ball.angular_velocity,
                                 size_x=ball_d, size_y=ball_d))
        s = self.state
        return WorldSnapshot(scenario=self.scenario, episode_id=self.episode_id, tick=self.tick,
                             tick_period=self._tick_seconds,
                             game_time=self.game_time, time_remaining=self.time_remaining, phase=int(s.phase),
                             ball_owner_team=s.ball_owner, ball_owner_remaining=s.ball_owner_remaining,
                             last_touch_robot_ids=tuple(s.chain), score_team_a=s.score[TEAM_A],
                             score_team_b=s.score[TEAM_B], objects=tuple(objects))

    def _robot_state(self, r: Robot) -> BodyState:
        status = ObjectStatus.NONE
        if r.rules.fallen:
            status |= ObjectStatus.FALLEN
        if r.rules.penalized:
            status |= ObjectStatus.PENALIZED
        if r.kick is not None:
            status |= ObjectStatus.KICKING
        moving = r.in_space
        v = r.body.velocity if moving else pymunk.Vec2d(0.0, 0.0)
        return BodyState(id=r.index, class_id=ObjectClass.ROBOT, team=r.team, x=r.x, y=r.y, yaw=r.yaw, vx=v.x,
                         vy=v.y, yaw_rate=r.body.angular_velocity if moving else 0.0, head_yaw=r.head_yaw,
                         size_x=2 * BODY_RADIUS, size_y=2 * BODY_RADIUS, status=status,
                         penalty_remaining=max(0.0, r.rules.penalty_remaining) if r.rules.penalized else 0.0)

    # -- scripted situations (tests, demos) ------------------------------------------------------------------------
    def place_robot(self, index: int, x: float, y: float, yaw: float) -> None:
        robot = self.robots[index]
        robot.place(x, y, yaw)
        robot.rules.last_ball_distance = None

    def place_ball(self, x: float, y: float, vx: float = 0.0, vy: float = 0.0) -> None:
        self._flush_progress()
        self.ball.position = (x, y)
        self.ball.velocity = (vx, vy)
        self.ball.angular_velocity = 0.0
        self.physics.space.reindex_shapes_for_body(self.ball)
        self._after_ball_teleport()

    def set_ball_owner(self, team: int, seconds: float, phase: Phase = Phase.KICK_IN) -> None:
        if team == 0:
            self.state.free_ball()
        else:
            self.state.give_ball(team, seconds, phase)

    # -- one motion period -------------------------------------------------------------------------------------
    def step(self, actions: Sequence[Any], on_frame: FrameCallback | None = None,
             names: Sequence[str] | None = None) -> PeriodResult:
        """Run one motion period. ``on_frame(k)`` is called at each of its vision instants, k = 0..frames-1."""
        parsed = self.parse_actions(actions, names)
        if self.state.phase == Phase.FINISHED:
            raise RuntimeError("the episode has finished; call reset() first")
        self.last_actions = parsed
        self.ledger.clear()
        self.events = []
        rates = self.config.rates
        period_ticks = rates.motion_period_ticks
        strikes = self._start_period(parsed)
        schedule: dict[int, list[tuple[Robot, int]]] = {}
        strike_ticks = max(1, round(self.config.kick.strike_seconds / self._tick_seconds))
        for robot in strikes:
            for offset, stroke in ((0, 1), (strike_ticks, -1), (2 * strike_ticks, 0)):
                schedule.setdefault(min(offset, period_ticks), []).append((robot, stroke))
        vision = rates.vision_tick_offsets()
        frame_of = {offset: k for k, offset in enumerate(vision)}
        done = 0
        for boundary in sorted(set(vision) | set(schedule)):
            if boundary > done:
                self.physics.step(boundary - done)
                self.tick += boundary - done
                done = boundary
            for robot, stroke in schedule.get(boundary, ()):
                self._stroke(robot, stroke)
            frame = frame_of.get(boundary)
            if frame is not None:
                self._vision_instant((frame + 1) / len(vision))
                try:
                    if on_frame is not None:
                        on_frame(frame)
                finally:
                    self.instant_positions = None
        self._flush_progress()
        self.period += 1
        truncated = self.period >= self.config.episode_periods
        if truncated:
            self.state.phase = Phase.FINISHED
        return PeriodResult(self.ledger.values.copy(), False, truncated, self.events)

    def _start_period(self, actions: list[SoccerAction]) -> list[Robot]:
        """Apply each robot's action (or not: fallen, penalized, kicking); return the robots that strike now."""
        falls = self.config.falls
        period_seconds = self._period_seconds
        strikes = []
        for robot, action in zip(self.robots, actions):
            robot.begin_head_turn(action.head_yaw_delta)
            if robot.kick is not None:
                robot.kick.periods_left -= 1
                if robot.kick.periods_left <= 0:
                    robot.end_kick(self.physics.space)
                elif robot.kick.periods_left == 1:
                    strikes.append(robot)
            if not robot.can_act:
                continue
            if action.kick != Kick.NONE and not action.moves:
                if falls.enabled and self.rng.random() < falls.p_kick:
                    self._fall(robot, punish=False, reason="fell while kicking")
                    continue
                robot.start_kick(action.kick)
                if robot.kick is not None and robot.kick.periods_left == 1:
                    strikes.append(robot)
            elif action.moves:
                if falls.enabled and (
                        (action.walk and self.rng.random() < falls.p_walk)
                        or (action.turn and self.rng.random() < falls.p_turn)):
                    self._fall(robot, punish=False, reason="fell while walking")
                    continue
                robot.walk(action, period_seconds)
            else:
                robot.stand()
        return strikes

    def _stroke(self, robot: Robot, stroke: int) -> None:
        if robot.kick is None or not robot.in_space:
            return
        if stroke == 0:
            robot.withdraw_foot(self.physics.space)
        else:
            robot.strike(self.physics.space, stroke)

    def _vision_instant(self, fraction: float) -> None:
        """Clocks, timers and positional rules, evaluated at every vision frame."""
        dt = self._vision_seconds
        f = self.config.field
        world_x, world_y = f.half_length + f.border, f.half_width + f.border
        area_front = f.half_length - f.penalty_area_length
        area_half_width = f.penalty_area_width / 2
        # Every body's position read once (a pymunk read costs ≈ 0.7 µs) and used by the rules and the approach
        # shaping, unless a rule moved a robot (penalty, return, getting up or falling): from then on read anew.
        positions = [robot.body.position for robot in self.robots]
        moved = False
        for robot, position in zip(self.robots, positions):
            robot.head_yaw = robot.head_at(fraction)
            rules = robot.rules
            if rules.penalized:
                rules.penalty_remaining -= dt
                if rules.penalty_remaining <= _EPS:
                    self._unpenalize(robot)
                    moved = True
                continue
            if rules.fallen:
                rules.fall_timer -= dt
                if rules.fall_timer <= _EPS:
                    self._try_get_up(robot)
                    moved = True
            x, y = robot.body.position if moved else position
            if abs(x) > world_x or abs(y) > world_y:
                self._penalize(robot, "left the field")
                moved = True
                continue
            if robot.team * x < -area_front and abs(y) < area_half_width:
                if rules.entered_own_area_tick is None:
                    rules.entered_own_area_tick = self.tick
            else:
                rules.entered_own_area_tick = None
        moved = self._check_illegal_defenders() or moved
        s = self.state
        if s.ball_owner != 0:
            s.ball_owner_remaining -= dt
            if s.ball_owner_remaining <= _EPS:
                s.free_ball()
        self._approach_rewards(None if moved else positions)

    def _check_illegal_defenders(self) -> bool:
        """Penalize the robots beyond the limit in their own penalty area; whether any was."""
        limit = self.config.penalties.max_in_own_penalty_area
        inside_any = [r for r in self.robots if r.rules.entered_own_area_tick is not None and not r.rules.penalized]
        if len(inside_any) <= limit:                   # no team can have more (the usual case: one pass)
            return False
        penalized = False
        for team in (TEAM_A, TEAM_B):
            inside = [r for r in inside_any if r.team == team]
            if len(inside) > limit:
                inside.sort(key=lambda r: (r.rules.entered_own_area_tick, r.slot))
                for robot in inside[limit:]:
                    self._penalize(robot, "illegal defender")
                    penalized = True
        return penalized

    def _approach_rewards(self, positions: list[Any] | None = None) -> None:
        """The robot of each team closest to the ball is paid for closing in on it (docs/original.md §6.1).
        ``positions``: the robots' positions now, if the caller has read them since anything moved."""
        weight = self.config.rewards.approach_per_m
        # Every body's position once (a pymunk read costs µs), kept for this instant's on_frame callback: the
        # last rule of the instant has acted, and nothing moves before the callback returns (then cleared).
        if positions is None:
            positions = [robot.body.position for robot in self.robots]
        ball = self.ball.position
        self.instant_positions = (positions, ball)
        bx, by = ball
        best: dict[int, tuple[float, Robot]] = {}
        for robot, (x, y) in zip(self.robots, positions):
            if robot.rules.penalized:
                continue
            d = math.hypot(x - bx, y - by)
            if robot.team not in best or d < best[robot.team][0]:
                best[robot.team] = (d, robot)
            robot.rules.approach_candidate = d
        for d, robot in best.values():
            last = robot.rules.last_ball_distance
            if last is not None:
                self.ledger.add(RewardTerm.AUXILIARY, robot.index, -weight * (d - last))
        for robot in self.robots:
            if not robot.rules.penalized:
                robot.rules.last_ball_distance = robot.rules.approach_candidate

    # -- contacts (pymunk callbacks: record now, act right after the tick) -----------------------------------------
    def _defer(self, *event: Any) -> None:
        self._pending.append(event)
        self.physics.space.add_post_step_callback(self._resolve_pending, "rules")

    def _resolve_pending(self, space: pymunk.Space, key: Any) -> None:
        # Within one tick, touches and falls happened before the ball was judged out: resolve them first.
        pending, self._pending = sorted(self._pending, key=lambda event: event[0] == "out"), []
        for kind, *args in pending:
            getattr(self, "_resolve_" + kind)(*args)

    def _on_ball_touch(self, arbiter: pymunk.Arbiter, space: pymunk.Space, data: Any) -> None:
        shape = arbiter.shapes[0]
        robot = self._robot_of_shape.get(shape)
        if robot is None:   # a kicking foot
            robot = next((r for r in self.robots if r.kick is not None and r.kick.foot_shape is shape), None)
        if robot is not None:
            self._defer("touch", robot)

    def _on_ball_out(self, arbiter: pymunk.Arbiter, space: pymunk.Space, data: Any) -> None:
        self._defer("out")

    def _robot_pair(self, arbiter: pymunk.Arbiter) -> tuple[Robot, Robot] | None:
        a, b = (self._robot_of_shape.get(s) for s in arbiter.shapes)
        return (a, b) if a is not None and b is not None else None

    def _on_robot_contact(self, arbiter: pymunk.Arbiter, space: pymunk.Space, data: Any) -> None:
        pair = self._robot_pair(arbiter)
        if pair is None:
            return
        a, b = pair
        falls = self.config.falls
        for robot, other in ((a, b), (b, a)):
            vx, vy = robot.commanded_velocity()
            speed = math.hypot(vx, vy)
            dx, dy = other.x - robot.x, other.y - robot.y
            dist = math.hypot(dx, dy)
            if speed > falls.push_min_speed and dist > 0 and (vx * dx + vy * dy) / (speed * dist) > falls.push_cos:
                robot.pushing.add(other.index)
        self._contacts.add((min(a.index, b.index), max(a.index, b.index)))

    def _on_robot_pressing(self, arbiter: pymunk.Arbiter, space: pymunk.Space, data: Any) -> None:
        falls = self.config.falls
        pair = self._robot_pair(arbiter)
        if not falls.enabled or pair is None:
            return
        a, b = pair
        for robot, other in ((a, b), (b, a)):
            if robot.rules.fallen or robot.rules.penalized:
                continue
            robot.rules.contact_ticks += 1
            pushing = other.index in robot.pushing
            base = falls.contact_base_pusher if pushing else falls.contact_base
            if self.rng.random() > base ** robot.rules.contact_ticks:
                self._defer("fall", robot, pushing, "fell in a robot contact")

    def _on_robot_separate(self, arbiter: pymunk.Arbiter, space: pymunk.Space, data: Any) -> None:
        pair = self._robot_pair(arbiter)
        if pair is None:
            return
        a, b = pair
        a.pushing.discard(b.index)
        b.pushing.discard(a.index)
        a.rules.contact_ticks = b.rules.contact_ticks = 0
        self._contacts.discard((min(a.index, b.index), max(a.index, b.index)))

    def _on_post_pressing(self, arbiter: pymunk.Arbiter, space: pymunk.Space, data: Any) -> None:
        falls = self.config.falls
        robot = self._robot_of_shape.get(arbiter.shapes[0])
        if robot is None or not falls.enabled or robot.rules.fallen or robot.rules.penalized:
            return
        robot.rules.contact_ticks += 1
        if self.rng.random() > falls.goalpost_base ** robot.rules.contact_ticks:
            self._defer("fall", robot, True, "fell against a goalpost")

    def _on_post_separate(self, arbiter: pymunk.Arbiter, space: pymunk.Space, data: Any) -> None:
        robot = self._robot_of_shape.get(arbiter.shapes[0])
        if robot is not None:
            robot.rules.contact_ticks = 0

    # -- rule decisions ----------------------------------------------------------------------------------------------
    def _resolve_fall(self, robot: Robot, punish: bool, reason: str) -> None:
        self._fall(robot, punish, reason)

    def _resolve_touch(self, robot: Robot) -> None:
        if robot.rules.penalized:
            return
        self._flush_progress()
        s = self.state
        s.touched(robot.index, self.config.rewards.chain_length)
        self._event("touch", robot)
        if s.ball_owner == robot.team:
            s.free_ball()
        elif s.ball_owner == -robot.team:
            self._penalize(robot, "touched the ball during the opponents' free kick")

    def _resolve_out(self) -> None:
        f, r = self.config.field, self.config.ball.radius
        x, y = self.ball_xy
        if abs(x) <= f.half_length + r - _EPS and abs(y) <= f.half_width + r - _EPS:
            return   # already put back by an earlier event of the same tick
        s = self.state
        last_team = self.robots[s.chain[0]].team if s.chain else s.kickoff_team
        decision = decide_out(x, y, last_team, f, self.config.ball)
        self._flush_progress()
        if decision.goal_for:
            s.score[decision.goal_for] += 1
            self.events.append(GameEvent("goal", self.tick, team=decision.goal_for,
                                         detail=f"score {s.score[TEAM_A]}:{s.score[TEAM_B]}"))
            share_ball_value(self.ledger, RewardTerm.PRIMARY, self.config.rewards.goal * decision.goal_for,
                             self.robots, s.chain, (x, y), self.config.rewards)
            self._kickoff(-decision.goal_for)
            return
        self.events.append(GameEvent("out", self.tick, team=decision.awarded_to, detail=decision.restart.name))
        self.place_ball(*decision.ball_xy)
        s.give_ball(decision.awarded_to, self.config.ball.free_kick_ownership_seconds, decision.restart)

    def _fall(self, robot: Robot, punish: bool, reason: str) -> None:
        rules = robot.rules
        if rules.fallen or rules.penalized:
            return
        falls = self.config.falls
        if punish:
            self.ledger.add(RewardTerm.RULE, robot.index, self.config.rewards.fall)
        self._event("fall", robot, reason)
        rules.fallen = True
        rules.fall_timer = falls.getup_seconds
        rules.fall_count += 1
        robot.end_kick(self.physics.space)
        robot.stand()
        self._knock_around(robot)
        for i, j in list(self._contacts):
            if robot.index in (i, j):
                other = self.robots[j if i == robot.index else i]
                if (robot.index in other.pushing and other.index not in robot.pushing
                        and other.team != robot.team):
                    self._penalize(other, f"pushing robot {robot.index}")
        if rules.fall_count >= falls.falls_to_penalty:
            self._penalize(robot, f"fell {rules.fall_count} times without getting up")

    def _knock_around(self, robot: Robot) -> None:
        """A falling robot shoves the ball and robots close to it (docs/original.md §2.5)."""
        falls = self.config.falls
        bodies = [(other.body, other) for other in self.robots if other is not robot and other.in_space]
        bodies.append((self.ball, None))
        for body, other in bodies:
            dx, dy = body.position.x - robot.x, body.position.y - robot.y
            dist = math.hypot(dx, dy)
            if 0 < dist < falls.knock_radius:
                body.velocity = body.velocity + (dx / dist * falls.knock_speed, dy / dist * falls.knock_speed)
                if other is None:
                    self._flush_progress()
                    self.state.touched(robot.index, self.config.rewards.chain_length)

    def _try_get_up(self, robot: Robot) -> None:
        falls = self.config.falls
        if falls.enabled and self.rng.random() < falls.p_fall_again:
            robot.rules.fallen = False       # falls again at once, unpunished
            self._fall(robot, punish=False, reason="fell again while getting up")
            return
        robot.rules.fallen = False
        robot.rules.fall_count = 0
        self._event("get_up", robot)

    def _penalize(self, robot: Robot, reason: str) -> None:
        rules = robot.rules
        if rules.penalized:
            return
        seconds = self.state.next_penalty(robot.team, self.config.penalties)
        self.ledger.add(RewardTerm.RULE, robot.index, self.config.rewards.penalty_per_second * seconds)
        self._event("penalty", robot, f"{reason} ({seconds:g} s)")
        robot.remove_from(self.physics.space)
        self._contacts = {pair for pair in self._contacts if robot.index not in pair}
        for other in self.robots:
            other.pushing.discard(robot.index)
        rules.penalized, rules.penalty_remaining = True, seconds
        rules.fallen, rules.fall_timer, rules.fall_count, rules.contact_ticks = False, 0.0, 0, 0
        rules.entered_own_area_tick = rules.last_ball_distance = None
        robot.place(*self._sideline_spot(robot))

    def _unpenalize(self, robot: Robot) -> None:
        robot.rules.penalized = False
        robot.rules.penalty_remaining = 0.0
        robot.place(*self._sideline_spot(robot))
        robot.add_to(self.physics.space)
        self._event("return", robot)

    def _sideline_spot(self, robot: Robot) -> tuple[float, float, float]:
        p = self.config.penalties
        spots = sideline_spots(self.config.field, robot.team, self.ball_xy[1], p.sideline_spacing, p.spots_per_side)
        occupied = [(r.x, r.y) for r in self.robots if r is not robot]
        return free_spot(spots, occupied, p.sideline_spacing)

    def _kickoff(self, kicking_team: int) -> None:
        """Ball to the centre, robots to kickoff positions, the kicking team owns the ball (docs/original.md §2.2)."""
        c = self.config
        poses = kickoff_poses(self.rng, c.players_per_team, kicking_team)
        space = self.physics.space
        for robot in self.robots:
            if robot.rules.penalized:
                continue
            robot.end_kick(space)
            robot.rules.fallen, robot.rules.fall_timer, robot.rules.fall_count = False, 0.0, 0
            robot.rules.entered_own_area_tick = None
            robot.place(*poses[robot.team][robot.slot])
            robot.rules.last_ball_distance = None
        self.state.chain.clear()
        self.place_ball(0.0, 0.0)
        self.state.give_ball(kicking_team, c.ball.kickoff_ownership_seconds, Phase.KICKOFF)

    def _attack_start(self, attacking_team: int) -> None:
        """The ball near the goal ``attacking_team`` attacks, its robots behind the ball, the defenders at their
        kickoff spots or out of play; the ball free (docs/soccer.md, "Start states")."""
        c = self.config
        ball, attackers, defenders = attack_scene(self.rng, c.field, c.start, c.players_per_team, attacking_team)
        for robot in self.robots:
            if robot.team == attacking_team:
                robot.place(*attackers[robot.slot])
            elif defenders is not None:
                robot.place(*defenders[robot.slot])
            else:
                self._take_out(robot)
        self.place_ball(*ball)
        self.state.free_ball()

    def _take_out(self, robot: Robot) -> None:
        """Out of play for the rest of the episode (``defenders: absent``): off the physics world and the carpet,
        penalized for longer than the episode lasts (so it never acts, returns or earns, and the rules and the
        robots' perception pass it by: ``rules.absent``), without a penalty's cost or event."""
        robot.remove_from(self.physics.space)
        rules = robot.rules
        rules.absent = rules.penalized = True
        rules.penalty_remaining = self._episode_seconds + self._period_seconds
        robot.place(*absent_spot(self.config.field, robot.team, robot.slot))

    # -- bookkeeping ---------------------------------------------------------------------------------------------
    def _flush_progress(self) -> None:
        """Credit the ball's x travel since the last flush to the touch chain as it stood during that travel."""
        x, y = self.ball_xy
        anchor = self._progress_anchor
        if anchor is not None and x != anchor:
            share_ball_value(self.ledger, RewardTerm.AUXILIARY, self.config.rewards.ball_progress_per_m * (x - anchor),
                             self.robots, self.state.chain, (x, y), self.config.rewards)
        self._progress_anchor = x

    def _after_ball_teleport(self) -> None:
        self._progress_anchor = self.ball.position.x
        for robot in self.robots:
            robot.rules.last_ball_distance = None

    def _event(self, kind: str, robot: Robot, detail: str = "") -> None:
        self.events.append(GameEvent(kind, self.tick, robot.index, robot.team, detail))
