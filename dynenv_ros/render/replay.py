"""A world's recorded ground truth drawn again, top-down, one frame per world state (``dynenv-bag render``), with one
robot's (car's) detections over it: one replay per world, found by the ``scenario`` code its WorldState messages
carry (``replay_of``). A bag carries neither the field nor the map, so soccer is drawn on the default
``FieldGeometry`` and driving on the default ``DrivingMap``.

Each replay draws a world state (``draw``), overlays an observer's detections on that frame (``overlay``), keeps
the frame (``keep``) and writes the kept frames as a GIF (``save_gif``). What it draws with is imported when it is
made, so a replay of one world loads nothing of the other's.
"""
from __future__ import annotations

from typing import Any

from dynenv_ros.core.object_classes import ObjectClass
from dynenv_ros.driving.config import SCENARIO_DRIVING
from dynenv_ros.soccer.config import SCENARIO_SOCCER


class SoccerReplay:
    """Soccer on the default field; a robot's detections are in its camera's frame (body yaw + head yaw)."""
    default_pixels_per_metre = 40.0        # the field is 10.4 m wide
    observer_class = ObjectClass.ROBOT

    def __init__(self, pixels_per_metre: float) -> None:
        from dynenv_ros.render.detections import field_view
        from dynenv_ros.render.topdown import EpisodeRecorder
        from dynenv_ros.soccer.field import FieldGeometry
        geometry = FieldGeometry()
        self.view = field_view(geometry, pixels_per_metre)
        self.recorder = EpisodeRecorder(geometry, pixels_per_metre=pixels_per_metre)

    def draw(self, snapshot: Any) -> Any:
        """The frame of one world state (the ball drawn at its recorded size), kept (``keep`` adds nothing)."""
        balls = snapshot.of_class(ObjectClass.BALL)
        self.recorder.ball_radius = balls[0].size_x / 2 if balls and balls[0].size_x > 0 else 0.05
        return self.recorder.add(snapshot)

    def overlay(self, frame: Any, observer: Any, detections: Any, rows: Any, team: int) -> None:
        from dynenv_ros.render.detections import overlay_detections
        pose = (observer.x, observer.y, observer.yaw + float(detections.head_yaw))
        overlay_detections(frame, self.view, pose, rows, observer_team=team)

    def keep(self, frame: Any) -> None:
        """Nothing to do: ``draw`` kept the frame, and an overlay is drawn on it in place."""

    def save_gif(self, path: Any, fps: float) -> None:
        self.recorder.save_gif(path, fps=fps)

    def __len__(self) -> int:
        return len(self.recorder)


class DrivingReplay:
    """Driving on the default map; a car's detections are in its body frame. A frame is kept (``keep``) once drawn
    over: the recorder keeps palette images, not the picture itself."""
    default_pixels_per_metre = 4.0         # the map is 182 m wide
    observer_class = ObjectClass.CAR

    def __init__(self, pixels_per_metre: float) -> None:
        from dynenv_ros.driving.roads import DrivingMap
        from dynenv_ros.render.driving import DrivingRecorder
        self.recorder = DrivingRecorder(DrivingMap(), pixels_per_metre=pixels_per_metre)
        self.view = self.recorder.view

    def draw(self, snapshot: Any) -> Any:
        return self.recorder.render(snapshot)

    def overlay(self, frame: Any, observer: Any, detections: Any, rows: Any, team: int) -> None:
        from dynenv_ros.render.driving import overlay_driving_detections
        overlay_driving_detections(frame, self.view, (observer.x, observer.y, observer.yaw), rows, observer_team=team)

    def keep(self, frame: Any) -> None:
        self.recorder.add(frame)

    def save_gif(self, path: Any, fps: float) -> None:
        self.recorder.save_gif(path, fps=fps)

    def __len__(self) -> int:
        return len(self.recorder)


# Each world's replay by its WorldState.SCENARIO_* code: a new world adds a row.
REPLAYS: dict[int, type[SoccerReplay] | type[DrivingReplay]] = {SCENARIO_SOCCER: SoccerReplay,
                                                                SCENARIO_DRIVING: DrivingReplay}


def replay_of(code: int | None) -> type[SoccerReplay] | type[DrivingReplay]:
    """The replay of the world a WorldState's ``scenario`` code names; soccer's where it names none, or there is no
    code (a bag's world states are soccer's unless they say otherwise)."""
    return REPLAYS.get(code, SoccerReplay)
