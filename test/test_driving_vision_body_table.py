"""The driving world's state read in one pymunk batch call equals reading every body through its properties, as
cars leave at their destinations and pedestrians are hit (vision.BodyTable, vision.driving_state)."""
import math

import numpy as np

from dynenv_ros.driving.config import DrivingConfig
from dynenv_ros.driving.vision import BodyTable, driving_state
from dynenv_ros.driving.world import DrivingWorld


def _body_by_body(world):
    """The reference: each car's and pedestrian's pose and velocity through pymunk's Body properties."""
    cars = []
    for car in world.cars:
        b = car.body
        speed = b.velocity.x * math.cos(b.angle) + b.velocity.y * math.sin(b.angle)
        yaw = (b.angle + math.pi) % (2 * math.pi) - math.pi
        cars.append((b.position.x, b.position.y, yaw, speed, b.angular_velocity))
    peds = [(b.position.x, b.position.y) for b in world.pedestrians.bodies]
    return np.array(cars), np.array(peds)


def test_the_batch_read_equals_the_bodies_through_leaving_cars_and_hit_pedestrians():
    world = DrivingWorld(DrivingConfig(n_cars=4))
    world.reset(seed=3)
    table = BodyTable(world)
    rng = np.random.default_rng(0)
    left = killed = 0
    for step in range(400):
        if step == 5:   # a pedestrian hit: out of the space, still listed where it fell
            world.pedestrians.kill(0, world.physics.space)
        if step == 7:   # a car at its destination: out of the space, at rest
            world.cars[1].leave(world.physics.space)
        result = world.step(rng.integers(0, 3, size=(4, 2)))
        state = driving_state(world, table)
        cars, peds = _body_by_body(world)
        np.testing.assert_allclose(np.c_[state.x, state.y, state.yaw, state.speed, state.yaw_rate], cars,
                                   rtol=0, atol=1e-12)
        np.testing.assert_allclose(np.c_[state.pedestrian_x, state.pedestrian_y], peds, rtol=0, atol=1e-12)
        assert list(state.present) == [car.in_space for car in world.cars]
        assert list(state.pedestrian_alive) == list(world.pedestrians.alive)
        left, killed = sum(not c.in_space for c in world.cars), int((~world.pedestrians.alive).sum())
        if result.terminated or result.truncated:
            break
    assert left >= 1 and killed >= 1 and step > 100   # both kinds of absent body were read, over many steps
