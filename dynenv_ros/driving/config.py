"""Every number of the driving world in one validated place: map, car types, pedestrians, obstacles, rewards.

Units and scale: metres, seconds, radians, kilograms. The original DynEnv driving world works in pixels; this one
uses **0.1 m per original pixel** throughout (lane width 35 px = 3.5 m, world 1700 x 1000 px = 170 x 100 m, cars
20–50 px = 2–5 m long, pedestrians 10 px = 1 m across). Speeds convert the same way (10 px/s = 1 m/s), so the
original's per-step speed changes keep their numbers in m/s per 100 ms period: gas +3.1 px/s per step is +0.31 m/s.

Map frame: origin at the map's lower-left corner, x east (right), y north (up), yaw counter-clockwise (REP 103).
The original's screen y points down; the map is symmetric about its horizontal road, so the buildings and roads
keep the original's coordinates times 0.1. Traffic drives on the right.

Rewards keep the original's magnitudes (so the paper's reward figures compare: random ≈ 0.7, Pred 26.47): a
per-pixel weight becomes a per-metre weight ten times larger, a weight on a speed in px/s becomes one ten times
larger on m/s. Defaults follow docs/original.md §1, §3, §6.2; docs/driving.md lists every
departure from the original and why.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from dataclasses import field as _default
from typing import Any, Mapping

from dynenv_ros.core.settings import build_settings, check_numbers
from dynenv_ros.sim.timing import Rates

MAX_CARS = 10
PX = 0.1                                   # metres per original DynEnv pixel
SCENARIO_DRIVING = 1                       # WorldState.SCENARIO_DRIVING
ACTION_MODES = ("discrete", "continuous")


def is_driving_world(code: int) -> bool:
    """Whether a WorldState's (a snapshot's) ``scenario`` code is driving's: what reads only driving's ground truth
    (the scripted drivers) refuses another world's."""
    return code == SCENARIO_DRIVING


def car_names(n_cars: int) -> list[str]:
    """Car names, also agent names and ROS namespaces (index = car id)."""
    return [f"car_{i}" for i in range(n_cars)]


@dataclass(frozen=True)
class MapConfig:
    """Two crossing roads, their walkways and four buildings (docs/original.md §3, × 0.1 m/px)."""
    width: float = 170.0                   # m (1700 px)
    height: float = 100.0                  # m (1000 px)
    lane_width: float = 3.5                # m (35 px)
    vertical_road_x: float = 87.5          # m: the north–south road's centre line (875 px)
    vertical_lanes: int = 2                # lanes per direction
    horizontal_road_y: float = 50.0        # m: the east–west road's centre line (500 px)
    horizontal_lanes: int = 1              # lanes per direction
    walkway_width: float = 3.5             # m: one lane width outside each road edge (walkway line at ±(n+1)·35 px)
    building_half_size: tuple[float, float] = (40.0, 22.5)   # m: half-extents x, y (400 x 225 px)
    building_centres: tuple[tuple[float, float], ...] = ((36.5, 20.0), (36.5, 80.0), (138.5, 20.0), (138.5, 80.0))
    off_road_margin: float = 0.5           # m beyond a road edge before a car is off road (5 px)
    end_margin: float = 1.0                # m beyond a road end before a car is past it (10 px)
    goal_radius: float = 10.0              # m: past the destination's road end and this close to it (100 px)
    spawns_per_lane: int = 5
    spawn_spacing: float = 9.0             # m between spawn spots of one lane (90 px)
    spawn_first: float = 4.5               # m from the road end to the first spot (half a spacing: the car is inside)
    boundary_margin: float = 10.0          # m: walls this far outside the map stop anything sliding away

    def __post_init__(self) -> None:
        object.__setattr__(self, "building_half_size", _float_tuple("map.building_half_size",
                                                                    self.building_half_size, 2))
        object.__setattr__(self, "building_centres", tuple(
            _float_tuple(f"map.building_centres[{i}]", c, 2) for i, c in enumerate(_sequence(
                "map.building_centres", self.building_centres))))


@dataclass(frozen=True)
class CarConfig:
    """Car types (drawn uniformly per car) and the vehicle model (docs/driving.md, "Vehicle model").

    ``power`` is the original's per-step speed gain in px/s, which is exactly the traction acceleration in m/s²
    (power px/s per 0.1 s = 10·power px/s² = power m/s²). Rolling resistance is the original's constant
    deceleration ∝ mass (5e-5 px/s per tick per kg = 5e-4 m/s² per kg), so type 1 (1800 kg, power 4) gains
    (4 − 0.9)·0.1 = 0.31 m/s per period on gas and loses (2·4 + 0.9)·0.1 = 0.89 m/s braking, as measured.
    """
    masses: tuple[float, ...] = (1200.0, 1800.0, 3500.0, 5000.0)      # kg
    half_widths: tuple[float, ...] = (0.5, 0.6, 0.7, 0.8)             # m (5..8 px)
    half_lengths: tuple[float, ...] = (1.0, 1.5, 2.0, 2.5)            # m (10..25 px)
    powers: tuple[float, ...] = (3.0, 4.0, 3.0, 4.0)                  # m/s² of traction at full throttle
    reverse_fraction: float = 0.75         # reverse traction = this · power
    brake_factor: float = 2.0              # full brake = this · power (m/s²)
    rolling_per_kg: float = 5e-4           # m/s² of rolling resistance per kg of mass
    finished_per_kg: float = 5e-3          # m/s² per kg once crashed or finished (the original's high friction)
    finished_spin: float = 2.0             # rad/s² of yaw deceleration once finished
    max_yaw_rate: float = math.radians(2.0) / 0.1   # rad/s: the discrete ±2° per 100 ms, also the continuous bound
    min_turn_radius: float = 4.0           # m: |yaw rate| ≤ |speed| / this (no turning on the spot)
    stop_speed: float = 0.01               # m/s: slower than this counts as standing (may change direction)
    drive_accel: float = 15.0              # m/s²: the drive joint's force cap per kg (tyre grip for collisions)
    drive_yaw_accel: float = 20.0          # rad/s²: the drive's torque cap per unit of moment of inertia
    elasticity: float = 0.05
    friction: float = 0.7                  # shape friction in contacts

    def __post_init__(self) -> None:
        for name in ("masses", "half_widths", "half_lengths", "powers"):
            object.__setattr__(self, name, _float_tuple(f"cars.{name}", getattr(self, name)))

    @property
    def n_types(self) -> int:
        return len(self.masses)


@dataclass(frozen=True)
class PedestrianConfig:
    """Walkers on the walkways; now and then one crosses its road (docs/original.md §3, × 0.1 m/px)."""
    count_min: int = 10
    count_max: int = 20
    mass: float = 90.0                     # kg, the original's; unused while pedestrians are kinematic sensors
    radius: float = 0.5                    # m (5 px)
    base_speed_min: int = 3                # base speed = randint(min, max) · speed_unit (3..6 px/s)
    base_speed_max: int = 6
    speed_unit: float = 0.1                # m/s per base-speed unit (1 px/s)
    walk_multiplier_max: int = 2           # walking: base · randint(−max, max) along the walkway (0 = stand)
    cross_multiplier_min: int = 1          # crossing: base · randint(min, max) across the road
    cross_multiplier_max: int = 2
    cross_probability: float = 0.05        # per new movement
    movement_ms_min: int = 5000            # a movement lasts randint(min, max) ms
    movement_ms_max: int = 30000
    lateral_min: float = 0.25              # placed this many lane widths outside the road edge (at least) ...
    lateral_max: float = 0.75              # ... and at most
    hit_min_speed: float = 0.1             # m/s: a slower car does not hurt a pedestrian (1 px/s)


@dataclass(frozen=True)
class ObstacleConfig:
    """Static boxes on the walkways (docs/original.md §3: 10–20 of 20 x 20 px)."""
    count_min: int = 10
    count_max: int = 20
    size: float = 2.0                      # m, square


@dataclass(frozen=True)
class RewardConfig:
    """Weights in SI units that give the original's reward magnitudes (docs/original.md §6.2, §3 collisions).

    Penalties are stored as positive magnitudes and subtracted.
    """
    goal_per_second: float = 1.0           # PRIMARY: seconds left in the episode when reaching the destination
    team_bonus_per_second: float = 1.0     # PRIMARY: to every car of a team once all of it finished uncrashed
    crash_per_speed: float = 2.0           # RULE: −this·|v| (m/s) per crash = the original −|v|/5 with v in px/s
    opposing_per_metre: float = 0.1        # RULE: per metre driven in the opposing lane (−|v|/10000 px/s per tick)
    progress_per_metre: float = 0.2        # AUXILIARY: per metre closer to the destination (Δpx/50)
    blame_cos: float = 0.4                 # a car drove into a body when cos(its velocity, direction to it) > this


@dataclass(frozen=True)
class DrivingConfig:
    n_cars: int = 2
    teams: int = 1                         # 1: every car shares the team bonus; 2: cars alternate teams A, B
    action_mode: str = "discrete"          # or "continuous"
    episode_seconds: float = 60.0
    rates: Rates = _default(default_factory=lambda: Rates(physics_hz=100.0, vision_period_ticks=10,
                                                          motion_period_ticks=10))
    map: MapConfig = _default(default_factory=MapConfig)
    cars: CarConfig = _default(default_factory=CarConfig)
    pedestrians: PedestrianConfig = _default(default_factory=PedestrianConfig)
    obstacles: ObstacleConfig = _default(default_factory=ObstacleConfig)
    rewards: RewardConfig = _default(default_factory=RewardConfig)

    def __post_init__(self) -> None:
        n = self.n_cars
        if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= MAX_CARS:
            raise ValueError(f"n_cars must be an integer in 1..{MAX_CARS}, got {n!r}")
        if isinstance(self.teams, bool) or self.teams not in (1, 2):
            raise ValueError(f"teams must be 1 or 2, got {self.teams!r}")
        if self.teams > n:
            raise ValueError(f"teams ({self.teams}) cannot exceed n_cars ({n})")
        if self.action_mode not in ACTION_MODES:
            raise ValueError(f"action_mode must be 'discrete' or 'continuous', got {self.action_mode!r}")
        if not isinstance(self.rates, Rates):
            raise ValueError(f"rates must be a Rates, got {self.rates!r}")
        check_numbers(self)
        self._check_positive()
        self._check_cars()
        self._check_map()
        self._check_counts()
        period = self.period_seconds
        if self.episode_seconds < period:
            raise ValueError(f"episode_seconds ({self.episode_seconds}) is shorter than one motion period ({period})")

    def _check_positive(self) -> None:
        for name in ("map.width", "map.height", "map.lane_width", "map.walkway_width", "map.goal_radius",
                     "map.spawn_spacing", "map.boundary_margin", "map.end_margin", "cars.brake_factor",
                     "cars.rolling_per_kg", "cars.finished_per_kg", "cars.finished_spin", "cars.max_yaw_rate",
                     "cars.min_turn_radius", "cars.stop_speed", "cars.drive_accel", "cars.drive_yaw_accel",
                     "pedestrians.mass", "pedestrians.radius", "pedestrians.speed_unit", "obstacles.size"):
            owner, leaf = name.split(".")
            if not getattr(getattr(self, owner), leaf) > 0:
                raise ValueError(f"{name} must be positive, got {getattr(getattr(self, owner), leaf)}")
        for name in ("vertical_lanes", "horizontal_lanes", "spawns_per_lane"):
            value = getattr(self.map, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"map.{name} must be an integer of at least 1, got {value!r}")
        if not 0.0 <= self.pedestrians.cross_probability <= 1.0:
            raise ValueError(f"pedestrians.cross_probability must be in [0, 1], got "
                             f"{self.pedestrians.cross_probability}")
        if not 0.0 <= self.rewards.blame_cos < 1.0:
            raise ValueError(f"rewards.blame_cos must be in [0, 1), got {self.rewards.blame_cos}")
        if not 0.0 <= self.cars.reverse_fraction <= 1.0:
            raise ValueError(f"cars.reverse_fraction must be in [0, 1], got {self.cars.reverse_fraction}")

    def _check_cars(self) -> None:
        c = self.cars
        n_types = len(c.masses)
        if n_types < 1:
            raise ValueError("cars.masses must list at least one car type")
        for name in ("half_widths", "half_lengths", "powers"):
            if len(getattr(c, name)) != n_types:
                raise ValueError(f"cars.{name} must have one value per car type ({n_types}, as cars.masses), "
                                 f"got {len(getattr(c, name))}")
        for name in ("masses", "half_widths", "half_lengths", "powers"):
            for i, value in enumerate(getattr(c, name)):
                if not (math.isfinite(value) and value > 0):
                    raise ValueError(f"cars.{name}[{i}] must be a positive number, got {value}")
        for i, (hw, hl) in enumerate(zip(c.half_widths, c.half_lengths)):
            if hw > hl:
                raise ValueError(f"cars.half_widths[{i}] ({hw}) exceeds cars.half_lengths[{i}] ({hl}): a car is "
                                 "longer than wide")
            if 2 * hw >= self.map.lane_width:
                raise ValueError(f"cars.half_widths[{i}] ({hw} m): the car does not fit in a "
                                 f"{self.map.lane_width} m lane")

    def _check_map(self) -> None:
        m = self.map
        hx, hy = m.building_half_size
        if not (hx > 0 and hy > 0):
            raise ValueError(f"map.building_half_size must be positive, got {m.building_half_size}")
        for name, centre, span in (("vertical_road_x", m.vertical_road_x, m.width),
                                   ("horizontal_road_y", m.horizontal_road_y, m.height)):
            if not 0 < centre < span:
                raise ValueError(f"map.{name} ({centre}) must lie inside the map (0..{span})")
        v_half = m.vertical_lanes * m.lane_width + m.walkway_width
        h_half = m.horizontal_lanes * m.lane_width + m.walkway_width
        if not (m.vertical_road_x - v_half > 0 and m.vertical_road_x + v_half < m.width):
            raise ValueError("map.vertical_road_x: the road and its walkways must fit inside the map width")
        if not (m.horizontal_road_y - h_half > 0 and m.horizontal_road_y + h_half < m.height):
            raise ValueError("map.horizontal_road_y: the road and its walkways must fit inside the map height")
        for i, (cx, cy) in enumerate(m.building_centres):
            if abs(cx - m.vertical_road_x) < hx + v_half or abs(cy - m.horizontal_road_y) < hy + h_half:
                raise ValueError(f"map.building_centres[{i}] ({cx}, {cy}): the building overlaps a road or walkway")
        # The last spawn spot (and the longest car) must stay clear of the other road's carriageway.
        reach = m.spawn_first + (m.spawns_per_lane - 1) * m.spawn_spacing + max(self.cars.half_lengths)
        v_clear = min(m.horizontal_road_y, m.height - m.horizontal_road_y) - m.horizontal_lanes * m.lane_width
        h_clear = min(m.vertical_road_x, m.width - m.vertical_road_x) - m.vertical_lanes * m.lane_width
        if reach >= min(v_clear, h_clear):
            raise ValueError(f"map.spawn_spacing / spawns_per_lane / spawn_first: spawn spots reach {reach:.1f} m "
                             f"from a road end, into the crossing ({min(v_clear, h_clear):.1f} m)")
        if m.spawn_first < max(self.cars.half_lengths):
            raise ValueError(f"map.spawn_first ({m.spawn_first} m) must be at least the longest half car length "
                             f"({max(self.cars.half_lengths)} m), so a car starts inside the map")
        if m.spawn_spacing < 2 * max(self.cars.half_lengths):
            raise ValueError(f"map.spawn_spacing ({m.spawn_spacing} m) is shorter than the longest car")
        if m.goal_radius <= m.end_margin:
            raise ValueError(f"map.goal_radius ({m.goal_radius}) must exceed map.end_margin ({m.end_margin})")
        if m.boundary_margin <= m.end_margin + max(self.cars.half_lengths):
            raise ValueError("map.boundary_margin must leave room past a road end for a car to reach its goal")
        spots = 2 * (m.vertical_lanes + m.horizontal_lanes) * m.spawns_per_lane
        if spots < self.n_cars:
            raise ValueError(f"n_cars ({self.n_cars}) exceeds the map's {spots} spawn spots")

    def _check_counts(self) -> None:
        for owner in ("pedestrians", "obstacles"):
            group = getattr(self, owner)
            for name in ("count_min", "count_max"):
                value = getattr(group, name)
                if isinstance(value, bool) or not isinstance(value, int):
                    raise ValueError(f"{owner}.{name} must be an integer, got {value!r}")
            if group.count_min > group.count_max:
                raise ValueError(f"{owner}.count_min ({group.count_min}) exceeds {owner}.count_max "
                                 f"({group.count_max})")
        p = self.pedestrians
        for low, high in (("base_speed_min", "base_speed_max"), ("cross_multiplier_min", "cross_multiplier_max"),
                          ("movement_ms_min", "movement_ms_max"), ("lateral_min", "lateral_max")):
            for name in (low, high):
                value = getattr(p, name)
                if isinstance(value, bool) or (low != "lateral_min" and not isinstance(value, int)):
                    raise ValueError(f"pedestrians.{name} must be an integer, got {value!r}")
            if getattr(p, low) > getattr(p, high):
                raise ValueError(f"pedestrians.{low} ({getattr(p, low)}) exceeds pedestrians.{high} "
                                 f"({getattr(p, high)})")
        if p.cross_multiplier_min < 1:
            raise ValueError("pedestrians.cross_multiplier_min must be at least 1: a crossing must move")
        if p.movement_ms_min < 1:
            raise ValueError("pedestrians.movement_ms_min must be at least 1 ms")
        if p.base_speed_min < 1:
            raise ValueError("pedestrians.base_speed_min must be at least 1")
        if not 2 * p.radius < self.map.walkway_width:
            raise ValueError(f"pedestrians.radius ({p.radius} m) does not fit on a {self.map.walkway_width} m "
                             "walkway")
        if p.lateral_max * self.map.lane_width + p.radius > self.map.walkway_width:
            raise ValueError("pedestrians.lateral_max: pedestrians would stand off the walkway")
        if self.obstacles.size >= self.map.walkway_width:
            raise ValueError(f"obstacles.size ({self.obstacles.size} m) does not fit on a "
                             f"{self.map.walkway_width} m walkway")

    # -- derived ------------------------------------------------------------------------------------------------
    @property
    def car_names(self) -> list[str]:
        return car_names(self.n_cars)

    @property
    def period_seconds(self) -> float:
        return self.rates.motion_period_ticks * self.rates.tick_seconds

    @property
    def episode_periods(self) -> int:
        return max(1, round(self.episode_seconds / self.period_seconds))

    @property
    def episode_ticks(self) -> int:
        return self.episode_periods * self.rates.motion_period_ticks

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any] | None = None) -> "DrivingConfig":
        """Build from nested plain values (YAML, keyword arguments); unknown keys are refused by name."""
        values = dict(values or {})
        if "rates" in values and isinstance(values["rates"], Mapping):
            try:
                values["rates"] = Rates(**dict(values["rates"]))
            except TypeError as exc:
                raise ValueError(f"rates: {exc}") from None
        return build_settings(cls, values, "driving")


def _sequence(name: str, value: Any) -> tuple:
    if isinstance(value, (str, bytes, Mapping)) or not hasattr(value, "__iter__"):
        raise ValueError(f"{name} must be a list, got {value!r}")
    return tuple(value)


def _float_tuple(name: str, value: Any, length: int | None = None) -> tuple[float, ...]:
    items = _sequence(name, value)
    if length is not None and len(items) != length:
        raise ValueError(f"{name} must hold {length} numbers, got {len(items)}")
    for item in items:
        if isinstance(item, bool) or not isinstance(item, (int, float)) or not math.isfinite(item):
            raise ValueError(f"{name} must hold finite numbers, got {item!r}")
    return tuple(float(v) for v in items)


__all__ = ["DrivingConfig", "MapConfig", "CarConfig", "PedestrianConfig", "ObstacleConfig", "RewardConfig",
           "MAX_CARS", "PX", "SCENARIO_DRIVING", "ACTION_MODES", "car_names", "is_driving_world"]
