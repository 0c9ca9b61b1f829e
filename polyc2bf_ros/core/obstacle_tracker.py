"""Obstacle store keyed by marker ``ns/id``, with constant-velocity estimates.

Markers arrive as ADD/MODIFY (replace the obstacle with that key), DELETE (drop
it) and DELETEALL (drop every obstacle, like RViz does).  Each update carries a
stamp ``t`` [s] and a reference position ``p`` (the marker pose, or the
vertices' centroid); the velocity of a key is estimated from successive updates
and smoothed exponentially::

    v_raw = (p_k - p_{k-1}) / (t_k - t_{k-1})
    v_k   = a v_raw + (1 - a) v_{k-1}          a = ``smoothing`` in (0, 1]

The previous update is remembered across DELETE/DELETEALL for ``max_gap``
seconds, so a publisher that clears and re-adds its markers every message still
gets velocities.  A gap longer than ``max_gap``, or a stamp going backwards
(bag loop, simulation reset), restarts the estimate at zero velocity; a repeated
stamp keeps it.

``snapshot`` moves every obstacle to a common reference time ``t_ref`` (the
newest stamp held): ``polygon + v_xy (t_ref - t)``, ``z + v_z (t_ref - t)``.
The filter then extrapolates all of them together by the state's age.

``outline_polygon`` turns degenerate outlines into polygons: one distinct point
becomes a square of side ``thickness``; collinear points become a rectangle of
width ``thickness`` around the segment they span, extended by ``thickness / 2``
at both ends (a 2-point wall); anything else goes through ``clean_polygon``.
"""
import math
from dataclasses import dataclass

import numpy as np

from polyc2bf_ros.core.geometry import clean_polygon
from polyc2bf_ros.core.obstacles import Obstacle

# Points closer than this [m] are the same point; points within this distance
# of the line through the two extreme points make the outline collinear.
POINT_TOLERANCE = 1e-6


def outline_polygon(points, thickness):
    """Polygon ``(k, 2)`` for the outline ``points (n, 2)``; raises ``ValueError`` with a reason.

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
        return clean_polygon(points)
    if not thickness > 0.0:
        raise ValueError(f'degenerate outline (a point or a segment) and thickness {thickness}')
    half = 0.5 * thickness
    a, b = a - half * d, b + half * d
    return np.array([a - half * n, b - half * n, b + half * n, a + half * n])


@dataclass
class _Track:
    """One obstacle: geometry at ``stamp`` plus its velocity estimate."""

    frame: str
    polygons: list
    z_min: float
    z_max: float
    position: np.ndarray
    stamp: float
    velocity: np.ndarray


class ObstacleTracker:
    """Obstacles by key, with velocity estimates, rejections and extrapolation."""

    def __init__(self, smoothing=0.5, max_gap=1.0):
        """``smoothing`` in (0, 1] (1 = raw differences), ``max_gap`` [s] > 0."""
        if not (0.0 < smoothing <= 1.0 and max_gap > 0.0):
            raise ValueError('need 0 < smoothing <= 1 and max_gap > 0, '
                             f'got {smoothing}, {max_gap}')
        self.smoothing = float(smoothing)
        self.max_gap = float(max_gap)
        self._tracks = {}
        self._history = {}
        self._rejected = {}
        self._invalid = set()

    def __len__(self):
        """Return the number of obstacles held (rejected ones excluded)."""
        return len(self._tracks)

    @property
    def rejected(self):
        """``{key: reason}`` of the markers whose last update was refused."""
        return dict(self._rejected)

    @property
    def has_invalid(self):
        """True while some key's last update had non-finite numbers (the node brakes)."""
        return bool(self._invalid)

    def update(self, key, frame, stamp, position, polygons, z_min=-math.inf, z_max=math.inf):
        """ADD/MODIFY ``key``: ``polygons`` (list of ``(k, 2)``) and ``z`` range at ``stamp``."""
        position = np.array(position, dtype=float).reshape(3)
        velocity = np.zeros(3)
        previous = self._history.get(key)
        if previous is not None:
            dt = stamp - previous.stamp
            if dt == 0.0:
                velocity = previous.velocity
            elif 0.0 < dt <= self.max_gap:
                raw = (position - previous.position) / dt
                velocity = self.smoothing * raw + (1.0 - self.smoothing) * previous.velocity
        track = _Track(frame, [np.asarray(p, dtype=float) for p in polygons],
                       float(z_min), float(z_max), position, float(stamp), velocity)
        self._tracks[key] = track
        self._history[key] = track
        self._rejected.pop(key, None)
        self._invalid.discard(key)
        self._prune(stamp)

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
        old = [k for k, t in self._history.items()
               if now - t.stamp > self.max_gap and k not in self._tracks]
        for k in old:
            del self._history[k]

    def snapshot(self, frame, position_dim):
        """Obstacles in ``frame`` moved to the newest stamp.

        Returns ``(obstacles, t_ref, wrong_frame)``: a list of core ``Obstacle``
        (velocity of length ``position_dim``; keys ``ns/id``, ``ns/id#i`` for
        multi-polygon markers), the reference time (``nan`` if empty) and
        ``{key: reason}`` for obstacles in another frame.
        """
        obstacles, wrong_frame = [], {}
        stamps = [t.stamp for t in self._tracks.values() if t.frame == frame]
        t_ref = max(stamps) if stamps else math.nan
        for key, t in self._tracks.items():
            if t.frame != frame:
                wrong_frame[key] = (f'frame {t.frame!r} is not the odometry frame {frame!r}')
                continue
            shift = t.velocity * (t_ref - t.stamp)
            for i, polygon in enumerate(t.polygons):
                obstacles.append(Obstacle(
                    polygon=polygon + shift[:2], velocity=t.velocity[:position_dim].copy(),
                    z_min=t.z_min + shift[2], z_max=t.z_max + shift[2],
                    key=key if len(t.polygons) == 1 else f'{key}#{i}'))
        return obstacles, t_ref, wrong_frame


def extrapolation_age(state_stamp, t_ref, max_extrapolation):
    """Return how far [s] to move a ``snapshot`` (taken at ``t_ref``) to a state's stamp.

    ``age = clip(state_stamp - t_ref, 0, max_extrapolation)``; 0 while either stamp is
    unset (not > 0, e.g. NaN for an empty snapshot).  The clip keeps stale or
    future-stamped obstacles from being thrown far along their velocity estimate.
    """
    if state_stamp > 0.0 and t_ref > 0.0:
        return min(max(state_stamp - t_ref, 0.0), max_extrapolation)
    return 0.0
