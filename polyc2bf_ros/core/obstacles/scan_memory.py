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
   odometry frame, with that scan's stamp.
2. A point is dropped when this scan could have seen it: its bearing from the sensor lies
   within the beams' span (widened by half an increment on each side) and its range within
   ``[range_min, range_max]``.  It is also dropped when it is older than ``keep_time``.
3. The rest within ``reach`` of the sensor is drawn as the laser would see it from here:
   by bearing, in bins of the scan's increment from the blind sector's first bearing on,
   the nearest point per bin, in bearing order.  ``scan_obstacles`` turns them into
   obstacles (linked by distance alone, as neighbouring beams), standing still.  A point
   farther away is kept, not drawn: the robot may back towards it.  (Measured: dropped
   for good once beyond ``reach``, a post last seen 2.2 m away was gone when a Jackal,
   pushed back by the filter, reversed 2 m onto it; BARN world 4 from the laser.)

Limits.  Points live in the odometry frame, so they drift with odometry (``keep_time``
bounds that); a standing object that leaves the view and then moves away stays a phantom
behind the robot until it ages out, which only keeps the robot from turning or backing into
where it was.  A point hidden in the view behind a nearer object is dropped like a seen one.
Only a scan with a blind sector keeps anything.  Kept points are drawn reaching
``depth`` away from where the laser is now, not behind the surface they were seen on: a
post kept from its far side (the robot drove or turned round it) is drawn on that side
only, and its side facing the robot, never lit, is open.  (Measured: BARN world 280 from
the laser, go-to-goal, a Jackal box backing round a post at 0.05 m/s grazed it by 1 mm with
its rear corner; ``test_scan_memory.py`` holds the case as an expected failure.)
"""
import math
from typing import NamedTuple

import numpy as np

from polyc2bf_ros.core.obstacles.scan_conversion import FULL_TURN, scan_obstacles


class ScanView(NamedTuple):
    """Where one scan looked, in the odometry frame.

    ``x``, ``y`` [m], ``yaw`` [rad]: the sensor; ``first``, ``last`` [rad]: the lowest and
    highest beam bearing in the sensor frame; ``step`` [rad] > 0: the increment's size;
    ``range_min``, ``range_max`` [m]; ``base``: (x, y) of the robot's base.
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

    def blind(self):
        """Return True when the beams leave a sector unseen (less than a full turn)."""
        return self.last - self.first + 2.0 * self.step < FULL_TURN

    def bearings(self, points):
        """Return (ranges, bearings after the view's last beam in [0, 2 pi)) of (n, 2) points."""
        dx, dy = points[:, 0] - self.x, points[:, 1] - self.y
        after = (np.arctan2(dy, dx) - self.yaw - self.last - 0.5 * self.step) % FULL_TURN
        return np.hypot(dx, dy), after

    def unseen(self, ranges, after):
        """Return (n,) True where no beam of this scan reaches a point (module step 2).

        ``ranges``, ``after``: the points' ``bearings``.
        """
        blind = FULL_TURN - (self.last - self.first + self.step)
        return ((after < blind) | (ranges < self.range_min) | (ranges > self.range_max))


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
        self._last = (np.zeros((0, 2)), 0.0)

    def __len__(self):
        """Return the number of points kept."""
        return len(self._points)

    def update(self, stamp, view, standing, settings):
        """Take one scan; return the obstacles of what it cannot see and was seen before.

        ``stamp`` [s]; ``view``: its ``ScanView``; ``standing``: (n, 2) odometry-frame
        endpoints of its standing clusters (joining the memory at the next scan);
        ``settings``: its ``ScanSettings``.  Obstacles are keyed ``scan/<i>``.
        """
        last, last_stamp = self._last
        self._last = (np.asarray(standing, dtype=np.float64).reshape(-1, 2), float(stamp))
        if not view.blind():
            self._points, self._stamps = np.zeros((0, 2)), np.zeros(0)
            return []
        points = np.concatenate((self._points, last))
        stamps = np.concatenate((self._stamps, np.full(len(last), last_stamp)))
        age = stamp - stamps
        ranges, after = view.bearings(points)
        keep = view.unseen(ranges, after) & (age >= 0.0) & (age <= self.keep_time)
        self._points, self._stamps = points[keep], stamps[keep]
        near = keep & (ranges <= self.reach)
        if not near.any():
            return []
        points, ranges, after = points[near], ranges[near], after[near]
        bins = np.floor(after / view.step).astype(np.int64)
        order = np.lexsort((ranges, bins))
        nearest = order[np.concatenate(([True], bins[order][1:] != bins[order][:-1]))]
        return scan_obstacles(points[nearest], view.base, settings)
