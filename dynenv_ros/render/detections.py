"""One robot's detections drawn over a top-down picture, so the perception model's errors can be seen, not guessed.

Detections arrive in the observer's camera frame (x along the gaze, y left); they are turned back into the field
frame with the observer's pose and drawn with ``FieldView`` so they land on the same pixels as the ground truth
``render_snapshot`` drew. Detections are diamonds with a dark outline (ground truth is discs), so a detection lying
right on its object stays distinguishable from it. Error marks: a red X over a false positive, a red ring around a
confusion (reported class differs from the real one), a hollow white circle on a visible object that was missed.
Scenario-neutral: driving classes (cars by team relation, pedestrians, obstacles, lanes as segments) are drawn the
same way on a ``render.driving.MapView`` (``render.driving.overlay_driving_detections``). Pillow only, like the rest
of the renderer.
"""
from __future__ import annotations

import math
from collections.abc import Iterable, Sequence

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from dynenv_ros.core.object_classes import ObjectClass
from dynenv_ros.perception.model import missed_objects
from dynenv_ros.render.topdown import (BALL, FOV, LEGEND_ROW, OBSTACLE, PEDESTRIAN, TEAM_COLOURS, Colour,
                                       FieldView)
from dynenv_ros.soccer.field import FieldGeometry

GOALPOST: Colour = (255, 220, 0)
MARK: Colour = (230, 0, 230)            # penalty crosses and line crossings
LINE_DETECTION: Colour = (0, 230, 230)  # field lines and the centre circle
OTHER: Colour = (150, 150, 150)         # any class this overlay has no colour for
OUTLINE: Colour = (0, 0, 0)
ERROR: Colour = (255, 0, 0)             # false positives and confusions
MISSED: Colour = (255, 255, 255)

# Marker half-sizes in metres (made at least MIN_MARKER_PX so they stay visible on small pictures).
MARKER_SIZE = {ObjectClass.BALL: 0.08, ObjectClass.ROBOT: 0.13, ObjectClass.GOALPOST: 0.1,
               ObjectClass.PENALTY_CROSS: 0.09, ObjectClass.LINE_CROSSING: 0.09,
               ObjectClass.CAR: 1.2, ObjectClass.PEDESTRIAN: 0.6, ObjectClass.OBSTACLE: 1.0}
LINE_CLASSES = (ObjectClass.FIELD_LINE, ObjectClass.LANE)      # drawn as segments from their endpoints
HEADED_CLASSES = (ObjectClass.ROBOT, ObjectClass.CAR)          # drawn with a facing tick when yaw is defined
DEFAULT_MARKER_SIZE = 0.09
MIN_MARKER_PX = 3.0
MISSED_RADIUS = 0.17                    # m: larger than any marker, so a miss ring never hides a detection


def field_view(geometry: FieldGeometry, pixels_per_metre: float = 60.0) -> FieldView:
    """The view ``render_snapshot(…, pixels_per_metre=…)`` draws with, so overlays land on its pixels."""
    return FieldView(geometry, pixels_per_metre)


def camera_to_field(observer_pose: tuple[float, float, float], x: np.ndarray | float,
                    y: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
    """Camera-frame points (x along the gaze, y left) to field coordinates; pose = (x, y, body yaw + head yaw)."""
    ox, oy, heading = observer_pose
    c, s = math.cos(heading), math.sin(heading)
    x, y = np.asarray(x, float), np.asarray(y, float)
    return ox + c * x - s * y, oy + s * x + c * y


def classify_rows(d: np.ndarray, observer_pose: tuple[float, float, float]
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per detection row (non-empty): reported class, field x and y, false positive (true_id -1) and confused
    (a real object reported as another class); what the RViz markers and the Foxglove live view draw from."""
    cls = d["class_id"].astype(int)
    fx, fy = camera_to_field(observer_pose, d["x"], d["y"])
    fx, fy = np.atleast_1d(fx), np.atleast_1d(fy)
    false_positive = d["true_id"] == -1
    true_class = d["true_class"].astype(int)
    confused = ~false_positive & (true_class != 0) & (true_class != cls)
    return cls, fx, fy, false_positive, confused


def class_colour(class_id: int, team: int = 0, observer_team: int = 1) -> Colour:
    """Marker colour of a reported class; robots and cars by team relation (own = the observer's team colour)."""
    if class_id in (ObjectClass.ROBOT, ObjectClass.CAR):
        return TEAM_COLOURS.get(int(team) * observer_team, TEAM_COLOURS[0])
    return {ObjectClass.BALL: BALL, ObjectClass.GOALPOST: GOALPOST, ObjectClass.PENALTY_CROSS: MARK,
            ObjectClass.LINE_CROSSING: MARK, ObjectClass.FIELD_LINE: LINE_DETECTION,
            ObjectClass.CENTER_CIRCLE: LINE_DETECTION, ObjectClass.LANE: LINE_DETECTION,
            ObjectClass.PEDESTRIAN: PEDESTRIAN, ObjectClass.OBSTACLE: OBSTACLE}.get(int(class_id), OTHER)


def overlay_detections(image: Image.Image, view: FieldView, observer_pose: tuple[float, float, float],
                       detections: np.ndarray, *, truth: Iterable[tuple[float, float]] | None = None,
                       observer_team: int = 1, fov_half_angle: float | None = math.pi / 4,
                       legend: bool = True) -> Image.Image:
    """Draw ``detections`` (DETECTION_DTYPE rows of one observer) on ``image`` in place and return it.

    ``observer_pose`` = (x, y, camera heading) in the field frame, camera heading = body yaw + head yaw.
    ``truth``: field positions of objects that were visible but missed, drawn as hollow white circles.
    ``observer_team`` (+1 team A, -1 team B) turns the reported team relation into the colours of the picture.
    Misses are drawn first and false-positive crosses last, so errors stay on top of the detections they mark.
    ``fov_half_angle`` draws the observer's field-of-view wedge (None: none; the default is the presets' 90° view);
    ``legend`` names the detection marks in the view's second legend row.
    """
    if image.size != view.size:
        raise ValueError(f"image is {image.size} px but the view is {view.size} px: "
                         "build the view with the geometry and pixels_per_metre the image was rendered with")
    if observer_team not in (1, -1):
        raise ValueError(f"observer_team must be +1 or -1, got {observer_team!r}")
    draw = ImageDraw.Draw(image)
    if fov_half_angle is not None:
        if not (math.isfinite(fov_half_angle) and 0.0 < fov_half_angle < math.pi):
            raise ValueError(f"fov_half_angle must be in (0, pi) rad, got {fov_half_angle!r}")
        ox, oy = view.field_to_pixel(observer_pose[0], observer_pose[1])
        reach = math.hypot(*view.size)          # past any image edge; Pillow clips
        for side in (-1.0, 1.0):
            angle = observer_pose[2] + side * fov_half_angle
            draw.line((ox, oy, ox + reach * math.cos(angle), oy - reach * math.sin(angle)), fill=FOV, width=1)
    if legend and view.legend_height >= 2 * LEGEND_ROW:
        draw_legend(image, (4, view.legend_row(1) - LEGEND_ROW / 2), soccer_legend(observer_team),
                    height=LEGEND_ROW)
    for x, y in truth or ():
        _ring(draw, *view.field_to_pixel(x, y), max(MIN_MARKER_PX + 4, view.length_to_pixels(MISSED_RADIUS)),
              MISSED, width=2)
    d = np.asarray(detections)
    if len(d) == 0:
        return image
    cls = d["class_id"].astype(int)
    fx, fy = camera_to_field(observer_pose, d["x"], d["y"])
    lines = np.isin(cls, LINE_CLASSES)
    if lines.any():
        sx, sy = camera_to_field(observer_pose, d["line_start_x"][lines], d["line_start_y"][lines])
        ex, ey = camera_to_field(observer_pose, d["line_end_x"][lines], d["line_end_y"][lines])
        width = max(1, round(view.length_to_pixels(0.025)))   # thin: noisy lines pile up over frames
        for segment in zip(sx, sy, ex, ey):
            draw.line((*view.field_to_pixel(segment[0], segment[1]), *view.field_to_pixel(segment[2], segment[3])),
                      fill=LINE_DETECTION, width=width)
    heading = observer_pose[2]
    crosses = []
    for i in np.flatnonzero(~lines):
        px, py = view.field_to_pixel(fx[i], fy[i])
        colour = class_colour(cls[i], d["team"][i], observer_team)
        if cls[i] == ObjectClass.CENTER_CIRCLE:
            size = max(MIN_MARKER_PX, view.length_to_pixels(float(d["size_x"][i]) / 2))
            _ring(draw, px, py, size, LINE_DETECTION, width=2)
        else:
            size = max(MIN_MARKER_PX, view.length_to_pixels(MARKER_SIZE.get(cls[i], DEFAULT_MARKER_SIZE)))
            _diamond(draw, px, py, size, colour)
            if cls[i] in HEADED_CLASSES and np.isfinite(d["yaw"][i]):
                yaw = heading + float(d["yaw"][i])          # the robot's facing, from camera to field frame
                draw.line((px, py, px + 1.8 * size * math.cos(yaw), py - 1.8 * size * math.sin(yaw)),
                          fill=OUTLINE, width=2)
        true_class = int(d["true_class"][i])
        if true_class != 0 and true_class != cls[i]:
            _ring(draw, px, py, size + 3, ERROR, width=2)
        if d["true_id"][i] == -1:
            crosses.append((px, py, size + 2))
    for px, py, size in crosses:
        _cross(draw, px, py, size)
    return image


def missed_positions(perception_visible: np.ndarray, detections: np.ndarray, object_ids: np.ndarray,
                     x: np.ndarray, y: np.ndarray) -> list[tuple[float, float]]:
    """Field positions of objects geometrically visible in a view that no detection row comes from.

    A confused object is not "seen" by the model's bookkeeping but does have a detection (with its red ring), so
    it is not counted as missed here; that keeps one error from being drawn twice.
    """
    missed = np.flatnonzero(missed_objects(perception_visible, detections, object_ids))
    return [(float(x[j]), float(y[j])) for j in missed]


LegendEntry = tuple[str, str, Colour]      # (marker kind: 'diamond' or 'line', label, colour)


def soccer_legend(observer_team: int = 1) -> tuple[LegendEntry, ...]:
    """The classes a soccer robot's detections are drawn as (``draw_legend``), in ``observer_team``'s colours."""
    return (("diamond", "ball", BALL), ("diamond", "own", TEAM_COLOURS[observer_team]),
            ("diamond", "opp.", TEAM_COLOURS[-observer_team]), ("diamond", "post", GOALPOST),
            ("diamond", "mark", MARK), ("line", "line", LINE_DETECTION))


def driving_legend(observer_team: int = 1) -> tuple[LegendEntry, ...]:
    """The classes a car's detections are drawn as (``draw_legend``, for ``overlay_driving_detections``)."""
    return (("diamond", "car: own team", TEAM_COLOURS[observer_team]),
            ("diamond", "other", TEAM_COLOURS[-observer_team]), ("diamond", "pedestrian", PEDESTRIAN),
            ("diamond", "obstacle", OBSTACLE), ("line", "lane", LINE_DETECTION))


def draw_legend(image: Image.Image, origin: tuple[float, float], classes: Sequence[LegendEntry], *,
                height: int = 14) -> Image.Image:
    """One row of marker samples with names at ``origin`` (pixels), so a picture explains itself in the docs:
    the world's ``classes`` (``soccer_legend``, ``driving_legend``), then the error marks."""
    draw = ImageDraw.Draw(image)
    font = ImageFont.load_default(size=max(8, height - 4))
    x, y = origin
    r = height / 2 - 2
    entries = (*classes, ("cross", "false pos.", ERROR), ("ring", "confused", ERROR), ("missed", "missed", MISSED))
    for kind, label, colour in entries:
        cx, cy = x + r + 1, y + height / 2
        if kind == "diamond":
            _diamond(draw, cx, cy, r, colour)
        elif kind == "line":
            draw.line((cx - r, cy + r, cx + r, cy - r), fill=colour, width=2)
        elif kind == "cross":
            _cross(draw, cx, cy, r)
        else:
            _ring(draw, cx, cy, r, colour, width=2)
        x += 2 * r + 3
        draw.text((x, cy), label, fill=MISSED, font=font, anchor="lm")
        x += draw.textlength(label, font=font) + 6
    return image


def _diamond(draw: ImageDraw.ImageDraw, px: float, py: float, size: float, colour: Colour) -> None:
    draw.polygon(((px, py - size), (px + size, py), (px, py + size), (px - size, py)), fill=colour, outline=OUTLINE)


def _ring(draw: ImageDraw.ImageDraw, px: float, py: float, radius: float, colour: Colour, *, width: int) -> None:
    draw.ellipse((px - radius, py - radius, px + radius, py + radius), outline=colour, width=width)


def _cross(draw: ImageDraw.ImageDraw, px: float, py: float, size: float) -> None:
    # A dark underlay keeps the red X apart from the red team's robots.
    for colour, width in ((OUTLINE, 4), (ERROR, 2)):
        draw.line((px - size, py - size, px + size, py + size), fill=colour, width=width)
        draw.line((px - size, py + size, px + size, py - size), fill=colour, width=width)
