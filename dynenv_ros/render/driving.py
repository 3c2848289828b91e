"""Top-down pictures of a driving ``WorldSnapshot``: one RGB image per instant, PNG stills and animated GIFs.

The static map (roads, lane lines, walkways, buildings) comes from ``DrivingMap``, the bodies from the snapshot
alone (cars, pedestrians, obstacles, each car's destination), so env renders, ``dynenv-play --scenario driving``
and bag replays draw the same picture. Map frame REP 103 (x east, y north, origin at the map's lower-left corner);
image rows grow downward, so ``MapView`` flips y. Cars are boxes filled with their own colour (their destination is
a ring of that colour at its road end), outlined in their team's colour (blue team A, red team B), with a dark
heading bar to the front; a crashed car is dimmed and crossed out, a car at its destination is drawn hollow where
it left the map. Pillow only; files are written atomically (``topdown.save_png`` / ``topdown.save_gif``).

One car's detections (rows of ``perception.detections.DETECTION_DTYPE`` in its frame: x forward, y left) are drawn
over a picture with ``overlay_driving_detections``, the hook for the driving perception.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import Iterable

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from dynenv_ros.core.object_classes import ObjectClass, ObjectStatus
from dynenv_ros.driving.roads import DrivingMap, LineKind
from dynenv_ros.render.topdown import (LEGEND_HEIGHT, LEGEND_ROW, OBSTACLE, PEDESTRIAN, STRIP, STRIP_HEIGHT,
                                       TEAM_COLOURS, TEXT, Colour, _check_positive, save_gif)
from dynenv_ros.sim.ground_truth import BodyState, WorldSnapshot

GROUND: Colour = (92, 122, 78)
ASPHALT: Colour = (62, 62, 68)
WALKWAY: Colour = (178, 176, 168)
EDGE_LINE: Colour = (245, 245, 245)
CENTRE_LINE: Colour = (250, 200, 30)
INNER_LINE: Colour = (215, 215, 215)
BUILDING: Colour = (128, 102, 92)
BUILDING_OUTLINE: Colour = (70, 52, 46)
HEADING: Colour = (15, 15, 15)
CRASH: Colour = (255, 0, 0)
OUTSIDE: Colour = (48, 58, 44)            # beyond the map's edge (the walled margin)
# Fill colour of car i (its destination ring has the same colour).
CAR_COLOURS: tuple[Colour, ...] = ((70, 170, 255), (255, 225, 40), (60, 220, 120), (255, 120, 60), (170, 120, 255),
                                   (0, 210, 210), (255, 150, 200), (190, 230, 60), (150, 90, 40), (240, 240, 240))
DEFAULT_BORDER = 6.0                      # m of the walled margin shown around the map


def car_colour(car_id: int) -> Colour:
    return CAR_COLOURS[int(car_id) % len(CAR_COLOURS)]


@dataclass(frozen=True)
class MapView:
    """Map-frame metres to image pixels, with the text strip above and the legend rows below.

    Same interface as ``topdown.FieldView`` (``size``, ``field_to_pixel``, ``length_to_pixels``, ``legend_row``,
    ``legend_height``), so ``render.detections.overlay_detections`` draws on it unchanged."""
    width: float                          # m, the map's
    height: float
    pixels_per_metre: float = 4.0
    border: float = DEFAULT_BORDER
    strip_height: int = STRIP_HEIGHT
    legend_height: int = LEGEND_HEIGHT

    def __post_init__(self) -> None:
        _check_positive("pixels_per_metre", self.pixels_per_metre)
        if not (math.isfinite(self.border) and self.border >= 0):
            raise ValueError(f"border must be a non-negative number of metres, got {self.border!r}")
        for name in ("strip_height", "legend_height"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                raise ValueError(f"{name} must be a non-negative integer, got {value!r}")

    @classmethod
    def of(cls, dmap: DrivingMap, pixels_per_metre: float = 4.0, border: float = DEFAULT_BORDER) -> "MapView":
        return cls(dmap.width, dmap.height, pixels_per_metre, border)

    @property
    def size(self) -> tuple[int, int]:
        ppm = self.pixels_per_metre
        return (max(1, round((self.width + 2 * self.border) * ppm)),
                max(1, round((self.height + 2 * self.border) * ppm)) + self.strip_height + self.legend_height)

    def legend_row(self, row: int) -> float:
        """Pixel row of the centre of legend row ``row`` (0: the world's, 1: the detections')."""
        return self.size[1] - self.legend_height + (row + 0.5) * LEGEND_ROW

    def field_to_pixel(self, x: float, y: float) -> tuple[float, float]:
        """Pixel (column, row) of map point (x, y)."""
        ppm = self.pixels_per_metre
        return (x + self.border) * ppm, self.strip_height + (self.height + self.border - y) * ppm

    def length_to_pixels(self, metres: float) -> float:
        return metres * self.pixels_per_metre


def render_driving(snapshot: WorldSnapshot, dmap: DrivingMap, *, pixels_per_metre: float = 4.0,
                   border: float = DEFAULT_BORDER) -> Image.Image:
    """Draw one instant top-down as an RGB image (module docstring for the marks; a legend row names them)."""
    view = MapView.of(dmap, pixels_per_metre, border)
    image = Image.new("RGB", view.size, OUTSIDE)
    draw = ImageDraw.Draw(image)
    _draw_map(draw, view, dmap)
    cars = snapshot.of_class(ObjectClass.CAR)
    _draw_destinations(draw, view, cars)
    for o in snapshot.of_class(ObjectClass.OBSTACLE):
        _box(draw, view, o.x, o.y, 0.0, o.size_x / 2, o.size_y / 2, fill=OBSTACLE, outline=HEADING)
    for p in snapshot.of_class(ObjectClass.PEDESTRIAN):
        _draw_pedestrian(draw, view, p)
    for car in cars:
        _draw_car(draw, view, car)
    _draw_labels(draw, view, cars)
    _draw_strip(draw, view, snapshot)
    _draw_world_legend(draw, view)
    return image


def car_corners(x: float, y: float, yaw: float, half_length: float, half_width: float) -> np.ndarray:
    """(4, 2) map-frame corners of a box at (x, y) turned by ``yaw``: rear right, front right, front left, rear
    left."""
    c, s = math.cos(yaw), math.sin(yaw)
    local = np.array([(-half_length, -half_width), (half_length, -half_width), (half_length, half_width),
                      (-half_length, half_width)])
    return np.column_stack((x + c * local[:, 0] - s * local[:, 1], y + s * local[:, 0] + c * local[:, 1]))


def _box(draw: ImageDraw.ImageDraw, view: MapView, x: float, y: float, yaw: float, half_length: float,
         half_width: float, *, fill: Colour | None, outline: Colour | None,
         width: int = 1) -> list[tuple[float, float]]:
    points = [view.field_to_pixel(px, py) for px, py in car_corners(x, y, yaw, half_length, half_width)]
    draw.polygon(points, fill=fill, outline=outline, width=width)
    return points


def _draw_map(draw: ImageDraw.ImageDraw, view: MapView, dmap: DrivingMap) -> None:
    m = dmap.config
    draw.rectangle((*view.field_to_pixel(0.0, dmap.height), *view.field_to_pixel(dmap.width, 0.0)), fill=GROUND)
    for fill, extra in ((WALKWAY, m.walkway_width), (ASPHALT, 0.0)):      # walkways first, roads over them
        for road in dmap.roads:
            half = road.half_width + extra
            corners = [road.to_map(0.0, -half), road.to_map(road.length, -half), road.to_map(road.length, half),
                       road.to_map(0.0, half)]
            draw.polygon([view.field_to_pixel(*p) for p in corners], fill=fill)
    for b in dmap.buildings:
        draw.rectangle((*view.field_to_pixel(b.x - b.half_x, b.y + b.half_y),
                        *view.field_to_pixel(b.x + b.half_x, b.y - b.half_y)), fill=BUILDING,
                       outline=BUILDING_OUTLINE, width=max(1, round(view.length_to_pixels(0.5))))
    width = max(1, round(view.length_to_pixels(0.15)))
    for line in dmap.lane_lines:
        road, other = dmap.roads[line.road], dmap.roads[1 - line.road]
        cs, _ = road.to_road(*dmap.crossing)
        colour = {LineKind.EDGE: EDGE_LINE, LineKind.CENTRE: CENTRE_LINE}.get(line.kind, INNER_LINE)
        dash = 3.0 if line.kind == LineKind.INNER else None
        # Painted up to the crossing's carriageway and on from it, not across it.
        for s0, s1 in ((0.0, cs - other.half_width), (cs + other.half_width, road.length)):
            _line(draw, view, road, line.offset, s0, s1, colour, width, dash)


def _line(draw: ImageDraw.ImageDraw, view: MapView, road, d: float, s0: float, s1: float, colour: Colour,
          width: int, dash: float | None) -> None:
    if dash is None:
        draw.line((*view.field_to_pixel(*road.to_map(s0, d)), *view.field_to_pixel(*road.to_map(s1, d))),
                  fill=colour, width=width)
        return
    s = s0
    while s < s1:
        e = min(s + dash, s1)
        draw.line((*view.field_to_pixel(*road.to_map(s, d)), *view.field_to_pixel(*road.to_map(e, d))), fill=colour,
                  width=width)
        s += 2 * dash


def _draw_destinations(draw: ImageDraw.ImageDraw, view: MapView, cars: tuple[BodyState, ...]) -> None:
    """A ring of each driving car's colour at its destination, rings of cars sharing one nested outward."""
    rings: dict[tuple[float, float], int] = {}
    for car in cars:
        if car.status & ObjectStatus.FINISHED or not (math.isfinite(car.goal_x) and math.isfinite(car.goal_y)):
            continue
        key = (round(car.goal_x, 3), round(car.goal_y, 3))
        k = rings.get(key, 0)
        rings[key] = k + 1
        px, py = view.field_to_pixel(car.goal_x, car.goal_y)
        r = view.length_to_pixels(2.0 + 1.2 * k)
        draw.ellipse((px - r, py - r, px + r, py + r), outline=car_colour(car.id),
                     width=max(2, round(view.length_to_pixels(0.5))))


def _dim(colour: Colour) -> Colour:
    return tuple((c + k) // 2 for c, k in zip(colour, ASPHALT))  # type: ignore[return-value]


def _draw_car(draw: ImageDraw.ImageDraw, view: MapView, car: BodyState) -> None:
    hl, hw = car.size_x / 2, car.size_y / 2
    fill = car_colour(car.id)
    team = TEAM_COLOURS.get(car.team, TEAM_COLOURS[0])
    stroke = max(1, round(view.length_to_pixels(0.25)))
    if car.status & ObjectStatus.AT_GOAL:          # left the map: a hollow ghost where it left
        _box(draw, view, car.x, car.y, car.yaw, hl, hw, fill=None, outline=fill, width=stroke)
        return
    crashed = bool(car.status & ObjectStatus.CRASHED)
    _box(draw, view, car.x, car.y, car.yaw, hl, hw, fill=_dim(fill) if crashed else fill, outline=team, width=stroke)
    # Heading: a dark bar across the front third.
    c, s = math.cos(car.yaw), math.sin(car.yaw)
    fx, fy = car.x + c * hl * 0.55, car.y + s * hl * 0.55
    _box(draw, view, fx, fy, car.yaw, hl * 0.25, hw * 0.8, fill=HEADING, outline=None)
    if crashed:
        r = max(3.0, view.length_to_pixels(hl))
        px, py = view.field_to_pixel(car.x, car.y)
        for colour, width in ((HEADING, stroke + 2), (CRASH, stroke)):
            draw.line((px - r, py - r, px + r, py + r), fill=colour, width=width)
            draw.line((px - r, py + r, px + r, py - r), fill=colour, width=width)


def _draw_pedestrian(draw: ImageDraw.ImageDraw, view: MapView, p: BodyState) -> None:
    px, py = view.field_to_pixel(p.x, p.y)
    r = max(2.0, view.length_to_pixels(p.size_x / 2 if p.size_x > 0 else 0.5))
    if p.status & ObjectStatus.CRASHED:           # hit: out of the world, marked where it was hit
        draw.line((px - r, py - r, px + r, py + r), fill=CRASH, width=2)
        draw.line((px - r, py + r, px + r, py - r), fill=CRASH, width=2)
        return
    draw.ellipse((px - r, py - r, px + r, py + r), fill=PEDESTRIAN, outline=HEADING)


def _draw_labels(draw: ImageDraw.ImageDraw, view: MapView, cars: tuple[BodyState, ...]) -> None:
    font = ImageFont.load_default(size=max(10, round(view.length_to_pixels(2.5))))
    for car in cars:
        px, py = view.field_to_pixel(car.x, car.y)
        offset = view.length_to_pixels(max(car.size_x, 1.0) / 2) + 2
        draw.text((px + offset, py - offset), f"c{car.id}", fill=TEXT, font=font, anchor="ld", stroke_width=2,
                  stroke_fill=STRIP)


def _draw_strip(draw: ImageDraw.ImageDraw, view: MapView, snapshot: WorldSnapshot) -> None:
    if view.strip_height <= 0:
        return
    draw.rectangle((0, 0, view.size[0] - 1, view.strip_height - 1), fill=STRIP)
    cars = snapshot.of_class(ObjectClass.CAR)
    home = sum(1 for c in cars if c.status & ObjectStatus.AT_GOAL)
    crashed = sum(1 for c in cars if c.status & ObjectStatus.CRASHED)
    hit = sum(1 for p in snapshot.of_class(ObjectClass.PEDESTRIAN) if p.status & ObjectStatus.CRASHED)
    text = (f"{snapshot.game_time:5.1f} s ({snapshot.time_remaining:.0f} s left)   cars {len(cars)}: "
            f"{home} home, {crashed} crashed   pedestrians hit {hit}")
    font = ImageFont.load_default(size=max(8, view.strip_height - 6))
    draw.text((4, view.strip_height / 2), text, fill=TEXT, font=font, anchor="lm")


def _draw_world_legend(draw: ImageDraw.ImageDraw, view: MapView) -> None:
    if view.legend_height <= 0:
        return
    top = view.size[1] - view.legend_height
    draw.rectangle((0, top, view.size[0] - 1, view.size[1] - 1), fill=STRIP)
    font = ImageFont.load_default(size=LEGEND_ROW - 4)
    y, x = view.legend_row(0), 4.0
    r = LEGEND_ROW / 2 - 3
    entries = (("car", "car", CAR_COLOURS[0]), ("ring", "its goal", CAR_COLOURS[0]),
               ("outline", "team A", TEAM_COLOURS[1]), ("outline", "team B", TEAM_COLOURS[-1]),
               ("disc", "pedestrian", PEDESTRIAN), ("square", "obstacle", OBSTACLE),
               ("square", "building", BUILDING), ("cross", "crash", CRASH))
    for kind, label, colour in entries:
        box = (x, y - r, x + 2 * r, y + r)
        draw.rectangle((x - 1, y - r - 1, x + 2 * r + 1, y + r + 1), fill=ASPHALT)
        if kind == "car":
            draw.rectangle(box, fill=colour, outline=TEAM_COLOURS[1])
            draw.rectangle((x + 1.3 * r, y - 0.7 * r, x + 1.7 * r, y + 0.7 * r), fill=HEADING)
        elif kind == "ring":
            draw.ellipse(box, outline=colour, width=2)
        elif kind == "outline":
            draw.rectangle(box, outline=colour, width=2)
        elif kind == "disc":
            draw.ellipse(box, fill=colour)
        elif kind == "square":
            draw.rectangle(box, fill=colour)
        else:
            draw.line((x, y - r, x + 2 * r, y + r), fill=colour, width=2)
            draw.line((x, y + r, x + 2 * r, y - r), fill=colour, width=2)
        x += 2 * r + 4
        draw.text((x, y), label, fill=TEXT, font=font, anchor="lm")
        x += draw.textlength(label, font=font) + 10


# -- one car's detections ------------------------------------------------------------------------------------------
def overlay_driving_detections(image: Image.Image, view: MapView, observer_pose: tuple[float, float, float],
                               detections: np.ndarray, *, truth: Iterable[tuple[float, float]] | None = None,
                               observer_team: int = 1, view_radius: float | None = None,
                               legend: bool = True) -> Image.Image:
    """Draw one car's detections on ``image`` (from ``render_driving`` with the same view) in place and return it.

    ``detections``: ``perception.detections.DETECTION_DTYPE`` rows in the car's frame (x forward, y left; lanes as
    ``LANE`` rows with line endpoints); ``observer_pose`` = the car's (x, y, yaw) in the map frame. Markers and
    error marks as ``render.detections.overlay_detections`` (diamonds; red X false positive, red ring confusion,
    white ring ``truth``: visible but missed). ``SELF`` rows (the car's own odometry and destination) are not
    sightings and are skipped. ``view_radius`` (m) draws the 360° view's range as a circle.
    """
    from dynenv_ros.render.detections import (MISSED, draw_legend, driving_legend,  # perception only when used
                                              overlay_detections)
    if view_radius is not None:
        if not (math.isfinite(view_radius) and view_radius > 0):
            raise ValueError(f"view_radius must be a positive number of metres, got {view_radius!r}")
        px, py = view.field_to_pixel(observer_pose[0], observer_pose[1])
        r = view.length_to_pixels(view_radius)
        ImageDraw.Draw(image).ellipse((px - r, py - r, px + r, py + r), outline=MISSED, width=1)
    rows = np.asarray(detections)
    if len(rows):
        rows = rows[rows["class_id"] != ObjectClass.SELF]     # what the car knows of itself, not a sighting
    overlay_detections(image, view, observer_pose, rows, truth=truth, observer_team=observer_team,
                       fov_half_angle=None, legend=False)
    if legend and view.legend_height >= 2 * LEGEND_ROW:
        draw_legend(image, (4, view.legend_row(1) - LEGEND_ROW / 2), driving_legend(observer_team),
                    height=LEGEND_ROW)
    return image


# -- recording -----------------------------------------------------------------------------------------------------
class DrivingRecorder:
    """Renders snapshots as they arrive and keeps the frames (as 8-bit palette images, a third of the memory of RGB),
    to save one animated GIF per episode (``topdown.save_gif``)."""

    def __init__(self, dmap: DrivingMap, *, pixels_per_metre: float = 3.0, border: float = DEFAULT_BORDER) -> None:
        self.map = dmap
        self.pixels_per_metre = _check_positive("pixels_per_metre", pixels_per_metre)
        self.border = border
        self.view = MapView.of(dmap, self.pixels_per_metre, border)
        self.frames: list[Image.Image] = []

    def __len__(self) -> int:
        return len(self.frames)

    def render(self, snapshot: WorldSnapshot) -> Image.Image:
        return render_driving(snapshot, self.map, pixels_per_metre=self.pixels_per_metre, border=self.border)

    def add(self, snapshot: WorldSnapshot | Image.Image) -> Image.Image:
        """Keep a frame: a snapshot (rendered here) or a picture already drawn (e.g. with detections over it)."""
        frame = snapshot if isinstance(snapshot, Image.Image) else self.render(snapshot)
        self.frames.append(frame.quantize(colors=128, method=Image.Quantize.MEDIANCUT))
        return frame

    def clear(self) -> None:
        self.frames.clear()

    def save_gif(self, path: str | os.PathLike[str], fps: float = 10.0) -> None:
        save_gif(self.frames, path, fps)


__all__ = ["MapView", "render_driving", "car_corners", "car_colour", "overlay_driving_detections", "DrivingRecorder",
           "CAR_COLOURS"]
