"""Obstacle store keyed by marker ``ns/id``, with constant-velocity estimates.

Markers arrive as ADD/MODIFY (replace the obstacle with that key), DELETE (drop
it) and DELETEALL (drop every obstacle, like RViz does).  Each update carries a
stamp ``t`` [s] and a reference position ``p`` (the marker pose, or the
vertices' centroid); the velocity of a key is estimated from successive updates by
the constant-velocity Kalman filter of ``core.obstacles.constant_velocity``, the one the scan
tracker uses: in the plane, position measured with standard deviation
``position_std`` [m] per axis, acceleration noise ``accel_std`` [m/s^2], and a first
velocity unknown with ``speed_std`` [m/s].  A marker that stands still keeps velocity 0
exactly (every innovation is 0).  The vertical velocity is the raw difference
``(z_k - z_{k-1}) / (t_k - t_{k-1})`` (3-D models only).

Acceleration (planar: an evasion's look ahead, ``SafetyFilter._look_ahead``, and the
braking check's motion of the part, ``SafetyFilter._path_clearance``) is an exponential
average of the filter's velocity differences, once the velocity is known
(its worst-axis standard deviation below ``SETTLED_SPEED_STD``)::

    a_k = a_{k-1} + (1 - exp(-dt / accel_time_constant)) ((v_k - v_{k-1}) / dt - a_{k-1})

capped at ``max_accel`` in norm.  Why not a constant-acceleration Kalman filter: this one
reuses the velocity filter the scan tracker shares, and on the dynamic suite's cylinders
(smooth loops, up to 2 m/s^2) the average with 0.3 s and 3 m/s^2 took the look ahead from
10 to 13 of the 20 medium worlds of the recorded seed, and 11 either way on unseen ones
(bench/README.md, Moving obstacles).  A new or restarted
estimate, and a standing marker, have zero acceleration.

The previous update is remembered across DELETE/DELETEALL for ``max_gap``
seconds, so a publisher that clears and re-adds its markers every message still
gets velocities.  A gap longer than ``max_gap``, or a stamp going backwards
(bag loop, simulation reset), restarts the estimate at zero velocity; a repeated
stamp keeps it.

Geometry is kept in each obstacle's own frame: a ``Shape`` (polygons and z
range) placed in the tracking frame by a ``Placement`` (rotation about z, then
translation), so an obstacle that only moves keeps its ``Shape`` object and
only its placement changes.  ``snapshot`` moves every obstacle to a common
reference time ``t_ref`` (the newest stamp held)::

    polygon = R(yaw) q + p_xy + v_xy (t_ref - t)        z = z_shape + p_z + v_z (t_ref - t)

The filter then extrapolates all of them together by the state's age.
``obstacle_set`` gives the same as the filter's ``ObstacleSet``; while the
obstacles in the frame keep their shapes and rotations (in the same order) it
only translates the set of the last call (``ObstacleSet.translated``) instead
of rebuilding it (convexity checks, decomposition), and the filter moves the
geometry it prepared for that set instead of preparing it again.

``outline_polygon`` turns degenerate outlines into polygons: one distinct point
becomes a square of side ``thickness``; collinear points become a rectangle of
width ``thickness`` around the segment they span, extended by ``thickness / 2``
at both ends (a 2-point wall); anything else goes through ``clean_polygon``, or, with more
than ``max_vertices`` points, becomes the enclosing polygon of ``polygon_limits`` (convex,
at most ``max_vertices`` vertices, containing every point).
"""
import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from polyc2bf_ros.core.geometry.polygon_limits import enclosing_polygon, MAX_PARTS
from polyc2bf_ros.core.geometry.polygons import clean_polygon
from polyc2bf_ros.core.obstacles import constant_velocity
from polyc2bf_ros.core.obstacles.obstacle_set import Obstacle, ObstacleSet

# Points closer than this [m] are the same point; points within this distance
# of the line through the two extreme points make the outline collinear.
POINT_TOLERANCE = 1e-6
# m/s: a velocity estimate this well known (worst axis, one sigma) starts the acceleration.
SETTLED_SPEED_STD = 1.0


def outline_polygon(points, thickness, max_vertices=None):
    """Polygon ``(k, 2)`` for the outline ``points (n, 2)``; raises ``ValueError`` with a reason.

    ``max_vertices``: above this many points the outline is replaced by its enclosing
    polygon (module docstring); None: no cap.

    Non-finite coordinates, an empty outline or a non-positive ``thickness``
    (when it is needed) are refused; ``clean_polygon`` raises
    ``InvalidPolygonError`` (a ``ValueError``) for e.g. self-intersections.
    """
    points = np.asarray(points, dtype=float).reshape(-1, 2)
    if not np.isfinite(points).all():
        raise ValueError('non-finite coordinates')
    if len(points) == 0:
        raise ValueError('no points')
    # Two sweeps find the extreme pair exactly for collinear points.
    a = points[np.argmax(np.linalg.norm(points - points[0], axis=1))]
    b = points[np.argmax(np.linalg.norm(points - a, axis=1))]
    axis = b - a
    length = float(np.linalg.norm(axis))
    d = axis / length if length > POINT_TOLERANCE else np.array([1.0, 0.0])
    n = np.array([-d[1], d[0]])
    if length > POINT_TOLERANCE and np.abs((points - a) @ n).max() > POINT_TOLERANCE:
        if max_vertices is not None and len(points) > max_vertices:
            return enclosing_polygon(points, max_vertices)
        return clean_polygon(points)
    if not thickness > 0.0:
        raise ValueError(f'degenerate outline (a point or a segment) and thickness {thickness}')
    half = 0.5 * thickness
    a, b = a - half * d, b + half * d
    return np.array([a - half * n, b - half * n, b + half * n, a + half * n])


@dataclass(frozen=True, eq=False)
class Shape:
    """An obstacle's geometry in its own frame; shapes compare by identity.

    ``polygons``: tuple of ``(k, 2)`` arrays; ``z_min`` / ``z_max``: z range;
    ``centroid``: the vertices' centroid (3,) for outlines, ``None`` for solids;
    ``source``: what the caller made it from, so that it can reuse the shape
    when the same thing arrives again (``ObstacleTracker.shape``); ``simplified``: the
    outline was replaced by an enclosing polygon (too many points or pieces).
    """

    polygons: tuple
    z_min: float = -math.inf
    z_max: float = math.inf
    centroid: np.ndarray = None
    source: object = None
    simplified: bool = False


class Placement(NamedTuple):
    """Own frame -> tracking frame: ``q -> R q + (x, y, z)``, ``R`` about z by (cos, sin)."""

    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
    cos: float = 1.0
    sin: float = 0.0

    def rotate(self, polygon):
        """Return ``R polygon`` (k, 2) (the polygon itself when R = I)."""
        if self.cos == 1.0 and self.sin == 0.0:
            return polygon
        return polygon @ np.array([[self.cos, self.sin], [-self.sin, self.cos]])


IDENTITY = Placement()


@dataclass
class _Track:
    """One obstacle: shape and placement at ``stamp`` plus its velocity estimate.

    ``estimate``: the Kalman filter's (state (4,), covariance (4, 4)) in the plane.
    """

    frame: str
    shape: Shape
    placement: Placement
    position: np.ndarray
    stamp: float
    velocity: np.ndarray
    estimate: tuple
    acceleration: np.ndarray

    def parts(self, key):
        """``(key, rotated polygon)`` per polygon; ``key#i`` for multi-polygon shapes."""
        polygons = self.shape.polygons
        if len(polygons) == 1:
            return [(key, self.placement.rotate(polygons[0]))]
        return [(f'{key}#{i}', self.placement.rotate(p)) for i, p in enumerate(polygons)]

    def moved(self, t_ref):
        """Return the offset (x, y, z) of the rotated shape at ``t_ref``: p + v (t_ref - t)."""
        dt = t_ref - self.stamp
        vx, vy, vz = self.velocity.tolist()
        p = self.placement
        return p.x + vx * dt, p.y + vy * dt, p.z + vz * dt


class ObstacleTracker:
    """Obstacles by key, with velocity estimates, rejections and extrapolation."""

    def __init__(self, accel_std=2.0, position_std=0.01, speed_std=2.0, max_gap=1.0,
                 accel_time_constant=0.3, max_accel=3.0):
        """Kalman filter and acceleration settings (module docstring), all > 0.

        Defaults: a walker's acceleration (1-2 m/s^2), marker poses good to a centimetre, a
        first velocity anywhere up to a run; the acceleration as measured on the dynamic
        suite (module docstring).
        """
        values = {'accel_std': accel_std, 'position_std': position_std,
                  'speed_std': speed_std, 'max_gap': max_gap,
                  'accel_time_constant': accel_time_constant, 'max_accel': max_accel}
        for name, value in values.items():
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f'{name} must be finite and positive, got {value!r}')
        self.accel_std, self.speed_std = float(accel_std), float(speed_std)
        self.accel_time_constant, self.max_accel = float(accel_time_constant), float(max_accel)
        self._noise = float(position_std) ** 2 * np.eye(2)
        self.max_gap = float(max_gap)
        self._tracks = {}
        self._history = {}
        self._rejected = {}
        self._invalid = set()
        self._layout = None  # keys, shapes and rotations behind _base (last obstacle_set)
        self._base = ObstacleSet.empty()

    def __len__(self):
        """Return the number of obstacles held (rejected ones excluded)."""
        return len(self._tracks)

    @property
    def rejected(self):
        """``{key: reason}`` of the markers whose last update was refused."""
        return dict(self._rejected)

    @property
    def simplified(self):
        """Return the number of obstacles held whose outline was simplified (``Shape``)."""
        return sum(t.shape.simplified for t in self._tracks.values())

    @property
    def has_invalid(self):
        """True while some key's last update had non-finite numbers (the node brakes)."""
        return bool(self._invalid)

    def shape(self, key):
        """Return the last ``Shape`` given for ``key`` (kept ``max_gap`` s after a delete)."""
        track = self._history.get(key)
        return track.shape if track is not None else None

    def update(self, key, frame, stamp, position, shape, placement=IDENTITY):
        """ADD/MODIFY ``key``: ``shape`` placed in ``frame`` by ``placement`` at ``stamp``.

        ``position`` (3,) in ``frame`` is the reference point of the velocity estimate.
        """
        position = np.array(position, dtype=float).reshape(3)
        previous = self._history.get(key)
        dt = stamp - previous.stamp if previous is not None else math.inf
        acceleration = np.zeros(2)
        if dt == 0.0:
            velocity, estimate = previous.velocity, previous.estimate
            acceleration = previous.acceleration
        elif 0.0 < dt <= self.max_gap:
            state, covariance = constant_velocity.predict(*previous.estimate, dt, self.accel_std)
            estimate = constant_velocity.update(state, covariance, position[:2], self._noise)
            velocity = np.array([*estimate[0][2:], (position[2] - previous.position[2]) / dt])
            if constant_velocity.velocity_std(previous.estimate[1]) < SETTLED_SPEED_STD:
                acceleration = self._averaged(previous, velocity, dt)
        else:
            velocity = np.zeros(3)
            estimate = constant_velocity.initial(position[:2], self._noise, self.speed_std)
        track = _Track(frame, shape, placement, position, float(stamp), velocity, estimate,
                       acceleration)
        self._tracks[key] = track
        self._history[key] = track
        self._rejected.pop(key, None)
        self._invalid.discard(key)
        self._prune(stamp)

    def _averaged(self, previous, velocity, dt):
        """Return the acceleration after ``previous``'s, from its velocity to ``velocity``."""
        measured = (velocity[:2] - previous.velocity[:2]) / dt
        share = -math.expm1(-dt / self.accel_time_constant)
        acceleration = previous.acceleration + share * (measured - previous.acceleration)
        norm = math.hypot(*acceleration)
        return acceleration * (self.max_accel / norm) if norm > self.max_accel else acceleration

    def reject(self, key, reason, invalid=False):
        """Refuse ``key``'s update: drop its obstacle, remember ``reason``.

        ``invalid`` marks non-finite input: ``has_invalid`` stays true until the
        key is updated with valid data, deleted, or everything is deleted.
        """
        self._tracks.pop(key, None)
        self._rejected[key] = reason
        if invalid:
            self._invalid.add(key)

    def delete(self, key):
        """DELETE ``key`` (unknown keys are ignored)."""
        self._tracks.pop(key, None)
        self._rejected.pop(key, None)
        self._invalid.discard(key)

    def delete_all(self):
        """DELETEALL: drop every obstacle and rejection (velocity history is kept)."""
        self._tracks.clear()
        self._rejected.clear()
        self._invalid.clear()

    def _prune(self, now):
        if len(self._history) == len(self._tracks):  # every key held is in use
            return
        old = [k for k, t in self._history.items()
               if now - t.stamp > self.max_gap and k not in self._tracks]
        for k in old:
            del self._history[k]

    def _in_frame(self, frame):
        """``([(key, track)] in frame, t_ref, {key: reason} for the other frames)``."""
        tracks, wrong_frame = [], {}
        for key, t in self._tracks.items():
            if t.frame == frame:
                tracks.append((key, t))
            else:
                wrong_frame[key] = f'frame {t.frame!r} is not the odometry frame {frame!r}'
        t_ref = max(t.stamp for _, t in tracks) if tracks else math.nan
        return tracks, t_ref, wrong_frame

    def snapshot(self, frame, position_dim):
        """Obstacles in ``frame`` moved to the newest stamp.

        Returns ``(obstacles, t_ref, wrong_frame)``: a list of core ``Obstacle``
        (velocity of length ``position_dim``; keys ``ns/id``, ``ns/id#i`` for
        multi-polygon markers), the reference time (``nan`` if empty) and
        ``{key: reason}`` for obstacles in another frame.
        """
        tracks, t_ref, wrong_frame = self._in_frame(frame)
        obstacles = []
        for key, t in tracks:
            x, y, z = t.moved(t_ref)
            for name, polygon in t.parts(key):
                obstacles.append(Obstacle(
                    polygon=polygon + (x, y), velocity=t.velocity[:position_dim].copy(),
                    z_min=t.shape.z_min + z, z_max=t.shape.z_max + z, key=name,
                    acceleration=t.acceleration.copy()))
        return obstacles, t_ref, wrong_frame

    def obstacle_set(self, frame, position_dim, max_parts=MAX_PARTS, max_obstacles=None):
        """``snapshot`` as the filter's ``ObstacleSet``: ``(obstacles, t_ref, wrong_frame)``.

        The set of the rotated shapes at the origin is rebuilt only when the
        keys, shapes or rotations in ``frame`` changed since the last call;
        otherwise each part is translated by its obstacle's ``moved`` offset
        (velocities beyond ``position_dim`` are 0, as in ``snapshot``).
        ``ObstacleSet.from_obstacles`` (``max_parts`` per footprint) raises
        ``ValueError`` for unusable polygons, and so does a set of more than
        ``max_obstacles`` convex parts (None: no cap).
        """
        tracks, t_ref, wrong_frame = self._in_frame(frame)
        layout = [(key, t.shape, t.placement.cos, t.placement.sin) for key, t in tracks]
        if layout != self._layout:
            if max_obstacles is not None:
                _check_count(sum(len(t.shape.polygons) for _, t in tracks), max_obstacles)
            base = ObstacleSet.from_obstacles([
                Obstacle(polygon=polygon, z_min=t.shape.z_min, z_max=t.shape.z_max, key=name)
                for key, t in tracks for name, polygon in t.parts(key)], max_parts)
            if max_obstacles is not None:
                _check_count(len(base), max_obstacles)
            self._base, self._layout = base, layout
        base = self._base
        rows = []
        for _, t in tracks:
            velocity = t.velocity.tolist()
            velocity[position_dim:] = [0.0] * (3 - position_dim)
            rows += [(*t.moved(t_ref), *velocity, *t.acceleration)] * len(t.shape.polygons)
        moves = np.array(rows, dtype=float).reshape(-1, 8)[base.owner]
        accelerations = moves[:, 6:] if moves[:, 6:].any() else None
        return (base.translated(moves[:, :3], moves[:, 3:6], accelerations), t_ref,
                wrong_frame)


def _check_count(parts, max_obstacles):
    """Raise ``ValueError`` when ``parts`` convex obstacle parts exceed ``max_obstacles``."""
    if parts > max_obstacles:
        raise ValueError(f'{parts} obstacle parts exceed max_obstacles ({max_obstacles})')


def extrapolation_age(state_stamp, t_ref, max_extrapolation):
    """Return how far [s] to move a ``snapshot`` (taken at ``t_ref``) to a state's stamp.

    ``age = clip(state_stamp - t_ref, 0, max_extrapolation)``; 0 while either stamp is
    unset (not > 0, e.g. NaN for an empty snapshot).  The clip keeps stale or
    future-stamped obstacles from being thrown far along their velocity estimate.
    """
    if state_stamp > 0.0 and t_ref > 0.0:
        return min(max(state_stamp - t_ref, 0.0), max_extrapolation)
    return 0.0
