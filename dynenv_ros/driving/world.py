"""The driving world: cars, pedestrians, obstacles and buildings on two crossing roads, one motion period per step.

ROS-free, like the soccer world. A period applies each car's action once (the vehicle model in cars.py), then runs
its physics ticks in chunks between vision instants (one per period by default, at its last tick). Contacts are
pymunk callbacks, resolved right after the tick they happen in; lane position, reaching the destination, leaving
the road, opposing-lane driving and progress are judged at each vision instant. Per tick the only Python work is
``Space.step``; pedestrians cost Python only when one of them changes its movement.

Rewards (RewardTerm rows, one column per car), with the original's magnitudes (config.py, docs/driving.md):
PRIMARY destination reached (+ seconds left) and the team bonus; RULE crashes (−2·|v| per crash, doubled for a
car out of its right lane or driving into another) and opposing-lane driving (−0.1 per metre); AUXILIARY progress
toward the destination (+0.2 per metre closer); OBSERVATION is always 0 here (nothing is observed in this world:
the original driving scenario has no observation reward, its seen statistics are the constant (1, 1, 1)).
"""
from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np
import pymunk

from dynenv_ros.core.object_classes import ObjectClass, ObjectStatus
from dynenv_ros.driving.cars import (ACCELERATION_CHOICES, BRAKE, STEERING_CHOICES, Car, Category, CollisionType,
                                     DrivingAction, car_types, discrete_action, parse_action)
from dynenv_ros.driving.config import SCENARIO_DRIVING, DrivingConfig
from dynenv_ros.driving.pedestrians import Pedestrians
from dynenv_ros.driving.roads import DrivingMap, LanePosition
from dynenv_ros.sim.ground_truth import BodyState, WorldSnapshot
from dynenv_ros.sim.physics import PhysicsWorld
from dynenv_ros.sim.reward_terms import RewardLedger, RewardTerm
from dynenv_ros.sim.scenario import FrameCallback, GameEvent, PeriodResult

TEAM_A, TEAM_B = 1, -1
PHASE_PLAYING, PHASE_FINISHED = 2, 6      # WorldState.PHASE_*
_STATIC_KIND = {CollisionType.OBSTACLE: "obstacle", CollisionType.BUILDING: "building", CollisionType.WALL: "wall"}


class DrivingWorld:
    """Up to 10 cars, 100 Hz physics; ``step`` advances one 100 ms motion period of every car."""

    scenario = SCENARIO_DRIVING

    def __init__(self, config: DrivingConfig | None = None, seed: int | None = None) -> None:
        self.config = config or DrivingConfig()
        self.map = DrivingMap(self.config.map)
        self.rng = np.random.default_rng(seed)
        self.episode_id = 0
        self._build()

    # -- episode -----------------------------------------------------------------------------------------------
    def reset(self, seed: int | None = None) -> None:
        """A fresh episode (new cars, destinations, pedestrians, obstacles). A seed re-seeds the world's only
        random generator."""
        if seed is not None:
            self.rng = np.random.default_rng(seed)
        self.episode_id += 1
        self._build()

    def _build(self) -> None:
        c = self.config
        rng = self.rng
        self._tick_seconds = c.rates.tick_seconds
        self._period_seconds = c.period_seconds
        self._vision_offsets = tuple(enumerate(c.rates.vision_tick_offsets()))   # fixed per config
        self._episode_ticks = c.episode_ticks
        self.physics = PhysicsWorld(self._tick_seconds)
        space = self.physics.space
        self.tick = 0
        self.period = 0
        self.done = False
        self.ledger = RewardLedger(c.n_cars)
        self.events: list[GameEvent] = []
        self._pending: list[tuple[Any, ...]] = []
        self._team_bonus_paid: set[int] = set()
        # Draws, always in this order: spawn spots, car types, destinations, obstacles, pedestrians.
        spots = self.map.spawn_spots
        chosen = rng.choice(len(spots), size=c.n_cars, replace=False)
        types = car_types(c.cars)
        type_index = rng.integers(len(types), size=c.n_cars)
        self.cars: list[Car] = []
        for i in range(c.n_cars):
            team = TEAM_A if c.teams == 1 or i % 2 == 0 else TEAM_B
            car = Car(i, team, types[int(type_index[i])], c.cars)
            car.add_to(space)
            spot = spots[int(chosen[i])]
            car.place(spot.x, spot.y, spot.yaw)
            car.start_end = spot.end
            others = [e for e in range(len(self.map.destinations)) if e != spot.end]
            self._set_goal(car, int(others[int(rng.integers(len(others)))]))
            self.cars.append(car)
        self._car_of_shape = {car.shape: car for car in self.cars}
        self._discrete_table = [[discrete_action(a, k, c.cars.max_yaw_rate) for k in range(STEERING_CHOICES)]
                                for a in range(ACCELERATION_CHOICES)]
        self.last_actions: list[DrivingAction] = [BRAKE] * c.n_cars
        self._add_buildings(space)
        self._add_walls(space)
        self._add_obstacles(space, int(rng.integers(c.obstacles.count_min, c.obstacles.count_max + 1)))
        count = int(rng.integers(c.pedestrians.count_min, c.pedestrians.count_max + 1))
        self.pedestrians = Pedestrians(rng, c.pedestrians, self.map, self._tick_seconds, count)
        self.pedestrians.add_to(space)
        self._add_handlers(space)

    def _static_box(self, space: pymunk.Space, cx: float, cy: float, hx: float, hy: float,
                    collision_type: int) -> pymunk.Poly:
        shape = pymunk.Poly(space.static_body, [(cx - hx, cy - hy), (cx + hx, cy - hy), (cx + hx, cy + hy),
                                                (cx - hx, cy + hy)])
        shape.elasticity = self.config.cars.elasticity
        shape.friction = self.config.cars.friction
        shape.collision_type = collision_type
        shape.filter = pymunk.ShapeFilter(categories=Category.STATIC, mask=Category.CAR)
        space.add(shape)
        return shape

    def _add_buildings(self, space: pymunk.Space) -> None:
        for b in self.map.buildings:
            self._static_box(space, b.x, b.y, b.half_x, b.half_y, CollisionType.BUILDING)

    def _add_walls(self, space: pymunk.Space) -> None:
        """The real position clamp (DynEnv's was a no-op): walls ``boundary_margin`` outside the map."""
        m, w, h = self.config.map.boundary_margin, self.map.width, self.map.height
        t = 5.0   # wall thickness, m
        for cx, cy, hx, hy in ((w / 2, -m - t, w / 2 + m + 2 * t, t), (w / 2, h + m + t, w / 2 + m + 2 * t, t),
                               (-m - t, h / 2, t, h / 2 + m + 2 * t), (w + m + t, h / 2, t, h / 2 + m + 2 * t)):
            self._static_box(space, cx, cy, hx, hy, CollisionType.WALL)

    def _add_obstacles(self, space: pymunk.Space, count: int) -> None:
        """Static boxes wholly on the walkways (none can land on the road, so none is dropped)."""
        segments = self.map.walkway_segments
        half = self.config.obstacles.size / 2
        weights = np.array([s.length for s in segments])
        choice = self.rng.choice(len(segments), size=count, p=weights / weights.sum())
        xy = np.zeros((count, 2))
        for j, k in enumerate(choice):
            seg = segments[int(k)]
            s = self.rng.uniform(seg.s_min + half, seg.s_max - half)
            d = seg.side * self.rng.uniform(seg.inner + half, seg.outer - half)
            xy[j] = self.map.roads[seg.road].to_map(s, d)
            self._static_box(space, xy[j, 0], xy[j, 1], half, half, CollisionType.OBSTACLE)
        self.obstacles_xy = xy

    def _add_handlers(self, space: pymunk.Space) -> None:
        space.on_collision(CollisionType.CAR, CollisionType.CAR, begin=self._on_car_contact)
        space.on_collision(CollisionType.CAR, CollisionType.PEDESTRIAN, begin=self._on_pedestrian_contact)
        for kind in _STATIC_KIND:
            space.on_collision(CollisionType.CAR, kind, begin=self._on_static_contact)

    def _set_goal(self, car: Car, goal: int) -> None:
        car.goal = goal
        car.goal_xy = (float(self.map.destinations[goal, 0]), float(self.map.destinations[goal, 1]))
        car.last_goal_distance = math.hypot(car.x - car.goal_xy[0], car.y - car.goal_xy[1])

    # -- public view -------------------------------------------------------------------------------------------
    @property
    def n_cars(self) -> int:
        return len(self.cars)

    @property
    def game_time(self) -> float:
        return self.tick * self._tick_seconds

    @property
    def time_remaining(self) -> float:
        return max(0.0, (self._episode_ticks - self.tick) * self._tick_seconds)

    def cars_done(self) -> list[bool]:
        """Per car: finished, and nothing more to earn (crashed, or its team's bonus decided). A car home while a
        team-mate still drives stays in the game: the team bonus is paid to cars already home."""
        pending = set()
        for team in {car.team for car in self.cars}:
            members = [car for car in self.cars if car.team == team]
            if not all(car.finished for car in members) and not any(car.crashed for car in members):
                pending.add(team)
        return [car.finished and (car.crashed or car.team not in pending) for car in self.cars]

    @property
    def names(self) -> list[str]:
        return self.config.car_names

    def parse_actions(self, actions: Sequence[Any], names: Sequence[str] | None = None) -> list[DrivingAction]:
        """Validate every car's action before anything moves; ValueError names the car and the field."""
        names = names or self.config.car_names
        if len(actions) != self.n_cars:
            raise ValueError(f"expected {self.n_cars} actions (one per car), got {len(actions)}")
        mode, limit = self.config.action_mode, self.config.cars.max_yaw_rate
        if isinstance(actions, np.ndarray):   # a batch from a learner or a pool: checked at once when valid
            fast = self._parse_batch(actions)
            if fast is not None:
                return fast
        return [parse_action(name, raw, mode=mode, max_yaw_rate=limit) for name, raw in zip(names, actions)]

    def _parse_batch(self, actions: np.ndarray) -> list[DrivingAction] | None:
        """All cars' actions from one array, or None to let ``parse_action`` find and name the problem."""
        limit = self.config.cars.max_yaw_rate
        if self.config.action_mode == "discrete":
            if actions.shape != (self.n_cars, 2) or actions.dtype.kind not in "iu":
                return None
            if actions.min() < 0 or actions.max() >= ACCELERATION_CHOICES:
                return None
            table = self._discrete_table
            return [table[a][s] for a, s in actions.tolist()]
        if actions.shape != (self.n_cars, 3) or actions.dtype.kind != "f":
            return None
        low, high = np.array([-1.0, 0.0, -limit]), np.array([1.0, 1.0, limit])
        if not (np.isfinite(actions).all() and (actions >= low - 1e-6).all() and (actions <= high + 1e-6).all()):
            return None
        return [DrivingAction(*row) for row in np.clip(actions, low, high).tolist()]

    def lane_position(self, index: int) -> LanePosition:
        car = self.cars[index]
        return self.map.classify(car.x, car.y, car.yaw, car.goal)

    def snapshot(self) -> WorldSnapshot:
        """Cars (ids 0..n−1), pedestrians, then obstacles. Static map geometry (roads, walkways, the four
        buildings) is not listed: it is fixed by ``config.map`` like the soccer field (docs/driving.md)."""
        objects = [self._car_state(car) for car in self.cars]
        peds = self.pedestrians
        diameter = 2 * self.config.pedestrians.radius
        first = self.n_cars
        for i, body in enumerate(peds.bodies):
            if peds.alive[i]:
                p, v = body.position, body.velocity
                objects.append(BodyState(id=first + i, class_id=ObjectClass.PEDESTRIAN, x=p.x, y=p.y,
                                         yaw=math.atan2(v.y, v.x) if v.x or v.y else 0.0, vx=v.x, vy=v.y,
                                         size_x=diameter, size_y=diameter))
            else:
                x, y = peds.death_xy[i]
                objects.append(BodyState(id=first + i, class_id=ObjectClass.PEDESTRIAN, x=float(x), y=float(y),
                                         size_x=diameter, size_y=diameter, status=ObjectStatus.CRASHED))
        first += len(peds)
        size = self.config.obstacles.size
        for j, (x, y) in enumerate(self.obstacles_xy):
            objects.append(BodyState(id=first + j, class_id=ObjectClass.OBSTACLE, x=float(x), y=float(y),
                                     size_x=size, size_y=size))
        return WorldSnapshot(scenario=self.scenario, episode_id=self.episode_id, tick=self.tick,
                             tick_period=self._tick_seconds, game_time=self.game_time,
                             time_remaining=self.time_remaining,
                             phase=PHASE_FINISHED if self.done else PHASE_PLAYING, objects=tuple(objects))

    def _car_state(self, car: Car) -> BodyState:
        status = ObjectStatus.NONE
        if car.finished:
            status |= ObjectStatus.FINISHED
        if car.crashed:
            status |= ObjectStatus.CRASHED
        if car.at_goal:
            status |= ObjectStatus.AT_GOAL
        v = car.body.velocity
        t = car.type
        return BodyState(id=car.index, class_id=ObjectClass.CAR, team=car.team, x=car.x, y=car.y, yaw=car.yaw,
                         vx=v.x, vy=v.y, yaw_rate=car.body.angular_velocity, size_x=2 * t.half_length,
                         size_y=2 * t.half_width, status=status, goal_x=car.goal_xy[0], goal_y=car.goal_xy[1])

    # -- scripted situations (tests, demos) ------------------------------------------------------------------------
    def place_car(self, index: int, x: float, y: float, yaw: float, speed: float = 0.0) -> None:
        """Teleport a car (between periods), moving at ``speed`` along ``yaw``; no progress is paid for the jump."""
        car = self.cars[index]
        car.place(x, y, yaw, speed)
        car.in_opposing_lane = False
        car.last_goal_distance = math.hypot(x - car.goal_xy[0], y - car.goal_xy[1])

    def set_goal(self, index: int, destination: int) -> None:
        """Send a car to one of the four road ends (``map.destinations``)."""
        if not 0 <= destination < len(self.map.destinations):
            raise ValueError(f"destination must be a road end index 0..{len(self.map.destinations) - 1}, "
                             f"got {destination}")
        self._set_goal(self.cars[index], destination)

    def place_pedestrian(self, i: int, x: float, y: float, vx: float = 0.0, vy: float = 0.0,
                         hold_seconds: float = 1e6) -> None:
        self.pedestrians.place(i, x, y, vx, vy, hold_seconds, self.tick)

    # -- one motion period -------------------------------------------------------------------------------------
    def step(self, actions: Sequence[Any], on_frame: FrameCallback | None = None,
             names: Sequence[str] | None = None) -> PeriodResult:
        """Run one motion period. ``on_frame(k)`` is called at each of its vision instants, k = 0..frames-1."""
        parsed = self.parse_actions(actions, names)
        if self.done:
            raise RuntimeError("the episode has finished; call reset() first")
        self.last_actions = parsed
        self.ledger.clear()
        self.events = []
        self.pedestrians.update(self.tick)
        seconds = self._period_seconds
        for car, action in zip(self.cars, parsed):
            car.apply(action, seconds)
        space_step, dt = self.physics.space.step, self._tick_seconds
        done = 0
        for frame, boundary in self._vision_offsets:
            for _ in range(boundary - done):   # tick by tick, so a contact's event carries its own tick
                self.tick += 1
                space_step(dt)
            done = boundary
            self._vision_instant()
            if on_frame is not None:
                on_frame(frame)
        self.period += 1
        terminated = all(car.finished for car in self.cars)
        truncated = not terminated and self.period >= self.config.episode_periods
        self.done = terminated or truncated
        return PeriodResult(self.ledger.values.copy(), terminated, truncated, self.events)

    def _vision_instant(self) -> None:
        """Lane position, destination, leaving the road, opposing lane and progress of every car still driving."""
        rewards = self.config.rewards
        classify = self.map.classify
        ledger = self.ledger.values
        for car in self.cars:
            if car.finished:
                continue
            p = car.body.position
            x, y = p.x, p.y
            gx, gy = car.goal_xy
            distance = math.hypot(x - gx, y - gy)
            ledger[RewardTerm.AUXILIARY, car.index] += rewards.progress_per_metre * (car.last_goal_distance - distance)
            car.last_goal_distance = distance
            position = classify(x, y, car.body.angle, car.goal)
            if position == LanePosition.AT_GOAL:
                ledger[RewardTerm.PRIMARY, car.index] += rewards.goal_per_second * self.time_remaining
                car.finish(crashed=False, at_goal=True)
                car.leave(self.physics.space)
                self._event("goal", car, f"destination {car.goal}")
            elif position >= LanePosition.OVER_ROAD:
                self._crash(car, car.abs_velocity,
                            "off road" if position == LanePosition.OFF_ROAD else "past a road end")
            elif position == LanePosition.OPPOSING_LANE:
                lx, ly = car.last_xy
                ledger[RewardTerm.RULE, car.index] -= rewards.opposing_per_metre * math.hypot(x - lx, y - ly)
                if not car.in_opposing_lane:
                    self._event("opposing_lane", car)
                car.in_opposing_lane = True
            else:
                car.in_opposing_lane = False
            car.last_xy = (x, y)
        self._team_bonus()

    def _team_bonus(self) -> None:
        """Once every car of a team has finished without crashing, each of them gets the seconds left (once)."""
        for team in {car.team for car in self.cars} - self._team_bonus_paid:
            members = [car for car in self.cars if car.team == team]
            if all(car.finished for car in members):
                self._team_bonus_paid.add(team)
                if not any(car.crashed for car in members):
                    bonus = self.config.rewards.team_bonus_per_second * self.time_remaining
                    self.ledger.add_many(RewardTerm.PRIMARY, [car.index for car in members], bonus)
                    self.events.append(GameEvent("team_bonus", self.tick, team=team, detail=f"{bonus:.2f}"))

    # -- contacts (pymunk callbacks: record now, act right after the tick) -----------------------------------------
    def _defer(self, *event: Any) -> None:
        self._pending.append(event)
        self.physics.space.add_post_step_callback(self._resolve_pending, "rules")

    def _resolve_pending(self, space: pymunk.Space, key: Any) -> None:
        pending, self._pending = self._pending, []
        for kind, *args in pending:
            getattr(self, "_resolve_" + kind)(*args)

    def _on_car_contact(self, arbiter: pymunk.Arbiter, space: pymunk.Space, data: Any) -> None:
        a, b = (self._car_of_shape.get(s) for s in arbiter.shapes)
        if a is not None and b is not None:
            self._defer("cars", a, b, tuple(a.body.velocity), tuple(b.body.velocity))

    def _on_pedestrian_contact(self, arbiter: pymunk.Arbiter, space: pymunk.Space, data: Any) -> None:
        car = self._car_of_shape.get(arbiter.shapes[0])
        i = self.pedestrians.index_of(arbiter.shapes[1])
        if car is not None and i is not None and car.abs_velocity > self.config.pedestrians.hit_min_speed:
            self._defer("pedestrian", car, i, tuple(car.body.velocity))

    def _on_static_contact(self, arbiter: pymunk.Arbiter, space: pymunk.Space, data: Any) -> None:
        car = self._car_of_shape.get(arbiter.shapes[0])
        if car is not None and not car.finished:
            self._defer("static", car, _STATIC_KIND[arbiter.shapes[1].collision_type], car.abs_velocity)

    # -- rule decisions ----------------------------------------------------------------------------------------------
    def _toward(self, car: Car, velocity: tuple[float, float], x: float, y: float) -> bool:
        """Moving toward a point: cos(velocity, direction to it) > blame_cos (DynEnv's pushing test)."""
        dx, dy = x - car.x, y - car.y
        speed, dist = math.hypot(*velocity), math.hypot(dx, dy)
        return speed > 0 and dist > 0 and (velocity[0] * dx + velocity[1] * dy) / (speed * dist) > \
            self.config.rewards.blame_cos

    def _resolve_cars(self, a: Car, b: Car, va: tuple[float, float], vb: tuple[float, float]) -> None:
        """Both crash. Each still driving pays −k·|v|; again if out of its right lane; again, when both were in their
        right lanes, if it drove into the other (docs/original.md §3)."""
        k = self.config.rewards.crash_per_speed
        lanes = {car.index: self.map.classify(car.x, car.y, car.body.angle) for car in (a, b)}
        for car, other, v in ((a, b, va), (b, a, vb)):
            if car.finished:
                continue
            speed = math.hypot(*v)
            penalty = k * speed
            if lanes[car.index] != LanePosition.RIGHT_LANE:
                penalty += k * speed
            elif lanes[other.index] == LanePosition.RIGHT_LANE and self._toward(car, v, other.x, other.y):
                penalty += k * speed
            self.ledger.add(RewardTerm.RULE, car.index, -penalty)
            car.finish(crashed=True)
            self._event("crash", car, f"car {other.index}")

    def _resolve_pedestrian(self, car: Car, i: int, velocity: tuple[float, float]) -> None:
        peds = self.pedestrians
        if not peds.alive[i]:
            return
        body = peds.bodies[i]
        toward = self._toward(car, velocity, body.position.x, body.position.y)
        peds.kill(i, self.physics.space)
        self._event("pedestrian_hit", car, f"pedestrian {self.n_cars + i}")
        if toward and not car.finished:
            self._crash(car, math.hypot(*velocity), "pedestrian")

    def _resolve_static(self, car: Car, kind: str, speed: float) -> None:
        if not car.finished:
            self._crash(car, speed, kind)

    def _crash(self, car: Car, speed: float, detail: str) -> None:
        self.ledger.add(RewardTerm.RULE, car.index, -self.config.rewards.crash_per_speed * speed)
        car.finish(crashed=True)
        self._event("crash", car, detail)

    def _event(self, kind: str, car: Car, detail: str = "") -> None:
        self.events.append(GameEvent(kind, self.tick, car.index, car.team, detail))


__all__ = ["DrivingWorld", "TEAM_A", "TEAM_B", "PHASE_PLAYING", "PHASE_FINISHED"]
