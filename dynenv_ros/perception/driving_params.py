"""The driving perception model's parameters: named, documented, loaded from YAML presets (docs/perception.md,
"Driving").

A car's sensors see 360° around it up to ``view_range`` (the original's radius of 680 px = 68 m); each class has its
own reliable (``near_range``) and maximum range. Probabilities are per unit of noise magnitude (0–5), as for soccer:
ρ = ``miss.base`` · ``noise_magnitude`` scales every failure at once. Distances are metres, angles radians.
Presets: ``config/perception/driving_<name>.yaml`` with a top-level ``driving_perception`` key.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from dynenv_ros.core.object_classes import ObjectClass
from dynenv_ros.core.settings import check_numbers
from dynenv_ros.perception.params import (load_section_yaml, parse_class, parse_class_sections, parse_confusions,
                                          parse_section, preset_dir, top_level_settings)

MODES = ("realistic", "random", "none")
CONFIDENCE_MODELS = ("calibrated", "none")
POSITION_MODELS = ("uniform", "polar")
DRIVING_PRESETS = ("realistic", "dynenv", "none")
CLASS_NAMES = {"car": ObjectClass.CAR, "pedestrian": ObjectClass.PEDESTRIAN, "obstacle": ObjectClass.OBSTACLE,
               "lane": ObjectClass.LANE, "none": ObjectClass.UNKNOWN}
POINT_CLASSES = (ObjectClass.CAR, ObjectClass.PEDESTRIAN, ObjectClass.OBSTACLE)
OCCLUDABLE = {"car": ObjectClass.CAR, "pedestrian": ObjectClass.PEDESTRIAN, "obstacle": ObjectClass.OBSTACLE}


@dataclass(frozen=True)
class DrivingClassParams:
    near_range: float               # beyond this a report is DISTANT (and, realistic, less reliable)
    max_range: float                # beyond this nothing of the class is detected (at most view_range)
    miss_scale: float = 1.0         # multiplies the base miss probability for this class
    correct_prior: float = 0.95     # calibrated confidence: the share of this class's reports that are correct


@dataclass(frozen=True)
class DrivingMissParams:
    """P(miss) = base · magnitude · miss_scale · multiplier; realistic multiplier = (offset + slope·(d/reference)²)
    × 4 if PARTIAL (partly hidden), else 3 if DISTANT, else 2 if NEARBY, else 1; random mode: multiplier 1."""
    base: float = 0.01
    range_offset: float = 0.25
    range_slope: float = 3.75
    range_reference: float = 68.0   # the original's maxVisDist radius (680 px)
    nearby_factor: float = 2.0
    distant_factor: float = 3.0
    partial_factor: float = 4.0
    nearby_distance: float = 2.0    # a pedestrian this close (centre to centre) to a car or obstacle is NEARBY


@dataclass(frozen=True)
class DrivingPositionParams:
    """Where a report lands, in the observer's frame. ``uniform`` (the original): each axis
    ± 0.5·magnitude·uniform_scale·multiplier (random mode: multiplier 1), heading ± 0.5·magnitude·yaw_std.
    ``polar``: radial σ = magnitude·(radial_base + radial_per_m2·d²), bearing σ = magnitude·bearing_std (random
    mode: σ = magnitude·random_std per axis), heading σ = magnitude·yaw_std. Sizes: relative σ = magnitude·size_std."""
    model: str = "polar"
    uniform_scale: float = 0.1
    radial_base: float = 0.05
    radial_per_m2: float = 0.0002
    bearing_std: float = 0.0087
    random_std: float = 0.1
    size_std: float = 0.05
    yaw_std: float = 0.05


@dataclass(frozen=True)
class DrivingLaneParams:
    """Lane noise: the visible lane segment is shifted sideways and turned about its point nearest the car.
    ``uniform`` (the original): shift ± 0.5·magnitude·lateral_uniform·mult, turn ± 0.5·magnitude·angle_uniform·mult
    with mult = offset + slope·(d/reference)² of the nearest point's distance d (random mode: mult 1);
    ``gaussian``: shift σ = magnitude·(lateral_base + lateral_per_m2·d²), turn σ = magnitude·angle_std. A lane is
    missed with P = ρ·miss_scale·mult (random mode: ρ·miss_scale)."""
    model: str = "gaussian"
    lateral_uniform: float = 1.0
    angle_uniform: float = 0.0034906585    # (π/180)/5 rad, the original
    lateral_base: float = 0.05
    lateral_per_m2: float = 0.0001
    angle_std: float = 0.01
    min_length: float = 1.0                 # m of a lane that must be within range to report it


@dataclass(frozen=True)
class DrivingConfusion:
    """A ``source`` report is given as ``target`` with P = probability · ρ · multiplier (optionally DISTANT only)."""
    source: ObjectClass
    target: ObjectClass
    probability: float
    distant_only: bool = False


@dataclass(frozen=True)
class DrivingFalsePositiveParams:
    trials: int = 10                     # per view, each firing with P = probability · magnitude
    probability: float = 0.01
    classes: tuple[ObjectClass, ...] = (ObjectClass.CAR, ObjectClass.OBSTACLE, ObjectClass.PEDESTRIAN,
                                        ObjectClass.UNKNOWN, ObjectClass.UNKNOWN, ObjectClass.UNKNOWN)
    max_distance: float = 68.0           # uniform in distance up to this (and the class's max_range), bearing 360°
    near_car_probability: float = 0.1    # realistic: per car seen (not DISTANT/PARTIAL) within near_car_range
    near_car_range: float = 25.0
    near_car_spread: float = 1.0         # m beyond the car's outline (plus a pedestrian's radius)


@dataclass(frozen=True)
class DrivingOcclusionParams:
    """Buildings hide every class; cars and obstacles hide the classes listed (the original: pedestrians only).
    Each object is tested along three sight lines (its centre and both edges of its outline): hidden when all three
    are blocked, PARTIAL when one or two are."""
    enabled: bool = True
    cars_hide: tuple[ObjectClass, ...] = (ObjectClass.PEDESTRIAN,)
    obstacles_hide: tuple[ObjectClass, ...] = (ObjectClass.PEDESTRIAN,)


@dataclass(frozen=True)
class DrivingSelfParams:
    """The observer's own row (SELF): odometry and navigation errors, Gaussian σ per unit magnitude."""
    speed_std: float = 0.05              # m/s
    yaw_rate_std: float = 0.005          # rad/s
    goal_std: float = 0.5                # m per axis of the destination's offset (localisation)


@dataclass(frozen=True)
class DrivingPerceptionParams:
    mode: str = "realistic"
    noise_magnitude: float = 1.0
    view_range: float = 68.0
    confidence: str = "calibrated"
    confidence_separation: float = 1.5
    classes: Mapping[ObjectClass, DrivingClassParams] = field(default_factory=dict)
    miss: DrivingMissParams = field(default_factory=DrivingMissParams)
    position: DrivingPositionParams = field(default_factory=DrivingPositionParams)
    lanes: DrivingLaneParams = field(default_factory=DrivingLaneParams)
    confusions: tuple[DrivingConfusion, ...] = ()
    false_positives: DrivingFalsePositiveParams = field(default_factory=DrivingFalsePositiveParams)
    occlusion: DrivingOcclusionParams = field(default_factory=DrivingOcclusionParams)
    self_state: DrivingSelfParams = field(default_factory=DrivingSelfParams)

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {self.mode!r}")
        m = self.noise_magnitude
        if isinstance(m, bool) or not isinstance(m, (int, float)) or not 0.0 <= m <= 5.0:
            raise ValueError(f"noise_magnitude must be a number in [0, 5], got {m!r}")
        if not (isinstance(self.view_range, (int, float)) and 0.0 < self.view_range < math.inf):
            raise ValueError(f"view_range must be a positive finite distance in m, got {self.view_range!r}")
        if self.confidence not in CONFIDENCE_MODELS:
            raise ValueError(f"confidence must be one of {CONFIDENCE_MODELS}, got {self.confidence!r}")
        if self.position.model not in POSITION_MODELS:
            raise ValueError(f"position.model must be one of {POSITION_MODELS}, got {self.position.model!r}")
        if self.lanes.model not in ("uniform", "gaussian"):
            raise ValueError(f"lanes.model must be 'uniform' or 'gaussian', got {self.lanes.model!r}")
        missing = [name for name, cls in CLASS_NAMES.items() if cls != ObjectClass.UNKNOWN and cls not in self.classes]
        if missing:
            raise ValueError(f"classes: no settings for {', '.join(missing)}")
        for cls, p in self.classes.items():
            name = ObjectClass(cls).name.lower()
            numbers = (p.near_range, p.max_range, p.miss_scale, p.correct_prior)
            if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in numbers):
                raise ValueError(f"classes.{name}: settings must be numbers, got {p}")
            if not (p.near_range > 0 and 0 < p.max_range <= self.view_range and p.miss_scale >= 0
                    and 0 < p.correct_prior < 1):
                raise ValueError(f"classes.{name}: near_range must be positive, max_range in (0, view_range = "
                                 f"{self.view_range}], miss_scale non-negative, correct_prior in (0, 1)")
        for i, rule in enumerate(self.confusions):
            if rule.source not in POINT_CLASSES or rule.target not in POINT_CLASSES or rule.source == rule.target:
                raise ValueError(f"confusions[{i}]: source and target must be two different classes of car, "
                                 "pedestrian, obstacle")
            if isinstance(rule.probability, bool) or not isinstance(rule.probability, (int, float)) or not (
                    0.0 <= rule.probability <= 1.0 / max(self.miss.base, 1e-12)):
                raise ValueError(f"confusions[{i}].probability must be a non-negative number, got {rule.probability!r}")
        sources = [rule.source for rule in self.confusions]
        if len(set(sources)) != len(sources):
            raise ValueError("confusions: at most one rule per source class")
        fp = self.false_positives
        if isinstance(fp.trials, bool) or not isinstance(fp.trials, int):
            raise ValueError(f"false_positives.trials must be an integer, got {fp.trials!r}")
        if not fp.classes or any(c not in POINT_CLASSES + (ObjectClass.UNKNOWN,) for c in fp.classes):
            raise ValueError("false_positives.classes: a non-empty list of car, pedestrian, obstacle, none")
        for key in ("cars_hide", "obstacles_hide"):
            if any(c not in POINT_CLASSES for c in getattr(self.occlusion, key)):
                raise ValueError(f"occlusion.{key}: a list of car, pedestrian, obstacle")
        for name, value in (("miss.base", self.miss.base), ("false_positives.probability", fp.probability),
                            ("false_positives.near_car_probability", fp.near_car_probability)):
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"{name} is a probability per unit magnitude: must be in [0, 1], got {value}")
        if self.miss.range_reference <= 0:
            raise ValueError(f"miss.range_reference must be positive, got {self.miss.range_reference}")
        check_numbers(self)

    @property
    def rho(self) -> float:
        """The original's ``randBase``: the base probability scaled by the noise magnitude."""
        return self.miss.base * self.noise_magnitude


def _class_list(values: Any, where: str, allowed: Mapping[str, ObjectClass] = CLASS_NAMES) -> tuple[ObjectClass, ...]:
    if not isinstance(values, (list, tuple)):
        raise ValueError(f"{where} must be a list of class names, got {values!r}")
    return tuple(parse_class(c, where, allowed) for c in values)


def driving_params_from_mapping(values: Mapping[str, Any]) -> DrivingPerceptionParams:
    """Parameters from plain values (a preset's ``driving_perception`` mapping); unknown keys refused by name."""
    if not isinstance(values, Mapping):
        raise ValueError(f"driving perception settings must be a mapping, got {values!r}")
    values = dict(values)
    kwargs = top_level_settings(values, DrivingPerceptionParams, "driving perception",
                                ("noise_magnitude", "view_range", "confidence_separation"))
    if "classes" in values:
        kwargs["classes"] = parse_class_sections(values["classes"], DrivingClassParams, CLASS_NAMES)
    for key, cls in (("miss", DrivingMissParams), ("position", DrivingPositionParams), ("lanes", DrivingLaneParams),
                     ("self_state", DrivingSelfParams)):
        if key in values:
            kwargs[key] = parse_section(cls, values[key], key)
    if "occlusion" in values:
        occ = dict(values["occlusion"] or {})
        for key in ("cars_hide", "obstacles_hide"):
            if key in occ:
                occ[key] = _class_list(occ[key], f"occlusion.{key}", OCCLUDABLE)
        kwargs["occlusion"] = parse_section(DrivingOcclusionParams, occ, "occlusion")
    if "false_positives" in values:
        fp = dict(values["false_positives"] or {})
        if "classes" in fp:
            fp["classes"] = _class_list(fp["classes"], "false_positives.classes")
        kwargs["false_positives"] = parse_section(DrivingFalsePositiveParams, fp, "false_positives")
    if "confusions" in values:
        kwargs["confusions"] = parse_confusions(values["confusions"], DrivingConfusion, CLASS_NAMES)
    return DrivingPerceptionParams(**kwargs)


def load_driving_yaml(path: str | Path, **overrides: Any) -> DrivingPerceptionParams:
    return load_section_yaml(path, "driving_perception", "driving perception", driving_params_from_mapping, overrides)


def load_driving_preset(name: str, **overrides: Any) -> DrivingPerceptionParams:
    """``config/perception/driving_<name>.yaml``; keyword overrides replace top-level settings
    (e.g. ``noise_magnitude=3``, ``mode="random"``)."""
    if name not in DRIVING_PRESETS:
        raise ValueError(f"unknown driving perception preset {name!r}; presets: {', '.join(DRIVING_PRESETS)}")
    return load_driving_yaml(preset_dir() / f"driving_{name}.yaml", **overrides)


__all__ = ["DrivingPerceptionParams", "DrivingClassParams", "DrivingMissParams", "DrivingPositionParams",
           "DrivingLaneParams", "DrivingConfusion", "DrivingFalsePositiveParams", "DrivingOcclusionParams",
           "DrivingSelfParams", "DRIVING_PRESETS", "driving_params_from_mapping", "load_driving_yaml",
           "load_driving_preset"]
