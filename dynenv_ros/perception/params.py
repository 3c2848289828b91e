"""The perception error model's parameters: named, documented, loaded from YAML presets (docs/perception.md).

Probabilities are *per unit of noise magnitude*: the model multiplies them by ``noise_magnitude`` (0–5), so one knob
scales every failure at once, as in DynEnv. Distances are metres, angles radians.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any, Callable, Mapping, TypeVar

import yaml

from dynenv_ros.core.object_classes import ObjectClass
from dynenv_ros.core.settings import check_numbers

MODES = ("realistic", "random", "none")
CONFIDENCE_MODELS = ("calibrated", "none")
OCCLUSION_MODELS = ("cone", "band")
PRESETS = ("realistic", "dynenv", "none")
LOCALIZATION_MODES = ("emulated", "none")
T = TypeVar("T")
CLASS_NAMES = {"ball": ObjectClass.BALL, "robot": ObjectClass.ROBOT, "goalpost": ObjectClass.GOALPOST,
               "penalty_cross": ObjectClass.PENALTY_CROSS, "line_crossing": ObjectClass.LINE_CROSSING,
               "field_line": ObjectClass.FIELD_LINE, "center_circle": ObjectClass.CENTER_CIRCLE,
               "none": ObjectClass.UNKNOWN}


@dataclass(frozen=True)
class ClassParams:
    """How far one class can be seen, and how reliably."""
    near_range: float          # beyond this the sighting is DISTANT (and, realistic, less reliable)
    max_range: float           # beyond this nothing is detected (inf: no cut-off, as in DynEnv)
    miss_scale: float = 1.0    # multiplies the base miss probability for this class
    visibility_radius: float = 0.05   # how far the object reaches out of the field of view to be partially seen
    correct_prior: float = 0.9        # calibrated confidence: the share of this class's reports that are correct


@dataclass(frozen=True)
class MissParams:
    """P(miss) = base · magnitude · miss_scale · multiplier; realistic multiplier = (offset + slope·(d/near)²) ×
    the factor of the sighting (partial beats distant beats nearby); random mode uses multiplier 1."""
    base: float = 0.01
    range_offset: float = 0.25
    range_slope: float = 3.75
    nearby_factor: float = 2.0
    distant_factor: float = 3.0
    partial_factor: float = 4.0
    nearby_distance: float = 0.35      # another object this close (centre to centre) makes a sighting NEARBY


@dataclass(frozen=True)
class PositionParams:
    """Where a detection lands. 'uniform' (DynEnv): each axis ± 0.5·magnitude·uniform_scale·multiplier (random
    mode: multiplier 4). 'polar' (realistic): radial σ = magnitude·(radial_base + radial_per_m2·d²) — a ground
    projection's error grows with the square of the distance — and bearing σ = magnitude·bearing_std."""
    model: str = "polar"
    uniform_scale: float = 0.0025
    radial_base: float = 0.01
    radial_per_m2: float = 0.0175
    bearing_std: float = 0.0175
    random_std: float = 0.05           # random mode with the polar model: σ per axis, independent of distance
    size_std: float = 0.05             # relative size error σ per unit magnitude
    yaw_std: float = 0.1               # robots' heading σ per unit magnitude, rad


@dataclass(frozen=True)
class Confusion:
    """A ``source`` detection is reported as ``target`` with P = probability · base · magnitude · multiplier."""
    source: ObjectClass
    target: ObjectClass
    probability: float
    distant_only: bool = False


@dataclass(frozen=True)
class FalsePositiveParams:
    trials: int = 10                   # per frame, each firing with P = probability · magnitude
    probability: float = 0.01
    classes: tuple[ObjectClass, ...] = (ObjectClass.BALL, ObjectClass.ROBOT, ObjectClass.GOALPOST,
                                        ObjectClass.PENALTY_CROSS, ObjectClass.LINE_CROSSING, ObjectClass.UNKNOWN)
    max_distance: float = 8.32         # placed uniformly in distance up to this, uniformly in bearing in the view
    at_feet_probability: float = 0.1   # realistic: per robot seen closer than at_feet_range, P(ball at its feet)
    at_feet_range: float = 2.5
    at_feet_spread: float = 0.175
    at_feet_robot_dropped: float = 0.08  # nested: P(the robot itself is not reported), per unit magnitude


@dataclass(frozen=True)
class OcclusionParams:
    """What a robot hides. ``cone`` (realistic): whatever lies behind it within its angular half-width
    asin(occluder_radius / its distance), the shadow of a body of that radius. ``band`` (DynEnv, docs/original.md §2.7):
    whatever lies behind it within ``occluder_radius`` of the line of sight through it, and only robots in the field
    of view occlude."""
    enabled: bool = True
    occluder_radius: float = 0.15
    model: str = "cone"


@dataclass(frozen=True)
class LocalizationParams:
    """The emulated self-localization (``perception/localization.py``; docs/perception.md, "Self-localization").
    Absolute values, not scaled by ``noise_magnitude``. σ (standard deviations) in metres and radians; the
    odometry terms are the σ reached after one unit walked / turned / waited without landmarks (the variance grows
    linearly: a random walk, so the numbers do not depend on the frame rate)."""
    mode: str = "emulated"             # 'emulated' | 'none' (the true pose, zero covariance)
    odometry_xy_per_m: float = 0.1     # position σ after walking 1 m (variance + this² per metre walked)
    odometry_yaw_per_rad: float = 0.1  # heading σ after turning 1 rad
    odometry_yaw_per_m: float = 0.05   # heading σ after walking 1 m
    drift_xy_per_s: float = 0.01       # floor: position σ after 1 s, walking or not (stepping on the spot, sway)
    drift_yaw_per_s: float = 0.01      # floor: heading σ after 1 s
    landmark_xy_std: float = 0.2       # one landmark sighting's evidence on the position, σ per axis
    landmark_yaw_std: float = 0.1      # ... on the heading
    landmark_cap: int = 4              # sightings of one frame beyond this add nothing (they share one camera pose)
    fall_xy_std: float = 0.5           # a fall adds this σ per position axis ...
    fall_yaw_std: float = 0.5          # ... and this to the heading
    lost_xy_std: float = 0.3           # position σ (either axis) above this: lost; the next sighting re-localizes
    flip_probability: float = 0.05     # P(re-localizing onto the mirror pose) without an asymmetric cue
    flip_probability_cue: float = 0.005  # the same with a cue (kickoff placement or penalty re-entry)
    cue_seconds: float = 30.0          # a kickoff or re-entry is a cue for this long
    placement_xy_std: float = 0.05     # kickoff / episode start: the estimate's error at a known spot
    placement_yaw_std: float = 0.05
    touchline_along_std: float = 1.0   # penalty re-entry: σ along the touchline (where along the own half)
    touchline_across_std: float = 0.1  # ... across it
    touchline_yaw_std: float = 0.1     # ... heading (placed facing into the field)

    def __post_init__(self) -> None:
        if self.mode not in LOCALIZATION_MODES:
            raise ValueError(f"localization.mode must be one of {LOCALIZATION_MODES}, got {self.mode!r}")
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name != "mode" and (isinstance(value, bool) or not isinstance(value, (int, float))):
                raise ValueError(f"localization.{f.name} must be a number, got {value!r}")
        check_numbers(self, "localization.")
        if not isinstance(self.landmark_cap, int) or self.landmark_cap < 1:
            raise ValueError(f"localization.landmark_cap must be a whole number >= 1, got {self.landmark_cap!r}")
        for name in ("flip_probability", "flip_probability_cue"):
            if getattr(self, name) > 1:
                raise ValueError(f"localization.{name} must be a probability in [0, 1], got {getattr(self, name)}")
        if self.flip_probability_cue > self.flip_probability:
            raise ValueError("localization.flip_probability_cue must not exceed flip_probability (a cue makes the "
                             f"mirror less likely), got {self.flip_probability_cue} > {self.flip_probability}")
        if self.landmark_xy_std <= 0 or self.landmark_yaw_std <= 0:
            raise ValueError("localization.landmark_xy_std and landmark_yaw_std must be positive (a sighting's "
                             f"evidence is never exact), got {self.landmark_xy_std}, {self.landmark_yaw_std}")


@dataclass(frozen=True)
class PerceptionParams:
    mode: str = "realistic"
    noise_magnitude: float = 1.0
    field_of_view: float = math.pi / 2
    # 'calibrated': a detector score, P(correct | score) under each class's correct_prior (docs/perception.md);
    # 'none': always 1 (DynEnv reports no confidence)
    confidence: str = "calibrated"
    confidence_separation: float = 1.5   # d': correct reports' evidence ~ N(d', 1), false ones' ~ N(0, 1)
    classes: Mapping[ObjectClass, ClassParams] = field(default_factory=dict)
    miss: MissParams = field(default_factory=MissParams)
    position: PositionParams = field(default_factory=PositionParams)
    confusions: tuple[Confusion, ...] = ()
    false_positives: FalsePositiveParams = field(default_factory=FalsePositiveParams)
    occlusion: OcclusionParams = field(default_factory=OcclusionParams)
    localization: LocalizationParams = field(default_factory=LocalizationParams)

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ValueError(f"perception mode must be one of {MODES}, got {self.mode!r}")
        m = self.noise_magnitude
        if isinstance(m, bool) or not isinstance(m, (int, float)) or not 0.0 <= m <= 5.0:
            raise ValueError(f"noise_magnitude must be a number in [0, 5], got {m!r}")
        if not 0.0 < self.field_of_view < math.pi:
            raise ValueError(f"field_of_view must be in (0, pi) rad, got {self.field_of_view}")
        if self.confidence not in CONFIDENCE_MODELS:
            raise ValueError(f"confidence must be one of {CONFIDENCE_MODELS}, got {self.confidence!r}")
        if self.occlusion.model not in OCCLUSION_MODELS:
            raise ValueError(f"occlusion.model must be one of {OCCLUSION_MODELS}, got {self.occlusion.model!r}")
        if self.position.model not in ("uniform", "polar"):
            raise ValueError(f"position.model must be 'uniform' or 'polar', got {self.position.model!r}")
        missing = [name for name, cls in CLASS_NAMES.items() if cls != ObjectClass.UNKNOWN and cls not in self.classes]
        if missing:
            raise ValueError(f"classes: no settings for {', '.join(missing)}")
        for cls, p in self.classes.items():
            numbers = (p.near_range, p.max_range, p.miss_scale, p.visibility_radius, p.correct_prior)
            if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in numbers) or not (
                    p.near_range > 0 and p.max_range > 0 and p.miss_scale >= 0 and p.visibility_radius >= 0
                    and 0 < p.correct_prior < 1):
                raise ValueError(f"classes.{ObjectClass(cls).name.lower()}: ranges must be positive, "
                                 "miss_scale and visibility_radius non-negative, correct_prior in (0, 1)")
        check_numbers(self, infinite_ok=("max_range",))

    @property
    def rho(self) -> float:
        """DynEnv's ``randBase``: the base probability scaled by the noise magnitude."""
        return self.miss.base * self.noise_magnitude

    def with_noise(self, magnitude: float | None = None, mode: str | None = None) -> "PerceptionParams":
        return replace(self, noise_magnitude=self.noise_magnitude if magnitude is None else magnitude,
                       mode=self.mode if mode is None else mode)


def preset_dir() -> Path:
    """``config/perception`` of the source tree, else of an installed share directory (colcon or pip)."""
    import os
    import sys
    candidates = [Path(__file__).resolve().parents[2] / "config" / "perception"]
    prefixes = [p for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p] + [sys.prefix]
    candidates += [Path(p) / "share" / "dynenv_ros" / "config" / "perception" for p in prefixes]
    for candidate in candidates:
        if candidate.is_dir():
            return candidate
    raise FileNotFoundError("perception presets not found in: " + ", ".join(str(c) for c in candidates))


def load_preset(name: str, **overrides: Any) -> PerceptionParams:
    """A named preset from ``config/perception/<name>.yaml``; keyword overrides replace top-level settings."""
    if name not in PRESETS:
        raise ValueError(f"unknown perception preset {name!r}; presets: {', '.join(PRESETS)}")
    return load_yaml(preset_dir() / f"{name}.yaml", **overrides)


def resolve_setting(setting: Any, params_cls: type[T], load: Callable[..., T], expected: str) -> T:
    """Perception parameters from what a user passes an env: ready ``params_cls``, a preset name, or a mapping
    ``{"preset": name, **overrides}`` (preset ``realistic`` when left out). ``expected`` names them for the error."""
    if isinstance(setting, params_cls):
        return setting
    if isinstance(setting, str):
        return load(setting)
    if isinstance(setting, Mapping):
        values = dict(setting)
        return load(values.pop("preset", "realistic"), **values)
    raise ValueError(f"perception must be {expected}, got {setting!r}")


def load_section_yaml(path: str | Path, key: str, what: str, parse: Callable[[Mapping[str, Any]], T],
                      overrides: Mapping[str, Any]) -> T:
    """``parse`` of the top-level ``key`` mapping of a YAML file, ``overrides`` replacing its settings; every error a
    ValueError naming the file. Shared by the soccer and driving perception presets (``what`` names which)."""
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise ValueError(f"cannot read {what} parameters from {path}: {exc}") from None
    if not isinstance(data, dict) or key not in data:
        raise ValueError(f"{path}: expected a mapping with a top-level '{key}' key")
    values = dict(data[key])
    values.update(overrides)
    try:
        return parse(values)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None


def load_yaml(path: str | Path, **overrides: Any) -> PerceptionParams:
    return load_section_yaml(path, "perception", "perception", from_mapping, overrides)


def parse_class(name: Any, where: str, allowed: Mapping[str, ObjectClass] = CLASS_NAMES) -> ObjectClass:
    """The class a settings file names (``allowed``: name → class, soccer's by default); else ValueError naming
    ``where`` and the known names. Shared with the driving perception's settings."""
    if name not in allowed:
        raise ValueError(f"{where}: unknown class {name!r}; classes: {', '.join(allowed)}")
    return allowed[name]


def parse_section(cls: type, values: Any, where: str) -> Any:
    """A settings dataclass from a mapping; unknown keys or a bad value raise ValueError naming ``where``."""
    if not isinstance(values, Mapping):
        raise ValueError(f"{where} must be a mapping, got {values!r}")
    known = {f.name for f in fields(cls)}
    unknown = sorted(set(values) - known)
    if unknown:
        raise ValueError(f"{where}: unknown setting(s) {unknown}; known: {sorted(known)}")
    try:
        return cls(**values)
    except TypeError as exc:
        raise ValueError(f"{where}: {exc}") from None


def top_level_settings(values: Mapping[str, Any], params_cls: type, what: str,
                       number_keys: tuple[str, ...]) -> dict[str, Any]:
    """The plain top-level settings (``mode``, ``confidence`` and the numbers ``number_keys``) as keyword arguments of
    ``params_cls``, after refusing unknown keys by name. Shared by the soccer and driving perception settings."""
    known = {f.name for f in fields(params_cls)}
    unknown = sorted(set(values) - known)
    if unknown:
        raise ValueError(f"unknown {what} setting(s) {unknown}; known: {sorted(known)}")
    kwargs: dict[str, Any] = {}
    for key in ("mode", "confidence"):
        if key in values:
            kwargs[key] = values[key]
    for key in number_keys:
        if key in values:
            if isinstance(values[key], bool) or not isinstance(values[key], (int, float)):
                raise ValueError(f"{key} must be a number, got {values[key]!r}")
            kwargs[key] = float(values[key])
    return kwargs


def parse_class_sections(values: Any, cls: type, allowed: Mapping[str, ObjectClass]) -> dict[ObjectClass, Any]:
    """The ``classes`` setting: class name → its ``cls`` settings, keyed by class."""
    if not isinstance(values, Mapping):
        raise ValueError("classes must map class names to their settings")
    return {parse_class(name, "classes", allowed): parse_section(cls, v, f"classes.{name}")
            for name, v in values.items()}


def parse_confusions(values: Any, cls: type, allowed: Mapping[str, ObjectClass]) -> tuple[Any, ...]:
    """The ``confusions`` setting: a list of ``cls`` rules whose ``source`` and ``target`` name classes."""
    rules = []
    for i, rule in enumerate(values or ()):
        where = f"confusions[{i}]"
        rule = dict(rule)
        for key in ("source", "target"):
            rule[key] = parse_class(rule.get(key), f"{where}.{key}", allowed)
        rules.append(parse_section(cls, rule, where))
    return tuple(rules)


def from_mapping(values: Mapping[str, Any]) -> PerceptionParams:
    """Parameters from plain values (a preset's ``perception`` mapping); unknown keys are refused by name."""
    values = dict(values)
    kwargs = top_level_settings(values, PerceptionParams, "perception",
                                ("noise_magnitude", "field_of_view", "confidence_separation"))
    if "classes" in values:
        kwargs["classes"] = parse_class_sections(values["classes"], ClassParams, CLASS_NAMES)
    for key, cls in (("miss", MissParams), ("position", PositionParams), ("occlusion", OcclusionParams),
                     ("localization", LocalizationParams)):
        if key in values:
            kwargs[key] = parse_section(cls, values[key], key)
    if "false_positives" in values:
        fp = dict(values["false_positives"] or {})
        if "classes" in fp:
            fp["classes"] = tuple(parse_class(c, "false_positives.classes") for c in fp["classes"])
        kwargs["false_positives"] = parse_section(FalsePositiveParams, fp, "false_positives")
    if "confusions" in values:
        kwargs["confusions"] = parse_confusions(values["confusions"], Confusion, CLASS_NAMES)
    return PerceptionParams(**kwargs)
