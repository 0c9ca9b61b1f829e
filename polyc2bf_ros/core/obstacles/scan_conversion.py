"""Convex obstacle polygons from a 2-D laser scan (plain numbers and numpy arrays, no ROS).

Over 500 lines on purpose: one algorithm, the steps below, each a short function, read
top to bottom.

Method, for a scan of N beams taken by a sensor at ``(s_x, s_y, s_yaw)`` in the robot's base
frame while the base is at ``q = (x, y)`` with heading ``yaw`` in the odometry frame:

1. Endpoints (``beam_endpoints``).  Beam i has range ``r_i`` and bearing
   ``alpha_i = angle_min + i * angle_increment`` in the sensor frame; it is kept when ``r_i``
   is finite, positive and within ``[range_min, range_max]``, and then ends at::

       p_i = o + r_i (cos phi_i, sin phi_i),   o = q + R(yaw) (s_x, s_y),
       phi_i = yaw + s_yaw + alpha_i.

2. Footprint.  Endpoints with ``|p_i - q| <= footprint_radius`` are the robot's own body and
   are dropped like invalid beams.
3. Clusters.  Kept beams i and i + 1 are linked when ``|p_{i+1} - p_i| <= cluster_tolerance``
   and the segment between them passes farther than ``footprint_radius`` from q; a dropped
   beam breaks the chain.  A scan that goes round (``N |angle_increment| >= 2 pi -
   |angle_increment| / 2``) also links beam N - 1 to beam 0, so the cluster across the seam is
   one; a cluster that goes all the way round is a ring, opened at the point farthest from
   its first point (a point of its convex hull, so a corner rather than the middle of a
   wall) and closed by repeating that point.  Clusters of fewer than ``min_cluster_points``
   points are noise and are dropped.
4. Pieces: the split step of split-and-merge (Ramer-Douglas-Peucker).  A cluster starts as
   one piece from its first to its last point; a piece is split at its point farthest from
   its chord (the segment joining its end points) while that distance exceeds
   ``split_tolerance`` (a compiled kernel, ``kernels.scan.split_to_tolerance``, one pass
   over all pieces).  Then a piece whose chord passes within
   ``footprint_radius`` of q is split at its middle point and splitting resumes, until no
   chord does (rare: the chord cuts across the robot).  A piece of two consecutive points is
   never split, and both rules were checked for it in step 3, so splitting ends.  Pieces
   are not merged again afterwards.
5. Depth.  A piece with chord ``[a, b]`` of length ``L >= t = segment_thickness`` becomes
   the rectangle ``a, b, b + D n, a + D n`` (D = ``depth``), n the unit normal of the chord
   on the side away from the sensor o: the beams crossed o's side (a and b swapped where
   needed for counter-clockwise order).  A shorter piece, or a single point, becomes the t
   wide, D deep rectangle whose near edge is centred on the chord midpoint m and which
   extends along ``(m - o) / |m - o|``, the beam's way.  A laser off the base can light a
   surface at grazing incidence whose line runs between o and q; should its rectangle then
   come within ``footprint_radius`` of q, it is built as from q instead (o replaced by q),
   so that none comes near the base.  Only the lit side is measured; D stands for the body
   behind it.  (At D = 2 cm, a robot passing a
   BARN cylinder of 7.5 cm radius saw a sliver of it: the side it came alongside had never
   been lit, the filter believed it a few millimetres farther than it was, and the robot
   grazed it.)
6. Front.  A piece's points may lie in front of its chord (on the sensor's side, up to
   ``split_tolerance``; ``t / 2`` for a lone point's).  The deepest of them, m, becomes a fifth
   corner between the chord's ends when it lies within the chord's span, so the near side
   runs a m b: exact across a box's corner, and a quarter of the chord's sagitta from an
   arc.  Then the near corners move forward, along the polygon's normal, by the largest
   distance a point still lies in front of that near side, so no measured point lies in
   front of its polygon: the polygon is at least as close as the surface the beams hit.
   (Left on the chord, a cylinder's front bulged up to 4 cm in front of its pieces and the
   robot grazed cylinders it believed centimetres away: BARN in scan mode.  Moved as a
   whole instead, the near edge stood up to ``split_tolerance`` in front of a box's faces
   next to a corner, and a gap between two pillars narrowed by twice that.)  The move is
   capped so that the polygon stays ``footprint_radius`` from q: a pentagon's line through
   its fifth corner, parallel to the chord (a piece whose corner would pass that line keeps
   four), a rectangle's near edge as a segment; uncapped when q lies behind the chord's
   line (step 5: the move then takes the near side away from q).  (Capped by the edge's
   line instead, a chord beside the robot, whose line passed within ``footprint_radius``
   though the chord did not, was never moved, and left the cylinder the robot was passing
   up to 4 mm in front of its polygon: a BARN graze.)

Guarantees. Every point of a piece lies within ``split_tolerance`` of its chord, an edge of
its rectangle, or within ``split_tolerance + t / 2`` of its short rectangle;
``ScanSettings`` requires that sum to be at most ``cluster_tolerance``. No point lies in
front of its polygon's near side (step 6) unless that would bring the polygon within
``footprint_radius`` of q. So, unless ``min_cluster_points > 1`` drops a cluster or
``max_obstacles`` drops a polygon, every kept endpoint lies within ``cluster_tolerance`` of
a returned polygon, and so does every segment between two linked endpoints (distance to a
chord is convex along it): the outline is open only where links break. Every polygon
stays more than ``footprint_radius`` from q (steps 4-6: its chord does, a rectangle that
would not is built away from q, and the front's move is capped or moves away from q): no
polygon contains the base. Polygons are rectangles, or pentagons with one corner in front of
the chord: convex, counter-clockwise, area at least ``t D``. At most ``max_obstacles`` are
returned; the farthest from q (by their chords' rectangles) are dropped.

Limits.
- A polygon is the lit side of an object, D deep: the far side and the true depth of the
  object are unknown.  It keeps a robot on the side it sees, not one already behind it; an
  object deeper than D may still reach nearer a robot that drives round it than its
  polygons do, until a scan lights that side.
- Between two beams a convex surface may still bulge in front of the near edge, by at most
  its sagitta over the beam spacing (a 0.1 m cylinder at 2 m and 0.33 degree beams: under
  0.1 mm).
- The chord runs between two measured points, so range noise at a piece's ends tilts it;
  noise approaching ``split_tolerance`` splits a wall into extra short pieces.  No merge step
  joins them again.
- Beams that return nothing (glass, black or grazed surfaces, beyond ``range_max``) leave
  gaps, and objects narrower than the beam spacing can fall between beams.  Neighbouring
  hits on a surface lie about ``r |angle_increment| / cos(incidence)`` apart; where that
  exceeds ``cluster_tolerance`` (head-on beyond 34 m at 0.25 deg and 0.15 m; along a corridor
  wall 1 m away, beyond about 6 m) they no longer link and the surface becomes a row of
  short rectangles, which still cover every endpoint.
- Anything closer than ``footprint_radius`` to the base is taken for the robot itself and
  ignored, even a real obstacle.
- The scan is taken as instantaneous at ``robot_pose`` (no de-skewing of motion during the
  sweep); obstacles get zero velocity and an unbounded z range (``scan_tracker`` estimates
  velocities from the clusters that ``with_clusters=True`` returns).  ``pose_at`` picks that
  pose from odometry samples: interpolated between the two stamped around the scan.
- ``obstacle_tracker.outline_polygon`` thickens an outline symmetrically, one obstacle at a
  time; here the thickening goes away from the base, so that it can never cover it, and is
  done for all pieces at once.

Cost.  O(N) numpy work for endpoints, links and rectangles, the split (step 4: O(K) per
level of splitting over the K points still being split; levels: about log2 of a cluster's
length for smooth outlines, at most its number of pieces) and the front (step 6) each in
one compiled pass (``kernels.scan``), then one ``Obstacle`` per polygon.  At N = 1081
numpy's call overhead and the ``Obstacle`` objects dominate: a median of 0.2-0.4 ms per
scan on the benchmark VM in a room with 0-30 moving objects (``bench/bench_tracking.py``),
about half of what the same steps took in numpy, and up to about twice that while the VM
is slow or another process loads both cores.  ``with_clusters`` adds one (K, 2) array and
a view per cluster: a few hundredths of a millisecond.
"""
import functools
import math
import numbers
from dataclasses import dataclass

import numpy as np

from polyc2bf_ros.core.geometry.polygons import _inverse_square_lengths, _segment_square_distances
from polyc2bf_ros.core.kernels.scan import front, split_to_tolerance
from polyc2bf_ros.core.obstacles.obstacle_set import Obstacle

FULL_TURN = 2.0 * math.pi
STILL = np.zeros(3)  # the velocity of every scan obstacle: one shared read-only array
STILL.flags.writeable = False


@dataclass(frozen=True)
class ScanSettings:
    """How a scan becomes obstacles (module docstring); checked when made (``validate``).

    ``cluster_tolerance`` [m]: the largest gap between linked neighbouring endpoints;
    ``min_cluster_points``: smaller clusters are dropped as noise; ``segment_thickness`` [m]:
    t, the side of a lone point's polygon and the shortest chord; ``depth`` [m]: D >= t, how
    far every polygon reaches behind the surface it outlines; ``split_tolerance`` [m]: the
    largest distance of a point from its piece's chord; ``footprint_radius`` [m]: endpoints
    this close to the base are the robot itself; ``max_obstacles``: how many polygons, the
    nearest, are kept.
    """

    cluster_tolerance: float = 0.15
    min_cluster_points: int = 1
    segment_thickness: float = 0.02
    depth: float = 0.10
    split_tolerance: float = 0.05
    footprint_radius: float = 0.0
    max_obstacles: int = 512

    def __post_init__(self):
        """Refuse settings out of range (``validate``)."""
        self.validate()

    def validate(self):
        """Raise ValueError naming the first field out of range.

        Lengths are finite, tolerance and thickness positive, counts integers >= 1,
        ``depth >= segment_thickness`` and ``split_tolerance + segment_thickness / 2 <=
        cluster_tolerance`` (the coverage bound).
        """
        for name, positive in (('cluster_tolerance', True), ('segment_thickness', True),
                               ('depth', True),
                               ('split_tolerance', False), ('footprint_radius', False)):
            value = getattr(self, name)
            if (isinstance(value, bool) or not isinstance(value, numbers.Real)
                    or not math.isfinite(value) or value < 0 or (positive and value == 0)):
                bound = '> 0' if positive else '>= 0'
                raise ValueError(f'{name} must be a finite number {bound}, got {value!r}')
        for name in ('min_cluster_points', 'max_obstacles'):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < 1:
                raise ValueError(f'{name} must be an integer >= 1, got {value!r}')
        if not self.depth >= self.segment_thickness:
            raise ValueError(f'depth must be at least segment_thickness = '
                             f'{self.segment_thickness!r}, got {self.depth!r}')
        if self.split_tolerance + self.segment_thickness / 2 > self.cluster_tolerance:
            raise ValueError(
                f'split_tolerance + segment_thickness / 2 = '
                f'{self.split_tolerance + self.segment_thickness / 2!r} must not exceed '
                f'cluster_tolerance = {self.cluster_tolerance!r} (the coverage guarantee)')


DEFAULT_SETTINGS = ScanSettings()


def _finite_number(value, name):
    """Return ``value`` as a float or raise ValueError when it is not a finite number."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ValueError(f'{name} must be a finite number, got {value!r}') from None
    if not math.isfinite(number):
        raise ValueError(f'{name} must be a finite number, got {value!r}')
    return number


def _finite_vector(values, size, name):
    """Return ``values`` as ``size`` floats or raise ValueError (wrong shape, non-finite)."""
    try:
        vector = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f'{name} must be {size} finite numbers, got {values!r}') from None
    if vector.shape != (size,) or not np.isfinite(vector).all():
        raise ValueError(f'{name} must be {size} finite numbers, got {values!r}')
    return vector.tolist()


@functools.lru_cache(maxsize=8)
def _bearing_units(count, angle_min, angle_increment):
    """Return read-only (cos, sin) of the ``count`` beam bearings, cached per scan layout."""
    bearings = angle_min + angle_increment * np.arange(count)
    cos_bearing, sin_bearing = np.cos(bearings), np.sin(bearings)
    cos_bearing.flags.writeable = sin_bearing.flags.writeable = False
    return cos_bearing, sin_bearing


def beam_endpoints(ranges, angle_min, angle_increment, range_min, range_max, sensor_pose,
                   robot_pose):
    """Return the (N, 2) odometry-frame endpoints of the N beams; NaN rows for dropped beams.

    A beam is dropped when its range is NaN, infinite, not positive or outside
    ``[range_min, range_max]``.  Poses are ``(x, y, yaw)``: the sensor in the base frame, the
    base in the odometry frame.  Malformed arguments raise ValueError.
    """
    try:
        ranges = np.asarray(ranges, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError('ranges must be a 1-D array of numbers') from None
    if ranges.ndim != 1:
        raise ValueError(f'ranges must be a 1-D array, got shape {ranges.shape}')
    angle_min = _finite_number(angle_min, 'angle_min')
    angle_increment = _finite_number(angle_increment, 'angle_increment')
    if angle_increment == 0:
        raise ValueError('angle_increment must not be zero')
    range_min = _finite_number(range_min, 'range_min')
    range_max = _finite_number(range_max, 'range_max')
    if range_min > range_max:
        raise ValueError(f'range_min {range_min} must not exceed range_max {range_max}')
    sensor_pose = _finite_vector(sensor_pose, 3, 'sensor_pose')
    robot_pose = _finite_vector(robot_pose, 3, 'robot_pose')
    origin_x, origin_y = sensor_origin(sensor_pose, robot_pose)
    heading = robot_pose[2] + sensor_pose[2]
    cos_heading, sin_heading = math.cos(heading), math.sin(heading)
    cos_bearing, sin_bearing = _bearing_units(len(ranges), angle_min, angle_increment)
    # r >= range_min and r > 0 (math.ulp(0.0): the smallest positive float); False for NaN.
    kept = (ranges >= max(range_min, math.ulp(0.0))) & (ranges <= range_max)
    lengths = np.where(kept, ranges, np.nan)
    forward, left = lengths * cos_bearing, lengths * sin_bearing  # in the sensor frame
    endpoints = np.empty((len(ranges), 2))
    endpoints[:, 0] = forward * cos_heading - left * sin_heading + origin_x
    endpoints[:, 1] = forward * sin_heading + left * cos_heading + origin_y
    return endpoints


def sensor_origin(sensor_pose, robot_pose):
    """Return o = q + R(yaw) (s_x, s_y), the sensor's (x, y) in the odometry frame.

    Poses as ``beam_endpoints``'s: the sensor (x, y, yaw) in the base frame, the base in the
    odometry frame.
    """
    sensor_x, sensor_y, _ = sensor_pose
    x, y, yaw = robot_pose
    cos_yaw, sin_yaw = math.cos(yaw), math.sin(yaw)
    return x + cos_yaw * sensor_x - sin_yaw * sensor_y, y + sin_yaw * sensor_x + cos_yaw * sensor_y


def scan_points(ranges, angle_min, angle_increment, range_min, range_max, sensor_pose,
                robot_pose):
    """Return the (K, 2) odometry-frame endpoints of the kept beams, in beam order."""
    endpoints = beam_endpoints(ranges, angle_min, angle_increment, range_min, range_max,
                               sensor_pose, robot_pose)
    return endpoints[~np.isnan(endpoints[:, 0])]


def scan_wraps(beam_count, angle_increment):
    """Return True when the scan goes round, so that its last beam neighbours its first."""
    step = abs(angle_increment)
    return beam_count >= 2 and beam_count * step >= FULL_TURN - step / 2


def _links(px, py, beams, reach_sq, base, settings, wraps):
    """Return (K,) whether kept point k links to point k + 1, the last to the first (step 3).

    Only a pair with its first point within ``footprint_radius + cluster_tolerance`` of the
    base can pass within ``footprint_radius`` of it, so only those pairs are measured.
    """
    next_x, next_y = np.concatenate((px[1:], px[:1])), np.concatenate((py[1:], py[:1]))
    step_x, step_y = next_x - px, next_y - py
    links = step_x * step_x + step_y * step_y <= settings.cluster_tolerance ** 2
    links[:-1] &= beams[1:] - beams[:-1] == 1
    links[-1] &= wraps
    reach = settings.footprint_radius + settings.cluster_tolerance
    near = (links & (reach_sq < reach ** 2)).nonzero()[0]
    if near.size:
        ax, ay = px[near], py[near]
        ex, ey = next_x[near] - ax, next_y[near] - ay
        links[near] = _segment_square_distances(
            base[0] - ax, base[1] - ay, ex, ey,
            _inverse_square_lengths(ex, ey)) > settings.footprint_radius ** 2
    return links


def _chain(px, py, links):
    """Order the points as open chains; return (x, y, (K' - 1,) links, is a ring).

    The chain that crosses the scan's seam is made contiguous; a ring is opened at its point
    farthest from its first point, which is repeated at the end.
    """
    unlinked = (~links).nonzero()[0]
    if unlinked.size == 0:
        start = int(np.argmax((px - px[0]) ** 2 + (py - py[0]) ** 2))
        order = np.concatenate((np.arange(start, len(px)), np.arange(start + 1)))
        return px[order], py[order], links[order[:-1]], True
    start = int(unlinked[-1]) + 1
    if start == len(px):
        return px, py, links[:-1], False
    order = np.concatenate((np.arange(start, len(px)), np.arange(start)))
    return px[order], py[order], links[order[:-1]], False


def _split_to_tolerance(px, py, ends, tolerance):
    """Return the sorted piece ends once no piece deviates more than ``tolerance`` (step 4).

    ``kernels.scan.split_to_tolerance``: one compiled pass over the pieces.  (Split a level
    at a time in numpy, about 55 calls a level, it took 0.25 ms of a 1081-beam scan among 30
    moving objects, a third of the conversion: ``bench/bench_tracking.py``.)
    """
    out = np.empty(len(px) + 1, dtype=np.int64)
    count = split_to_tolerance(px, py, ends, tolerance * tolerance, out,
                               np.empty(2 * len(px) + 2, dtype=np.int64))
    return out[:count]


def _split(px, py, ends, base, settings):
    """Return the sorted piece ends of step 4, starting from the sorted cluster ends.

    Pieces are split to tolerance; then a piece of three or more points whose chord passes
    within ``footprint_radius`` of the base is split at its middle point, and so on until
    none is left (pieces of two points were checked when the points were linked).
    """
    while True:
        ends = _split_to_tolerance(px, py, ends, settings.split_tolerance)
        first, last = ends[:-1], ends[1:]
        inner = last - first >= 2
        first, last = first[inner], last[inner]
        ax, ay = px[first], py[first]
        ex, ey = px[last] - ax, py[last] - ay
        near = _segment_square_distances(
            base[0] - ax, base[1] - ay, ex, ey,
            _inverse_square_lengths(ex, ey)) <= settings.footprint_radius ** 2
        if not near.any():
            return ends
        ends = np.concatenate((ends, (first[near] + last[near]) // 2))
        ends.sort()


def _rectangles(ax, ay, bx, by, viewpoint, thickness, depth):
    """Return the (M, 4, 2) CCW polygons of chords [a, b], away from ``viewpoint`` (step 5).

    Corners 0, 1: the near edge.
    """
    length = np.sqrt((bx - ax) ** 2 + (by - ay) ** 2)
    short = length < thickness
    swap = ~short & ((bx - ax) * (viewpoint[1] - ay) > (by - ay) * (viewpoint[0] - ax))
    ax, bx = np.where(swap, bx, ax), np.where(swap, ax, bx)
    ay, by = np.where(swap, by, ay), np.where(swap, ay, by)
    if short.any():
        cx, cy = (ax + bx) / 2, (ay + by) / 2
        ux, uy = cx - viewpoint[0], cy - viewpoint[1]
        reach = np.sqrt(ux * ux + uy * uy)
        away = reach > 0  # False only for a midpoint on the viewpoint (footprint_radius 0)
        scale = 0.5 * thickness / np.where(away, reach, 1.0)
        ux = np.where(away, ux * scale, 0.5 * thickness)  # half the side, towards the far edge
        uy = np.where(away, uy * scale, 0.0)
        ax, ay = np.where(short, cx - uy, ax), np.where(short, cy + ux, ay)
        bx, by = np.where(short, cx + uy, bx), np.where(short, cy - ux, by)
        length = np.where(short, thickness, length)
    scale = depth / length
    nx, ny = (ay - by) * scale, (bx - ax) * scale
    corners = np.empty((len(ax), 4, 2))
    corners[:, 0, 0], corners[:, 0, 1] = ax, ay
    corners[:, 1, 0], corners[:, 1, 1] = bx, by
    corners[:, 2, 0], corners[:, 2, 1] = bx + nx, by + ny
    corners[:, 3, 0], corners[:, 3, 1] = ax + nx, ay + ny
    return corners


def _rectangles_behind(ax, ay, bx, by, sensor, base, settings):
    """Return step 5's rectangles, reaching away from the sensor (near the base: from it).

    The beams crossed the sensor's side of each chord, so the body lies on the other.  With
    the laser off the base, a chord in line with both (a surface lit at grazing incidence)
    may have the base on that other side; a rectangle that then comes within
    ``footprint_radius`` of the base reaches away from the base instead, as from a laser
    at the base, so that no polygon comes near the base.  (Measured: built away
    from the base, a post beside a Jackal's front corner, lit by the laser 5.5 cm ahead of
    the base, became a rectangle reaching 8 cm into the space the beams had crossed, towards
    the box's path, on every few scans; the barrier's h jumped from +0.02 to -0.16 and the
    robot stalled; BARN world 200 from the laser, go-to-goal.)
    """
    thickness, depth = settings.segment_thickness, settings.depth
    polygons = _rectangles(ax, ay, bx, by, sensor, thickness, depth)
    if sensor[0] == base[0] and sensor[1] == base[1]:
        return polygons
    near = _reach_within(polygons, base, settings.footprint_radius)
    if near.any():
        polygons[near] = _rectangles(ax[near], ay[near], bx[near], by[near], base, thickness,
                                     depth)
    return polygons


def _reach_within(rectangles, point, radius):
    """Return (M,) whether each (M, 4, 2) rectangle of ``_rectangles`` comes within ``radius``.

    In the rectangle's frame (corner 0; sides along corners 0-1 and 0-3, scaled to [0, 1]),
    the distance is that of the point's offsets beyond each side's span.
    """
    corner = rectangles[:, 0]
    along, across = rectangles[:, 1] - corner, rectangles[:, 3] - corner
    rel = point - corner
    gaps = []
    for side in (along, across):
        square = (side * side).sum(axis=1)
        t = (rel * side).sum(axis=1) / square
        gaps.append(np.maximum(np.maximum(-t, t - 1.0), 0.0) ** 2 * square)
    return gaps[0] + gaps[1] <= radius * radius


def _front(polygons, px, py, first, last, base, footprint_radius):
    """Return the piece polygons with their near sides brought to their points (step 6).

    Piece k is points ``first[k] .. last[k]`` and rectangle ``a, b, b', a'`` (``_rectangles``;
    near edge a b of length L, unit e along it, unit normal n from a to a').  Per point
    u = (p - a) . e and f = -(p - a) . n, how far it lies in front of the chord.  The point m
    of largest f, when f_m > ``kernels.scan.MIN_APEX_DEPTH`` and 0 < u_m < L, becomes a
    fifth corner between a and b (convex: m lies in front of the chord, within its span),
    where the near side then runs a m b, in front of u by c(u) = f_m min(u / u_m, (L - u) /
    (L - u_m)); else c = 0.  The near corners then move along -n by max(0, max f - c(u))
    over the piece, capped so that the line through the nearest corner parallel to a b
    stays ``footprint_radius`` from the base; a piece whose apex line is closer keeps 4
    corners.

    ``kernels.scan.front``, a compiled pass over the pieces.  (In numpy, about 50 calls, it
    took 0.17 ms of a 1081-beam scan among 30 moving objects.)
    """
    count = len(polygons)
    if not count:
        return []
    corners = np.empty((count, 5, 2))
    pointed = np.empty(count, dtype=bool)
    front(polygons, px, py, first, last, float(base[0]), float(base[1]), footprint_radius,
          corners, pointed)
    rectangles = corners[:, (0, 2, 3, 4)]
    return [corners[k] if pointed[k] else rectangles[k] for k in range(count)]


def _nearest(polygons, base, count):
    """Return the sorted indices of the ``count`` polygons nearest the base.

    Ranked by their near edges' distances: a polygon's own, but for one that reaches
    towards the base (step 5: lit at grazing incidence by a laser off the base), at most
    ``depth`` nearer.
    """
    ax, ay = polygons[:, 0, 0], polygons[:, 0, 1]
    ex, ey = polygons[:, 1, 0] - ax, polygons[:, 1, 1] - ay
    reach_sq = _segment_square_distances(base[0] - ax, base[1] - ay, ex, ey,
                                         _inverse_square_lengths(ex, ey))
    return np.sort(np.argpartition(reach_sq, count - 1)[:count])


def scan_obstacles(endpoints, robot_position, settings=DEFAULT_SETTINGS, wraps=False,
                   with_clusters=False, sensor_position=None):
    """Return the obstacles (``Obstacle``, keys ``scan/<i>``) outlined by beam endpoints.

    ``endpoints`` (N, 2): one row per beam in beam order, non-finite rows for beams without a
    return (``beam_endpoints``); ``robot_position``: the base origin (x, y) in the same frame;
    ``wraps``: the last beam neighbours the first (``scan_wraps``); ``sensor_position``:
    the laser's origin (x, y) in that frame, None: at the base.  Obstacles share one
    read-only zero velocity.  Module docstring: method, guarantees and limits.

    ``with_clusters``: return ``(obstacles, owner, clusters)`` instead, where ``clusters`` is
    the list of the clusters of step 3 that ``min_cluster_points`` keeps, each the (n_i, 2)
    read-only array of its endpoints in chain order (a ring's first point repeated at its
    end), views into one array; ``owner`` (len(obstacles),) int64: the index in ``clusters``
    of the cluster each obstacle outlines.  A cluster whose polygons ``max_obstacles`` all
    dropped owns none.
    """
    endpoints = np.asarray(endpoints, dtype=np.float64)
    if endpoints.ndim != 2 or endpoints.shape[1] != 2:
        raise ValueError(f'endpoints must have shape (N, 2), got {endpoints.shape}')
    base = _finite_vector(robot_position, 2, 'robot_position')
    sensor = base if sensor_position is None else _finite_vector(sensor_position, 2,
                                                                 'sensor_position')
    x, y = endpoints[:, 0], endpoints[:, 1]
    reach_sq = (x - base[0]) ** 2 + (y - base[1]) ** 2  # NaN or inf for beams without return
    beams = ((reach_sq > settings.footprint_radius ** 2) & (reach_sq < np.inf)).nonzero()[0]
    if beams.size == 0:
        return ([], np.zeros(0, dtype=np.int64), []) if with_clusters else []
    px, py = x[beams], y[beams]
    wraps = bool(wraps) and beams[0] == 0 and beams[-1] == len(endpoints) - 1
    px, py, links, ring = _chain(px, py, _links(px, py, beams, reach_sq[beams], base, settings,
                                                wraps))
    breaks = (~links).nonzero()[0]
    cluster_first = np.concatenate(([0], breaks + 1))
    cluster_last = np.concatenate((breaks, [len(px) - 1]))
    vertex = np.zeros(len(px), dtype=bool)
    vertex[cluster_first] = vertex[cluster_last] = True
    ends = _split(px, py, vertex.nonzero()[0], base, settings)
    within = links[ends[:-1]]
    lone = cluster_first[cluster_first == cluster_last]
    first = np.concatenate((ends[:-1][within], lone))
    last = np.concatenate((ends[1:][within], lone))
    sizes = cluster_last - cluster_first + 1 - ring
    cluster = cluster_first.searchsorted(first, side='right') - 1
    keep = sizes[cluster] >= settings.min_cluster_points
    first, last = first[keep], last[keep]
    order = first.argsort()
    first, last = first[order], last[order]
    polygons = _rectangles_behind(px[first], py[first], px[last], py[last], sensor, base,
                                  settings)
    nearest = None
    if len(polygons) > settings.max_obstacles:
        nearest = _nearest(polygons, base, settings.max_obstacles)
        polygons, first, last = polygons[nearest], first[nearest], last[nearest]
    polygons = _front(polygons, px, py, first, last, base, settings.footprint_radius)
    obstacles = [Obstacle(polygon=polygon, velocity=STILL, key=f'scan/{index}')
                 for index, polygon in enumerate(polygons)]
    if not with_clusters:
        return obstacles
    return (obstacles, *_clusters(px, py, cluster_first, cluster_last,
                                  sizes >= settings.min_cluster_points,
                                  cluster[keep][order], nearest))


def _clusters(px, py, cluster_first, cluster_last, kept, owner, nearest):
    """Return (owner, clusters) of ``scan_obstacles(..., with_clusters=True)``.

    ``kept``: per cluster, whether ``min_cluster_points`` keeps it; ``owner``: per polygon
    before the ``max_obstacles`` cut (``nearest``: the polygons it keeps, or None), the index
    of its cluster among all clusters, renumbered here among the kept ones.
    """
    points = np.empty((len(px), 2))
    points[:, 0], points[:, 1] = px, py
    points.flags.writeable = False
    renumber = np.cumsum(kept) - 1
    owner = renumber[owner] if nearest is None else renumber[owner[nearest]]
    if not kept.all():
        cluster_first, cluster_last = cluster_first[kept], cluster_last[kept]
    clusters = [points[start:stop] for start, stop in zip(cluster_first.tolist(),
                                                          (cluster_last + 1).tolist())]
    return owner.astype(np.int64, copy=False), clusters


def scan_to_obstacles(ranges, angle_min, angle_increment, range_min, range_max, sensor_pose,
                      robot_pose, settings=DEFAULT_SETTINGS, with_clusters=False):
    """Return the obstacles of one scan: ``beam_endpoints`` then ``scan_obstacles``.

    Arguments as ``beam_endpoints``; a scan that goes round (``scan_wraps``) is joined across
    its seam.  ``with_clusters``: return ``(obstacles, owner, clusters)`` (``scan_obstacles``).
    """
    endpoints = beam_endpoints(ranges, angle_min, angle_increment, range_min, range_max,
                               sensor_pose, robot_pose)
    return scan_obstacles(endpoints, _finite_vector(robot_pose, 3, 'robot_pose')[:2], settings,
                          scan_wraps(len(endpoints), angle_increment), with_clusters,
                          sensor_origin(sensor_pose, robot_pose))


def pose_at(odometry, stamp):
    """Return ``(x, y, yaw)`` of the odometry at ``stamp`` [s]; None when it is empty.

    ``odometry``: samples ``(stamp [s], x, y, yaw)``, in any order.  Between the samples
    stamped last before ``stamp`` and first after it, the pose is interpolated linearly
    (the yaw along the shorter arc), as tf interpolates between transforms: a base at
    2 m/s with odometry at 100 Hz is up to 1 cm from its nearest sample, and a scan placed
    there gives a standing post that much of a jump.  A stamp outside the samples' span
    takes the nearest end (no extrapolation); among samples of one stamp the later one is
    taken (all stamps 0: the latest); a ``stamp`` of 0 (an unstamped scan) takes the latest
    sample.
    """
    if not odometry:
        return None
    if stamp == 0.0:
        return tuple(odometry[-1][1:])
    before = after = None
    for sample in odometry:
        if sample[0] <= stamp and (before is None or sample[0] >= before[0]):
            before = sample
        if sample[0] >= stamp and (after is None or sample[0] <= after[0]):
            after = sample
    if after is None or before is None or before[0] == stamp:
        return tuple((before or after)[1:])
    share = (stamp - before[0]) / (after[0] - before[0])
    turn = math.remainder(after[3] - before[3], math.tau)
    return (before[1] + share * (after[1] - before[1]), before[2] + share * (after[2] - before[2]),
            before[3] + share * turn)
