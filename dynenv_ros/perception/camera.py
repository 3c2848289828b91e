"""The "image" observation mode: per-camera semantic-segmentation masks rendered from one vision frame's detections.

DynEnv's image mode gives learners what a NAO's segmentation network would see instead of a detection list, so the
two can be compared on equal footing. Detections are re-drawn as simple 3D primitives standing or lying on the
ground plane (ball sphere, NAO-sized billboard, goalpost bar, painted strips) and projected through pinhole models
of the NAO's top and bottom cameras. Coordinates follow the detection list's camera frame (REP 103 body convention:
x along the gaze, y left, z up, origin on the ground under the head yaw axis), not the z-forward optical frame.

Pixel convention: pixel (row i, column j) has its centre at (u, v) = (j, i); the image centre of a 640x480 image is
(319.5, 239.5), which is why the principal point sits there. numpy only (no OpenCV), so it runs headless and fast.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from dynenv_ros.core.object_classes import ObjectClass
from dynenv_ros.perception.detections import DETECTION_DTYPE

# Channel of each class group inside one camera's block of CHANNELS_PER_CAMERA channels.
BALL_CHANNEL = 0
ROBOT_CHANNEL = 1
GOALPOST_CHANNEL = 2
LINE_CHANNEL = 3                       # field lines, penalty crosses, line crossings and the centre circle
CHANNELS_PER_CAMERA = 4

REFERENCE_WIDTH = 640                  # px: resolution the NAO intrinsics were measured at
REFERENCE_HEIGHT = 480

NEAR_PLANE = 0.05                      # m: geometry closer to the camera than this is clipped (no wrap-around)

# Object shapes (m): defaults where a detection carries no usable size, fixed NAO / SPL sizes elsewhere.
ROBOT_HEIGHT = 0.58
ROBOT_WIDTH = 0.30
GOALPOST_HEIGHT = 0.80
DEFAULT_GOALPOST_DIAMETER = 0.10
DEFAULT_BALL_DIAMETER = 0.10
DEFAULT_CENTER_CIRCLE_DIAMETER = 1.50
LINE_WIDTH = 0.05                      # painted width of field lines and the centre circle
PENALTY_CROSS_SIZE = 0.10              # arm-to-arm length of the painted cross (arms LINE_WIDTH wide)
LINE_CROSSING_SIZE = 0.10              # side of the square mark drawn at a line crossing
CIRCLE_SEGMENTS = 48


@dataclass(frozen=True)
class CameraModel:
    """One head camera: a pinhole looking along the gaze, pitched down, at a fixed place on the head.

    ``focal_length_px`` and ``principal_point`` are given at 640x480 and scaled to the configured resolution, so one
    model serves every ``ImageConfig``. ``pitch`` is the total downward pitch (camera mount + head pitch), radians.
    """
    name: str
    height: float                      # m above the ground
    forward_offset: float              # m ahead of the head yaw axis, along the gaze
    pitch: float                       # rad, positive = looking down
    focal_length_px: float = 543.6
    principal_point: tuple[float, float] = (319.5, 239.5)

    def __post_init__(self) -> None:
        for field in ("height", "forward_offset", "pitch", "focal_length_px"):
            value = getattr(self, field)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
                    or not math.isfinite(value):
                raise ValueError(f"CameraModel.{field} must be a finite number, got {value!r}")
        if self.focal_length_px <= 0:
            raise ValueError(f"CameraModel.focal_length_px must be positive, got {self.focal_length_px!r}")
        if len(self.principal_point) != 2 or not all(math.isfinite(c) for c in self.principal_point):
            raise ValueError(f"CameraModel.principal_point must be two finite numbers, got {self.principal_point!r}")

    def intrinsics(self, config: ImageConfig) -> tuple[float, float, float, float]:
        """(fx, fy, cx, cy) at ``config``'s resolution.

        The principal point scales about pixel edges, (c + 0.5)·s − 0.5, so the image centre stays the image centre
        and a W/4 image lines up with a 4x downscale of the full one.
        """
        sx = config.width / REFERENCE_WIDTH
        sy = config.height / REFERENCE_HEIGHT
        cx, cy = self.principal_point
        return (self.focal_length_px * sx, self.focal_length_px * sy, (cx + 0.5) * sx - 0.5, (cy + 0.5) * sy - 0.5)


# DynEnv's NAO cameras (measured from the original, cm -> m); the +0.25 rad is DynEnv's fixed head pitch.
NAO_TOP = CameraModel("top", height=0.58364, forward_offset=0.05871, pitch=0.0209 + 0.25)
NAO_BOTTOM = CameraModel("bottom", height=0.53774, forward_offset=0.05071, pitch=0.6929 + 0.25)


@dataclass(frozen=True)
class ImageConfig:
    """Output resolution of every camera image; small ones (160x120) keep image-mode training fast."""
    width: int = REFERENCE_WIDTH
    height: int = REFERENCE_HEIGHT

    def __post_init__(self) -> None:
        for field in ("width", "height"):
            value = getattr(self, field)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value <= 0:
                raise ValueError(f"ImageConfig.{field} must be a positive integer, got {value!r}")


def _camera_coords(points: np.ndarray, camera: CameraModel) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(right, down, depth) of robot-frame points in the camera's optical axes."""
    c, s = math.cos(camera.pitch), math.sin(camera.pitch)
    rx = points[..., 0] - camera.forward_offset
    rz = points[..., 2] - camera.height
    return -points[..., 1], -rx * s - rz * c, rx * c - rz * s


def project_points(points_xyz: np.ndarray, camera: CameraModel,
                   config: ImageConfig) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates (N, 2) as (u, v) and optical depth (N,) of robot-frame points (x fwd, y left, z up).

    ``depth`` is the distance along the optical axis; where it is <= 0 the point is behind the camera and its
    ``uv`` is NaN rather than a mirrored, misleading pixel.
    """
    pts = np.asarray(points_xyz, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"points_xyz must have shape (N, 3), got {pts.shape}")
    fx, fy, cx, cy = camera.intrinsics(config)
    right, down, depth = _camera_coords(pts, camera)
    ahead = depth > 0
    safe = np.where(ahead, depth, 1.0)
    uv = np.column_stack([cx + fx * right / safe, cy + fy * down / safe])
    uv[~ahead] = np.nan
    return uv, depth


# --- scene: every detection as 3D primitives, built once per frame and shared by all cameras -----------------------

@dataclass(frozen=True)
class _Scene:
    """Camera-independent 3D primitives of one frame, so each camera only projects and rasterises."""
    quads: np.ndarray                  # (P, 4, 3) convex planar quads, robot frame
    quad_channel: np.ndarray           # (P,) channel index of each quad (1..3)
    balls: np.ndarray                  # (B, 3) sphere centres
    ball_radius: np.ndarray            # (B,)


def _sizes(values: np.ndarray, default: float) -> np.ndarray:
    v = values.astype(np.float64)
    return np.where(np.isfinite(v) & (v > 0), v, default)


def _yaw(values: np.ndarray) -> np.ndarray:
    v = values.astype(np.float64)
    return np.where(np.isfinite(v), v, 0.0)


def _billboards(x: np.ndarray, y: np.ndarray, half_width: np.ndarray, height: float) -> np.ndarray:
    """Upright rectangles through (x, y) facing the head axis, so a robot or post shows its full width."""
    dist = np.hypot(x, y)
    far = dist > 1e-9
    safe = np.where(far, dist, 1.0)
    px = np.where(far, -y / safe, 0.0) * half_width      # left of the ray from the head to the object
    py = np.where(far, x / safe, 1.0) * half_width
    zero, top = np.zeros_like(x), np.full_like(x, height)
    corners = [(x - px, y - py, zero), (x + px, y + py, zero), (x + px, y + py, top), (x - px, y - py, top)]
    return np.stack([np.stack(c, axis=-1) for c in corners], axis=1)


def _ground_rects(x: np.ndarray, y: np.ndarray, angle: np.ndarray, half_length: np.ndarray | float,
                  half_width: np.ndarray | float) -> np.ndarray:
    """Rectangles painted on the ground, centred on (x, y), long axis along ``angle``."""
    ax, ay = np.cos(angle) * half_length, np.sin(angle) * half_length
    px, py = -np.sin(angle) * half_width, np.cos(angle) * half_width
    zero = np.zeros_like(x)
    corners = [(x - ax - px, y - ay - py), (x + ax - px, y + ay - py), (x + ax + px, y + ay + py),
               (x - ax + px, y - ay + py)]
    return np.stack([np.stack((cx, cy, zero), axis=-1) for cx, cy in corners], axis=1)


def _ring_quads(x: np.ndarray, y: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """The painted centre-circle strip as CIRCLE_SEGMENTS convex quads (a ring is no convex polygon)."""
    theta = np.linspace(0.0, 2.0 * math.pi, CIRCLE_SEGMENTS + 1)
    cos, sin = np.cos(theta), np.sin(theta)
    outer = (radius + LINE_WIDTH / 2)[:, None]
    inner = np.maximum(radius - LINE_WIDTH / 2, 0.0)[:, None]
    ox, oy = x[:, None] + outer * cos, y[:, None] + outer * sin          # (n, S + 1)
    ix, iy = x[:, None] + inner * cos, y[:, None] + inner * sin
    qx = np.stack([ox[:, :-1], ox[:, 1:], ix[:, 1:], ix[:, :-1]], axis=-1)  # (n, S, 4)
    qy = np.stack([oy[:, :-1], oy[:, 1:], iy[:, 1:], iy[:, :-1]], axis=-1)
    return np.stack([qx, qy, np.zeros_like(qx)], axis=-1).reshape(-1, 4, 3)


def _build_scene(d: np.ndarray) -> _Scene:
    """All detections as primitives, vectorised per class (no per-detection Python work)."""
    cls = d["class_id"]
    x, y = d["x"].astype(np.float64), d["y"].astype(np.float64)
    usable = np.isfinite(x) & np.isfinite(y)
    quads: list[np.ndarray] = []
    channels: list[int] = []

    def add(q: np.ndarray, channel: int) -> None:
        if len(q):
            quads.append(q)
            channels.extend([channel] * len(q))

    m = usable & (cls == ObjectClass.ROBOT)
    add(_billboards(x[m], y[m], np.full(m.sum(), ROBOT_WIDTH / 2), ROBOT_HEIGHT), ROBOT_CHANNEL)
    m = usable & (cls == ObjectClass.GOALPOST)
    add(_billboards(x[m], y[m], _sizes(d["size_x"][m], DEFAULT_GOALPOST_DIAMETER) / 2, GOALPOST_HEIGHT),
        GOALPOST_CHANNEL)

    m = usable & (cls == ObjectClass.CENTER_CIRCLE)
    add(_ring_quads(x[m], y[m], _sizes(d["size_x"][m], DEFAULT_CENTER_CIRCLE_DIAMETER) / 2), LINE_CHANNEL)
    m = cls == ObjectClass.FIELD_LINE                 # placed by its end points alone
    sx, sy = d["line_start_x"][m].astype(np.float64), d["line_start_y"][m].astype(np.float64)
    ex, ey = d["line_end_x"][m].astype(np.float64), d["line_end_y"][m].astype(np.float64)
    length = np.hypot(ex - sx, ey - sy)
    ok = np.isfinite(length) & (length > 1e-6)
    # Square caps (half a line width past each end) so lines meeting at a corner leave no notch.
    add(_ground_rects((sx + ex)[ok] / 2, (sy + ey)[ok] / 2, np.arctan2(ey - sy, ex - sx)[ok],
                      length[ok] / 2 + LINE_WIDTH / 2, LINE_WIDTH / 2), LINE_CHANNEL)
    m = usable & (cls == ObjectClass.PENALTY_CROSS)
    yaw = _yaw(d["yaw"][m])
    for arm in (yaw, yaw + math.pi / 2):                # a plus sign is two convex bars
        add(_ground_rects(x[m], y[m], arm, PENALTY_CROSS_SIZE / 2, LINE_WIDTH / 2), LINE_CHANNEL)
    m = usable & (cls == ObjectClass.LINE_CROSSING)
    add(_ground_rects(x[m], y[m], _yaw(d["yaw"][m]), LINE_CROSSING_SIZE / 2, LINE_CROSSING_SIZE / 2), LINE_CHANNEL)

    m = usable & (cls == ObjectClass.BALL)
    radius = _sizes(d["size_x"][m], DEFAULT_BALL_DIAMETER) / 2
    return _Scene(quads=np.concatenate(quads) if quads else np.zeros((0, 4, 3)),
                  quad_channel=np.asarray(channels, dtype=np.intp),
                  balls=np.column_stack([x[m], y[m], radius]), ball_radius=radius)


# --- rasterisation ------------------------------------------------------------------------------------------------
#
# Coverage rule: a pixel is set when any part of the object falls inside its square. Small or distant objects
# therefore never vanish, and rendering commutes with downscaling: a W/4 image equals a 4x4 any-of (max) pooling of
# the full one, up to floating-point ties. Shapes become per-row pixel spans, computed for all shapes and rows at
# once and filled in one scatter; numpy only, no per-shape Python work (except clipping at the near plane).

_MAX_VERTICES = 5                      # a quad clipped by the near plane has at most five corners


def _clip_near(points: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """Sutherland-Hodgman clip of one convex polygon to depth >= NEAR_PLANE, so nothing behind the camera wraps."""
    out = []
    n = len(points)
    for i in range(n):
        j = (i + 1) % n
        a_in, b_in = depth[i] >= NEAR_PLANE, depth[j] >= NEAR_PLANE
        if a_in:
            out.append(points[i])
        if a_in != b_in:
            t = (NEAR_PLANE - depth[i]) / (depth[j] - depth[i])
            out.append(points[i] + t * (points[j] - points[i]))
    return np.asarray(out)


@dataclass
class _Spans:
    """Row spans [left, right] (inclusive pixel columns) per output channel, gathered over all cameras."""
    channel: list[np.ndarray]
    row: list[np.ndarray]
    left: list[np.ndarray]
    right: list[np.ndarray]

    def add(self, channel: np.ndarray, row: np.ndarray, xmin: np.ndarray, xmax: np.ndarray, width: int) -> None:
        with np.errstate(invalid="ignore"):
            left = np.maximum(np.ceil(xmin - 0.5), 0.0)
            right = np.minimum(np.floor(xmax + 0.5), width - 1.0)
            keep = left <= right                               # also drops empty (inf / NaN) rows
        self.channel.append(channel[keep])
        self.row.append(row[keep])
        self.left.append(left[keep].astype(np.intp))
        self.right.append(right[keep].astype(np.intp))


def _row_ranges(vmin: np.ndarray, vmax: np.ndarray, height: int) -> tuple[np.ndarray, np.ndarray]:
    """(owner index, image row) for every row whose pixel squares a shape spanning [vmin, vmax] can touch."""
    top = np.clip(np.ceil(vmin - 0.5), 0, height).astype(np.intp)
    bottom = np.clip(np.floor(vmax + 0.5), -1, height - 1).astype(np.intp)
    count = np.maximum(bottom - top + 1, 0)
    owner = np.repeat(np.arange(len(count)), count)
    starts = np.cumsum(count) - count
    return owner, top[owner] + np.arange(owner.size) - starts[owner]


def _polygon_spans(spans: _Spans, u: np.ndarray, v: np.ndarray, channel: np.ndarray, config: ImageConfig) -> None:
    """Spans of convex polygons (P, K) in pixel coordinates (repeat a corner to pad to K).

    A pixel square in row r meets the polygon iff its x interval meets the x extent of the polygon cut to the strip
    r - 0.5 <= v <= r + 0.5, and that extent is reached on the polygon's edges cut to the strip.
    """
    if not len(u):
        return
    owner, row = _row_ranges(v.min(axis=1), v.max(axis=1), config.height)
    if not owner.size:
        return
    au, av = u[owner], v[owner]                                # (R, K) edge starts
    bu, bv = np.roll(au, -1, axis=1), np.roll(av, -1, axis=1)  # edge ends
    y0 = (row - 0.5)[:, None]
    dv = bv - av
    flat = dv == 0
    with np.errstate(divide="ignore", invalid="ignore"):
        ta = (y0 - av) / dv
        tb = (y0 + 1.0 - av) / dv
    t_lo = np.where(flat, 0.0, np.maximum(np.minimum(ta, tb), 0.0))
    t_hi = np.where(flat, 1.0, np.minimum(np.maximum(ta, tb), 1.0))
    hit = np.where(flat, (av >= y0) & (av <= y0 + 1.0), t_lo <= t_hi)
    du = bu - au
    x_lo, x_hi = au + t_lo * du, au + t_hi * du
    xmin = np.where(hit, np.minimum(x_lo, x_hi), np.inf).min(axis=1)
    xmax = np.where(hit, np.maximum(x_lo, x_hi), -np.inf).max(axis=1)
    spans.add(channel[owner], row, xmin, xmax, config.width)


def _ellipse_spans(spans: _Spans, uc: np.ndarray, vc: np.ndarray, ru: np.ndarray, rv: np.ndarray,
                   channel: np.ndarray, config: ImageConfig) -> None:
    """Spans of filled axis-aligned ellipses (discs when fx == fy): per row, the widest chord inside the strip."""
    if not len(uc):
        return
    owner, row = _row_ranges(vc - rv, vc + rv, config.height)
    dy = np.maximum(np.abs(row - vc[owner]) - 0.5, 0.0) / rv[owner]
    half = ru[owner] * np.sqrt(np.maximum(1.0 - dy * dy, 0.0))
    half = np.where(dy <= 1.0, half, np.nan)
    spans.add(channel[owner], row, uc[owner] - half, uc[owner] + half, config.width)


def _camera_shapes(spans: _Spans, scene: _Scene, camera: CameraModel, config: ImageConfig, base: int) -> None:
    """Project one camera's view of the scene and queue its spans into channels base..base+3."""
    fx, fy, cx, cy = camera.intrinsics(config)
    w, h = config.width, config.height

    if len(scene.balls):
        right, down, depth = _camera_coords(scene.balls, camera)
        ok = depth > NEAR_PLANE
        z = depth[ok]
        angular = scene.ball_radius[ok] / z                   # radius f·r/depth, per axis
        _ellipse_spans(spans, cx + fx * right[ok] / z, cy + fy * down[ok] / z, fx * angular, fy * angular,
                       np.full(int(ok.sum()), base + BALL_CHANNEL), config)

    quads = scene.quads
    if not len(quads):
        return
    right, down, depth = _camera_coords(quads, camera)        # each (P, 4)
    front = depth.min(axis=1) >= NEAR_PLANE
    straddle = ~front & (depth.max(axis=1) >= NEAR_PLANE)
    z = depth[front]
    pad = [0, 1, 2, 3, 3]                                      # repeat a corner: quads as _MAX_VERTICES-gons
    u = (cx + fx * right[front] / z)[:, pad]
    v = (cy + fy * down[front] / z)[:, pad]
    channel = scene.quad_channel[front] + base
    if straddle.any():                                         # rare: clip in 3D before projecting
        extra_u, extra_v, extra_c = [], [], []
        for i in np.flatnonzero(straddle).tolist():
            clipped = _clip_near(quads[i], depth[i])
            if len(clipped) < 3:
                continue
            cr, cd, cz = _camera_coords(clipped, camera)
            missing = _MAX_VERTICES - len(clipped)
            extra_u.append(np.pad(cx + fx * cr / cz, (0, missing), mode="edge"))
            extra_v.append(np.pad(cy + fy * cd / cz, (0, missing), mode="edge"))
            extra_c.append(scene.quad_channel[i] + base)
        if extra_u:
            u = np.concatenate([u, np.asarray(extra_u)])
            v = np.concatenate([v, np.asarray(extra_v)])
            channel = np.concatenate([channel, np.asarray(extra_c, dtype=np.intp)])
    visible = (u.max(axis=1) >= -0.5) & (u.min(axis=1) <= w - 0.5) & (v.max(axis=1) >= -0.5) \
        & (v.min(axis=1) <= h - 0.5)
    _polygon_spans(spans, u[visible], v[visible], channel[visible], config)


def _validated(detections: np.ndarray) -> np.ndarray:
    if not isinstance(detections, np.ndarray) or detections.dtype != DETECTION_DTYPE:
        got = detections.dtype if isinstance(detections, np.ndarray) else type(detections).__name__
        raise ValueError("detections must be a numpy structured array with dtype "
                         f"dynenv_ros.perception.detections.DETECTION_DTYPE, got {got}")
    if detections.ndim != 1:
        raise ValueError(f"detections must be one-dimensional (one row per detection), got shape {detections.shape}")
    return detections


def render_segmentation(detections: np.ndarray, config: ImageConfig,
                        cameras: Sequence[CameraModel] = (NAO_TOP, NAO_BOTTOM)) -> np.ndarray:
    """uint8 0/1 masks of shape (4·len(cameras), H, W): per camera ball, robot, goalpost, lines (in that order).

    Channels are independent (a robot in front of a line leaves the line set), which is what a multi-label
    segmentation target needs. Rows of unknown or non-soccer classes, or with non-finite positions, are skipped.
    """
    if not isinstance(config, ImageConfig):
        raise ValueError(f"config must be an ImageConfig, got {type(config).__name__}")
    scene = _build_scene(_validated(detections))
    n_channels = CHANNELS_PER_CAMERA * len(cameras)
    h, w = config.height, config.width
    spans = _Spans([], [], [], [])
    for k, camera in enumerate(cameras):
        _camera_shapes(spans, scene, camera, config, CHANNELS_PER_CAMERA * k)
    if not spans.row or not sum(len(r) for r in spans.row):
        return np.zeros((n_channels, h, w), dtype=np.uint8)
    left = np.concatenate(spans.left)
    length = np.concatenate(spans.right) - left + 1
    first = (np.concatenate(spans.channel) * h + np.concatenate(spans.row)) * w + left
    # Every covered pixel's flat index: each span's first pixel repeated over its length, plus 0, 1, 2, ...
    offsets = np.cumsum(length) - length
    index = np.repeat(first - offsets, length) + np.arange(int(offsets[-1] + length[-1]))
    out = np.zeros(n_channels * h * w, dtype=np.uint8)
    out[index] = 1
    return out.reshape(n_channels, h, w)
