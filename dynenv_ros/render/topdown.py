"""Top-down pictures of a soccer ``WorldSnapshot``: one RGB image per instant, PNG stills and animated GIFs.

Pillow only (no display, no matplotlib) so it runs headless in CI and inside the env's ``render()``. Field frame
follows REP 103 (x toward the goal team A attacks, y left); images have y pointing down, so ``FieldView`` flips it.
Files are written to ``path + '.tmp'`` and moved into place with ``os.replace`` so a crash never leaves a truncated
picture under the final name.
"""
from __future__ import annotations

import math
import os
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from dynenv_ros.core.object_classes import ObjectClass, ObjectStatus
from dynenv_ros.sim.ground_truth import BodyState, WorldSnapshot
from dynenv_ros.soccer.field import FieldGeometry
from dynenv_ros.soccer.referee import Phase

Colour = tuple[int, int, int]

STRIP_HEIGHT = 20                      # px: score / clock / phase text above the carpet
LEGEND_ROW = 16                        # px: one legend row below the carpet
LEGEND_HEIGHT = 2 * LEGEND_ROW         # the world's legend, then (when overlaid) the detections' legend
CARPET: Colour = (34, 120, 48)
LINE: Colour = (255, 255, 255)
STRIP: Colour = (30, 30, 30)
TEXT: Colour = (240, 240, 240)
BALL: Colour = (255, 140, 0)
TEAM_COLOURS: dict[int, Colour] = {1: (40, 80, 230), -1: (220, 40, 40), 0: (150, 150, 150)}
FALLEN_OUTLINE: Colour = (128, 128, 128)
HEADING: Colour = (20, 20, 20)
HEAD: Colour = (255, 230, 0)
FOV: Colour = (255, 255, 140)
# Driving bodies: the map's pictures (render.driving) and the detection overlays (render.detections) share them.
OBSTACLE: Colour = (235, 130, 20)
PEDESTRIAN: Colour = (230, 60, 200)
DEFAULT_ROBOT_RADIUS = 0.1             # m: used when a snapshot carries no robot size


def _check_positive(name: str, value: float) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
            or not math.isfinite(value) or value <= 0:
        raise ValueError(f"{name} must be a positive finite number, got {value!r}")
    return float(value)


@dataclass(frozen=True)
class FieldView:
    """Field-frame metres to image pixels; kept public so overlays (detections, plans) land on the same pixels."""
    geometry: FieldGeometry
    pixels_per_metre: float = 60.0
    strip_height: int = STRIP_HEIGHT
    legend_height: int = LEGEND_HEIGHT

    def __post_init__(self) -> None:
        _check_positive("pixels_per_metre", self.pixels_per_metre)
        for name in ("strip_height", "legend_height"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                raise ValueError(f"{name} must be a non-negative integer, got {value!r}")

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) in pixels: the text strip on top, the carpet (field + border), the legend below."""
        g, ppm = self.geometry, self.pixels_per_metre
        width = round(2 * (g.half_length + g.border) * ppm)
        height = round(2 * (g.half_width + g.border) * ppm) + self.strip_height + self.legend_height
        return max(1, width), max(1, height)

    def legend_row(self, row: int) -> float:
        """Pixel row of the centre of legend row ``row`` (0: the world's, 1: the detections')."""
        return self.size[1] - self.legend_height + (row + 0.5) * LEGEND_ROW

    def field_to_pixel(self, x: float, y: float) -> tuple[float, float]:
        """Pixel (column, row) of field point (x, y); rows grow downward, so field y is flipped."""
        g, ppm = self.geometry, self.pixels_per_metre
        return (x + g.half_length + g.border) * ppm, self.strip_height + (g.half_width + g.border - y) * ppm

    def length_to_pixels(self, metres: float) -> float:
        return metres * self.pixels_per_metre


def phase_name(phase: int) -> str:
    try:
        return Phase(phase).name
    except ValueError:
        return f"PHASE {phase}"


def score_text(snapshot: WorldSnapshot) -> str:
    """The score line every soccer picture shows (PNG strip, RViz text, Foxglove text): score, clock, phase."""
    minutes, seconds = divmod(max(0.0, snapshot.game_time), 60.0)
    return (f"A {snapshot.score_team_a} : {snapshot.score_team_b} B   {int(minutes)}:{seconds:04.1f} "
            f"({snapshot.time_remaining:.0f} s left)   {phase_name(snapshot.phase)}")


def render_snapshot(snapshot: WorldSnapshot, geometry: FieldGeometry, *, pixels_per_metre: float = 60.0,
                    ball_radius: float = 0.05, fov: tuple[int, float] | None = None) -> Image.Image:
    """Draw one instant top-down as an RGB image.

    ``fov=(robot_id, half_angle_rad)`` adds that robot's field-of-view wedge (heading = yaw + head_yaw), so a
    perception overlay can be checked against what the robot could see. Robots are labelled with their names
    (``a0`` = team_a_0) and a legend row below the carpet names every mark.
    """
    view = FieldView(geometry, pixels_per_metre)
    ball_radius = _check_positive("ball_radius", ball_radius)
    image = Image.new("RGB", view.size, CARPET)
    draw = ImageDraw.Draw(image)
    _draw_field(draw, view)
    robots = snapshot.of_class(ObjectClass.ROBOT)
    if fov is not None:
        _draw_fov(draw, view, robots, fov)
    for robot in robots:
        _draw_robot(draw, view, robot)
    for ball in snapshot.of_class(ObjectClass.BALL):
        _disc(draw, view, ball.x, ball.y, ball_radius, fill=BALL, min_px=2.0)
    _draw_labels(draw, view, robots)
    _draw_strip(draw, view, snapshot)
    _draw_world_legend(draw, view, with_fov=fov is not None)
    return image


def robot_labels(robots: tuple[BodyState, ...]) -> dict[int, str]:
    """Short names by body id: team letter and index within the team, as in team_a_0 → "a0"."""
    labels: dict[int, str] = {}
    for team, letter in ((1, "a"), (-1, "b")):
        for k, robot in enumerate(sorted((r for r in robots if r.team == team), key=lambda r: r.id)):
            labels[robot.id] = f"{letter}{k}"
    return labels


def legend_font(view: FieldView) -> ImageFont.FreeTypeFont | ImageFont.ImageFont:
    return ImageFont.load_default(size=LEGEND_ROW - 4)


def _draw_labels(draw: ImageDraw.ImageDraw, view: FieldView, robots: tuple[BodyState, ...]) -> None:
    font = ImageFont.load_default(size=max(11, round(view.length_to_pixels(0.22))))
    for robot in robots:
        label = robot_labels(robots).get(robot.id)
        if label is None:
            continue
        radius = robot.size_x / 2 if robot.size_x > 0 else DEFAULT_ROBOT_RADIUS
        px, py = view.field_to_pixel(robot.x, robot.y)
        offset = max(3.0, view.length_to_pixels(radius)) + 2
        draw.text((px + offset, py - offset), label, fill=TEXT, font=font, anchor="ld", stroke_width=2,
                  stroke_fill=STRIP)


def _draw_world_legend(draw: ImageDraw.ImageDraw, view: FieldView, *, with_fov: bool) -> None:
    if view.legend_height <= 0:
        return
    top = view.size[1] - view.legend_height
    draw.rectangle((0, top, view.size[0] - 1, view.size[1] - 1), fill=STRIP)
    font, y, x = legend_font(view), view.legend_row(0), 4.0
    r = LEGEND_ROW / 2 - 3
    entries: list[tuple[str, str, Colour]] = [("disc", "team A", TEAM_COLOURS[1]), ("disc", "team B", TEAM_COLOURS[-1]),
                                              ("disc", "ball", BALL), ("line", "heading", HEADING),
                                              ("line", "gaze", HEAD)]
    if with_fov:
        entries.append(("line", "view", FOV))
    for kind, label, colour in entries:
        draw.rectangle((x - 1, y - r - 1, x + 2 * r + 1, y + r + 1), fill=CARPET)   # the colour as on the field
        if kind == "disc":
            draw.ellipse((x, y - r, x + 2 * r, y + r), fill=colour)
        else:
            draw.line((x, y, x + 2 * r, y), fill=colour, width=3)
        x += 2 * r + 4
        draw.text((x, y), label, fill=TEXT, font=font, anchor="lm")
        x += draw.textlength(label, font=font) + 10


def _line_px(view: FieldView) -> int:
    return max(1, round(view.length_to_pixels(view.geometry.line_width)))


def _disc(draw: ImageDraw.ImageDraw, view: FieldView, x: float, y: float, radius: float, *,
          fill: Colour | None = None, outline: Colour | None = None, width: int = 1, min_px: float = 1.0) -> float:
    cx, cy = view.field_to_pixel(x, y)
    r = max(min_px, view.length_to_pixels(radius))
    draw.ellipse((cx - r, cy - r, cx + r, cy + r), fill=fill, outline=outline, width=width)
    return r


def _draw_field(draw: ImageDraw.ImageDraw, view: FieldView) -> None:
    g = view.geometry
    w = _line_px(view)
    for x1, y1, x2, y2 in g.lines:
        draw.line((*view.field_to_pixel(x1, y1), *view.field_to_pixel(x2, y2)), fill=LINE, width=w)
    # Pillow strokes an ellipse inward from its box: grow the box by half a stroke to centre it on the radius.
    cx, cy = view.field_to_pixel(0.0, 0.0)
    r = view.length_to_pixels(g.center_circle_radius) + w / 2
    draw.ellipse((cx - r, cy - r, cx + r, cy + r), outline=LINE, width=w)
    half = view.length_to_pixels(g.penalty_mark_size) / 2
    for x, y in g.penalty_marks:
        px, py = view.field_to_pixel(x, y)
        draw.line((px - half, py, px + half, py), fill=LINE, width=w)
        draw.line((px, py - half, px, py + half), fill=LINE, width=w)
    for x, y in g.goalposts:
        _disc(draw, view, x, y, g.goalpost_radius, fill=LINE, min_px=1.5)


def _ray(view: FieldView, x: float, y: float, angle: float, length_px: float,
         start_px: float = 0.0) -> tuple[float, float, float, float]:
    cx, cy = view.field_to_pixel(x, y)
    dx, dy = math.cos(angle), -math.sin(angle)   # image rows grow downward
    return cx + dx * start_px, cy + dy * start_px, cx + dx * length_px, cy + dy * length_px


def _dim(colour: Colour) -> Colour:
    """Half way to the carpet: a penalized robot is off the game but should stay visible."""
    return tuple((c + k) // 2 for c, k in zip(colour, CARPET))  # type: ignore[return-value]


def _draw_robot(draw: ImageDraw.ImageDraw, view: FieldView, robot: BodyState) -> None:
    radius = robot.size_x / 2 if robot.size_x > 0 else DEFAULT_ROBOT_RADIUS
    colour = TEAM_COLOURS.get(robot.team, TEAM_COLOURS[0])
    heading, head = HEADING, HEAD
    if robot.status & ObjectStatus.PENALIZED:
        colour, heading, head = _dim(colour), _dim(heading), _dim(head)
    r_px = max(3.0, view.length_to_pixels(radius))
    stroke = max(1, round(r_px / 4))
    if robot.status & ObjectStatus.FALLEN:
        _disc(draw, view, robot.x, robot.y, radius, outline=FALLEN_OUTLINE, width=stroke + 1, min_px=3.0)
        _disc(draw, view, robot.x, robot.y, radius * 0.6, outline=colour, width=stroke, min_px=2.0)
    else:
        _disc(draw, view, robot.x, robot.y, radius, fill=colour, min_px=3.0)
    draw.line(_ray(view, robot.x, robot.y, robot.yaw, 1.6 * r_px), fill=heading, width=stroke)
    draw.line(_ray(view, robot.x, robot.y, robot.yaw + robot.head_yaw, 2.2 * r_px, start_px=0.5 * r_px),
              fill=head, width=max(1, stroke // 2))


def _draw_fov(draw: ImageDraw.ImageDraw, view: FieldView, robots: tuple[BodyState, ...],
              fov: tuple[int, float]) -> None:
    robot_id, half_angle = fov
    if not (math.isfinite(half_angle) and 0.0 < half_angle < math.pi):
        raise ValueError(f"fov half angle must be in (0, pi) rad, got {half_angle!r}")
    robot = next((r for r in robots if r.id == robot_id), None)
    if robot is None:
        raise ValueError(f"fov: no robot with id {robot_id} in the snapshot (ids {[r.id for r in robots]})")
    length = math.hypot(*view.size)   # reaches past any image edge; Pillow clips
    heading = robot.yaw + robot.head_yaw
    for side in (-1.0, 1.0):
        draw.line(_ray(view, robot.x, robot.y, heading + side * half_angle, length), fill=FOV, width=1)


def _draw_strip(draw: ImageDraw.ImageDraw, view: FieldView, snapshot: WorldSnapshot) -> None:
    if view.strip_height <= 0:
        return
    draw.rectangle((0, 0, view.size[0] - 1, view.strip_height - 1), fill=STRIP)
    font = ImageFont.load_default(size=max(8, view.strip_height - 6))
    draw.text((4, view.strip_height / 2), score_text(snapshot), fill=TEXT, font=font, anchor="lm")


def as_array(image: Image.Image) -> np.ndarray:
    """(H, W, 3) uint8 copy, the Gymnasium ``rgb_array`` render format."""
    return np.array(image.convert("RGB"), dtype=np.uint8)


def _checked_target(path: str | os.PathLike[str]) -> str:
    target = os.fspath(path)
    folder = os.path.dirname(os.path.abspath(target))
    if not os.path.isdir(folder):
        raise ValueError(f"cannot write {target!r}: directory {folder!r} does not exist")
    return target


def _write_atomically(target: str, write: Callable[[str], None]) -> None:
    tmp = target + ".tmp"
    try:
        write(tmp)
        os.replace(tmp, target)
    except BaseException:
        if os.path.exists(tmp):
            os.remove(tmp)
        raise


def save_png(image: Image.Image, path: str | os.PathLike[str]) -> None:
    """Write a PNG atomically (``path + '.tmp'`` then ``os.replace``)."""
    target = _checked_target(path)
    _write_atomically(target, lambda tmp: image.save(tmp, format="PNG"))


class EpisodeRecorder:
    """Renders snapshots as they arrive and keeps the frames, to save one animated GIF per episode.

    Frames are kept in memory (about W*H*3 bytes each); lower ``pixels_per_metre`` for long episodes.
    """

    def __init__(self, geometry: FieldGeometry, *, pixels_per_metre: float = 60.0, ball_radius: float = 0.05,
                 fov: tuple[int, float] | None = None) -> None:
        self.geometry = geometry
        self.pixels_per_metre = _check_positive("pixels_per_metre", pixels_per_metre)
        self.ball_radius = _check_positive("ball_radius", ball_radius)
        self.fov = fov
        self.frames: list[Image.Image] = []

    def __len__(self) -> int:
        return len(self.frames)

    def add(self, snapshot: WorldSnapshot) -> Image.Image:
        frame = render_snapshot(snapshot, self.geometry, pixels_per_metre=self.pixels_per_metre,
                                ball_radius=self.ball_radius, fov=self.fov)
        self.frames.append(frame)
        return frame

    def clear(self) -> None:
        self.frames.clear()

    def save_gif(self, path: str | os.PathLike[str], fps: float = 10.0) -> None:
        """Animated GIF that loops forever, written atomically.

        GIF delays are whole centiseconds, so playback speed is approximate; Pillow merges consecutive identical
        frames (summing their delays), so a reader may count fewer frames than ``len(self)`` for static stretches.
        """
        save_gif(self.frames, path, fps)


def save_gif(frames: list[Image.Image], path: str | os.PathLike[str], fps: float = 10.0) -> None:
    """Frames of any scenario as an animated GIF that loops forever, written atomically (``EpisodeRecorder``)."""
    if not frames:
        raise ValueError("nothing to save: the recorder has no frames (call add() first)")
    fps = _check_positive("fps", fps)
    target = _checked_target(path)
    duration_ms = max(10, round(1000.0 / fps))
    first, rest = frames[0], frames[1:]
    _write_atomically(target, lambda tmp: first.save(tmp, format="GIF", save_all=True, append_images=rest,
                                                     duration=duration_ms, loop=0))
