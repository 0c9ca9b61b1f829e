"""Keep what a laser saw once it has left the laser's view (numpy, no ROS).

A scan is rebuilt from what it lights.  A laser that sees less than a full turn (BARN's
Jackal carries a Hokuyo UST-10: 270 degrees) forgets a post as soon as the post passes
behind it, and a box that turns sweeps its rear corners through that blind sector.
(Measured: BARN world 46 from the laser, a Jackal at 2 m/s guarding its box, go-to-goal:
the rear-left corner touched a cylinder at 138 degrees from the laser; no scan obstacle lay
within 6.5 cm of it.)  Nav2's obstacle layer keeps its marks until a beam clears them; here
endpoints are kept while no beam can see them.

Per scan of one source, taken at ``stamp`` from ``ScanView`` ``view``:

1. The previous scan's endpoints of standing clusters (not a moving or untrusted track's:
   those the tracker keeps, ``scan_tracker.unseen_obstacles``) join the memory, in the
   odometry frame, with that scan's stamp.  So does each one's back: the point ``depth``
   farther along the beam that lit it, where a scan polygon's far side would be.  Drawn
   from elsewhere later, the backs outline the body behind the lit surface as seen from
   where it was lit.  (Measured: without them, a post kept from its far side, after the
   robot drove or turned round it, was drawn on that side only, reaching away from where
   the laser is now; its side facing the robot, never lit, was open, and a Jackal box
   backing round it grazed it by 1 mm; BARN world 280 from the laser.)
2. A point is dropped when this scan could have seen it: its bearing from the sensor lies
   within the beams' span (widened by half an increment on each side), its range within
   ``[range_min, range_max]``, and one of the two beams either side of its bearing got at
   least that far less ``cluster_tolerance`` (or returned nothing: the beam passed); a
   back, less the larger of ``cluster_tolerance`` and ``depth + split_tolerance``, since
   its own body stops the beams about ``depth`` short of it.  A point both beams stopped
   short of is hidden behind something nearer and is kept, like one in the blind sector.
   (Measured: dropped when hidden, a post that a nearer post hid from the laser was gone
   by the time it passed into the blind sector, and a Jackal box backing at 0.9 m/s
   grazed it by 4 mm; BARN world 119 from the laser.)  It is also dropped when it is
   older than ``keep_time`` and farther than ``reach`` from the sensor.  Near points do
   not age: odometry drifts as the robot drives, not as it stands, and a robot held
   beside a post in its blind sector (a deadlock, then its route) must not forget it.
   (Measured: aged out after 10 s, a post whose lit faces the memory had dropped, and
   whose side facing the robot was never lit, was backed into at 0.87 m/s by a Jackal
   box following a faster route than the shipped one; BARN world 115 from the laser.)
3. The rest within ``reach`` of the sensor is drawn as the laser would see it from here:
   by bearing, in bins of the scan's increment from the blind sector's first bearing on,
   the nearest point per bin, in bearing order.  ``scan_obstacles`` turns them into
   obstacles (linked by distance alone, as neighbouring beams), standing still.  A point
   farther away is kept, not drawn: the robot may back towards it.  (Measured: dropped
   for good once beyond ``reach``, a post last seen 2.2 m away was gone when a Jackal,
   pushed back by the filter, reversed 2 m onto it; BARN world 4 from the laser.)

Limits.  Points live in the odometry frame, so they drift with odometry (``keep_time``
bounds that once the robot has driven away); a standing object that leaves the view, or is
hidden, and then moves away stays a phantom until a beam passes through where it was, or
the robot is farther than ``reach`` from it and it ages out, which only keeps the robot
from turning or backing into that place.  Only a scan with a blind sector keeps
anything.  A body is taken as ``depth`` thick along the beams that lit it: a thinner one
leaves a phantom behind it, a thicker one (a BARN post is 0.15 m across, against the
default 0.10) may reach past its backs on the side never lit.
"""
import math
from typing import NamedTuple

import numpy as np

from polyc2bf_ros.core.obstacles.scan_conversion import FULL_TURN, scan_obstacles, sensor_origin


class ScanView(NamedTuple):
    """Where one scan looked, in the odometry frame.

    ``x``, ``y`` [m], ``yaw`` [rad]: the sensor; ``first``, ``last`` [rad]: the lowest and
    highest beam bearing in the sensor frame; ``step`` [rad] > 0: the increment's size;
    ``range_min``, ``range_max`` [m]; ``base``: (x, y) of the robot's base; ``ranges``:
    the beams' ranges [m] from ``first`` to ``last`` (None: every beam reached as far as
    ``range_max``).
    """

    x: float
    y: float
    yaw: float
    first: float
    last: float
    step: float
    range_min: float
    range_max: float
    base: tuple
    ranges: object = None

    @classmethod
    def of_scan(cls, robot_pose, sensor_pose, angle_min, increment, ranges, range_min,
                range_max):
        """Return the view of a scan: ``ranges`` in beam order from ``angle_min`` by ``increment``.

        Taken by a sensor at ``sensor_pose`` (x, y, yaw in the base frame) on a base at
        ``robot_pose`` (odometry frame); a negative increment is turned round.
        """
        last = angle_min + (len(ranges) - 1) * increment
        return cls(*sensor_origin(sensor_pose, robot_pose), robot_pose[2] + sensor_pose[2],
                   min(angle_min, last), max(angle_min, last), abs(increment), range_min,
                   range_max, tuple(robot_pose[:2]), ranges if increment > 0 else ranges[::-1])

    def blind(self):
        """Return True when the beams leave a sector unseen (less than a full turn)."""
        return self.last - self.first + 2.0 * self.step < FULL_TURN

    def bearings(self, points):
        """Return (ranges, bearings after the view's last beam in [0, 2 pi)) of (n, 2) points."""
        dx, dy = points[:, 0] - self.x, points[:, 1] - self.y
        after = (np.arctan2(dy, dx) - self.yaw - self.last - 0.5 * self.step) % FULL_TURN
        return np.hypot(dx, dy), after

    def unseen(self, ranges, after, tolerance):
        """Return (n,) True where no beam of this scan reaches a point (module step 2).

        ``ranges``, ``after``: the points' ``bearings``; ``tolerance`` [m]: how far short
        of a point a beam may stop and still count as having seen it.
        """
        outside, below, above = self._beams_either_side(ranges, after)
        reach = ranges - tolerance
        return outside | ((below < reach) & (above < reach))

    def seen_through(self, ranges, after, tolerance):
        """Return (n,) True where both beams either side of a point passed it by ``tolerance``.

        The point lies in space this scan saw empty (a beam without a return passed);
        ``ranges``, ``after`` as ``unseen``'s; ``tolerance`` [m] scalar or (n,).
        """
        outside, below, above = self._beams_either_side(ranges, after)
        reach = ranges + tolerance
        return ~outside & (below > reach) & (above > reach)

    def _beams_either_side(self, ranges, after):
        """Return (outside the beams' span or range, range of the beam below, of the beam above).

        Per point; a beam without a return (NaN, out of range, 0) reached inf; with no
        ``ranges`` every beam did.
        """
        blind = FULL_TURN - (self.last - self.first + self.step)
        outside = (after < blind) | (ranges < self.range_min) | (ranges > self.range_max)
        if self.ranges is None:
            everywhere = np.full(len(ranges), np.inf)
            return outside, everywhere, everywhere
        beams = np.asarray(self.ranges, dtype=np.float64)
        # Fractional beam index of each bearing: after - blind runs from 0 at half an
        # increment before the first beam to N increments after it.
        index = np.clip((after - blind) / self.step - 0.5, 0.0, len(beams) - 1)
        below = np.floor(index).astype(np.int64)
        above = np.minimum(below + 1, len(beams) - 1)
        stopped = np.where((beams > 0.0) & (beams >= self.range_min) & (beams <= self.range_max),
                           beams, np.inf)
        return outside, stopped[below], stopped[above]


class ScanMemory:
    """The endpoints one scan source saw that are out of its view now (module docstring).

    ``keep_time`` [s] > 0 as in step 2, ``reach`` [m] > 0 as in step 3.
    """

    def __init__(self, keep_time, reach):
        """Start with nothing seen."""
        for name, value in (('keep_time', keep_time), ('reach', reach)):
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f'{name} must be a finite number > 0, got {value!r}')
        self.keep_time, self.reach = float(keep_time), float(reach)
        self._points = np.zeros((0, 2))
        self._stamps = np.zeros(0)
        self._backs = np.zeros(0, dtype=bool)  # per point: a back (module step 1)
        self._last = (np.zeros((0, 2)), np.zeros(0, dtype=bool), 0.0)

    def __len__(self):
        """Return the number of points kept."""
        return len(self._points)

    def update(self, stamp, view, standing, settings):
        """Take one scan; return the obstacles of what it cannot see and was seen before.

        ``stamp`` [s]; ``view``: its ``ScanView``; ``standing``: (n, 2) odometry-frame
        endpoints of its standing clusters (joining the memory at the next scan);
        ``settings``: its ``ScanSettings``.  Obstacles are keyed ``scan/<i>``.
        """
        last, last_backs, last_stamp = self._last
        self._last = (*_with_backs(standing, view, settings.depth), float(stamp))
        if not view.blind():
            self._points, self._stamps = np.zeros((0, 2)), np.zeros(0)
            self._backs = np.zeros(0, dtype=bool)
            return []
        points = np.concatenate((self._points, last))
        stamps = np.concatenate((self._stamps, np.full(len(last), last_stamp)))
        backs = np.concatenate((self._backs, last_backs))
        age = stamp - stamps
        ranges, after = view.bearings(points)
        back_tolerance = max(settings.cluster_tolerance,
                             settings.depth + settings.split_tolerance)
        tolerance = np.where(backs, back_tolerance, settings.cluster_tolerance)
        within = ranges <= self.reach
        keep = (view.unseen(ranges, after, tolerance) & (age >= 0.0)
                & ((age <= self.keep_time) | within))
        self._points, self._stamps, self._backs = points[keep], stamps[keep], backs[keep]
        near = keep & within
        if not near.any():
            return []
        points, ranges, after = points[near], ranges[near], after[near]
        bins = np.floor(after / view.step).astype(np.int64)
        order = np.lexsort((ranges, bins))
        nearest = order[np.concatenate(([True], bins[order][1:] != bins[order][:-1]))]
        return scan_obstacles(points[nearest], view.base, settings,
                              sensor_position=(view.x, view.y))


def _with_backs(points, view, depth):
    """Return ``points`` seen from ``view`` with their backs, and which rows are backs.

    (2n, 2): the points, then each moved ``depth`` along its beam; (2n,) bool: True for
    the backs.  The backs stand for the body's far side (module
    step 1), as a scan polygon reaches ``depth`` behind the surface it outlines.
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    rays = points - (view.x, view.y)
    lengths = np.hypot(rays[:, 0], rays[:, 1])
    backs = points + rays * (depth / np.maximum(lengths, 1e-9))[:, None]
    return np.concatenate((points, backs)), np.repeat((False, True), len(points))
