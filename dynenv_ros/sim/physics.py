"""A top-down pymunk world stepped at a fixed tick, and the drive that moves bodies from high-level commands.

Scenarios (soccer, driving) build their bodies in one ``PhysicsWorld`` and react to contacts through pymunk
collision callbacks; nothing here knows a scenario. Per tick the only Python work is stepping the space (one call
of chipmunk's ``cpSpaceStep``, see ``PhysicsWorld.step``): everything else happens in callbacks when something
touches, or between vision frames.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import pymunk
from pymunk._chipmunk import lib as _chipmunk  # type: ignore[import-not-found]  # cffi, no stubs

# ``PhysicsWorld.step`` calls chipmunk's step itself and does ``Space.step``'s bookkeeping only on the ticks that
# need it (≈ 0.5 µs of Python saved per tick, 50 ticks a soccer period). That bookkeeping is pymunk's, read from
# its private attributes, so the fast path is taken only with the pymunk it was written against (the pinned
# version, requirements.lock); any other version steps through ``Space.step``.
_FAST_STEP_PYMUNK = ("7.3.1",)


class PhysicsWorld:
    """A gravity-free space and its fixed time step."""

    def __init__(self, tick_seconds: float) -> None:
        if not (math.isfinite(tick_seconds) and tick_seconds > 0):
            raise ValueError(f"tick_seconds must be positive, got {tick_seconds}")
        self.space = pymunk.Space()
        self.space.gravity = (0.0, 0.0)
        self.tick_seconds = tick_seconds
        self.fast_step = pymunk.version in _FAST_STEP_PYMUNK

    def step(self, ticks: int) -> None:
        """``ticks`` times ``Space.step(tick_seconds)``: the same chipmunk calls and, after each, the same
        bookkeeping (objects added or removed while the space was locked, post-step callbacks) whenever there is
        any, so every tick ends as ``Space.step``'s does."""
        space, dt = self.space, self.tick_seconds
        if not self.fast_step or space.threaded:
            step = space.step
            for _ in range(ticks):
                step(dt)
            return
        cp_step, handle = _chipmunk.cpSpaceStep, space._space
        for _ in range(ticks):
            if space._bodies_to_check:          # a body added since the last tick: pymunk checks its mass first
                space.step(dt)
                continue
            space._locked = True
            try:
                cp_step(handle, dt)
            finally:
                space._locked = False
            if space._removed_shapes or space._add_later or space._remove_later or space._post_step_callbacks:
                self._after_tick(space)

    @staticmethod
    def _after_tick(space: pymunk.Space) -> None:
        """What ``Space.step`` (pymunk 7.3.1) does after chipmunk's step, in its order."""
        space._removed_shapes.clear()
        space.add(*space._add_later)
        space._add_later.clear()
        removed = set()
        while space._remove_later:
            to_remove, _ = space._remove_later.popitem()
            if to_remove not in removed:
                removed.add(to_remove)
                space._remove(to_remove)
        for key in space._post_step_callbacks:
            space._post_step_callbacks[key](space)
        space._post_step_callbacks.clear()

    def add_floor_friction(self, body: pymunk.Body, deceleration: float, angular_deceleration: float) -> None:
        """Constant (Coulomb) rolling/sliding friction against the floor, solved in C like any joint.

        A pivot and a gear joint to the static body with zero bias and a capped force give exactly the
        deceleration ``force / mass``, so a ball stops after v²/2a instead of decaying forever.
        """
        floor = self.space.static_body
        linear = pymunk.PivotJoint(floor, body, (0.0, 0.0), (0.0, 0.0))
        linear.max_bias = 0.0
        linear.max_force = deceleration * body.mass
        angular = pymunk.GearJoint(floor, body, 0.0, 1.0)
        angular.max_bias = 0.0
        angular.max_force = angular_deceleration * body.moment
        self.space.add(linear, angular)


@dataclass
class Drive:
    """Moves a dynamic body with a kinematic control body (pymunk's top-down pattern), not by setting its state.

    The body follows the commanded velocity through two joints with capped force, so collisions still push it and
    the solver never fights a teleport.
    """
    control: pymunk.Body
    body: pymunk.Body
    pivot: pymunk.PivotJoint
    gear: pymunk.GearJoint

    @classmethod
    def attach(cls, space: pymunk.Space, body: pymunk.Body, max_force: float, max_torque: float) -> "Drive":
        control = pymunk.Body(body_type=pymunk.Body.KINEMATIC)
        control.position = body.position
        control.angle = body.angle
        pivot = pymunk.PivotJoint(control, body, (0.0, 0.0), (0.0, 0.0))
        pivot.max_bias = 0.0
        pivot.max_force = max_force
        gear = pymunk.GearJoint(control, body, 0.0, 1.0)
        gear.max_bias = 0.0
        gear.max_force = max_torque
        space.add(control, pivot, gear)
        return cls(control, body, pivot, gear)

    def command(self, vx: float, vy: float, yaw_rate: float) -> None:
        """World-frame velocity (m/s) and yaw rate (rad/s) to hold until the next command."""
        self.control.velocity = (vx, vy)
        self.control.angular_velocity = yaw_rate

    def stop(self) -> None:
        self.command(0.0, 0.0, 0.0)
        self.body.velocity = (0.0, 0.0)
        self.body.angular_velocity = 0.0

    def place(self, x: float, y: float, yaw: float) -> None:
        """Teleport (between ticks only): body and control body together, at rest."""
        for b in (self.body, self.control):
            b.position = (x, y)
            b.angle = yaw
        self.stop()
        if self.body.space is not None:
            self.body.space.reindex_shapes_for_body(self.body)
