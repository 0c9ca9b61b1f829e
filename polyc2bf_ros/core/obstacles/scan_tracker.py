"""Track laser-scan clusters over time and give moving ones a velocity (numpy, no ROS).

Input per scan: its stamp and its clusters (``scan_obstacles(..., with_clusters=True)``: the
endpoints of each cluster in chain order, odometry frame).  Output: one ``TrackEstimate`` per
cluster, in the same order.  One tracker serves every scan source; a stamp earlier than the
newest seen by more than ``max_backstep`` (a bag loop, a simulation reset) resets it, a
smaller step back is taken as no time passing.

Each track has a constant-velocity Kalman filter with a clone (``constant_velocity``: state
``[p, v, c]``, c the position when the track took its outline, the points of the cluster it
last matched).  Per scan, with ``dt`` the time since the newest stamp:

1. Predict every filter by ``dt`` (white-noise acceleration of spectral density
   ``accel_std^2``).  A track's predicted displacement since its outline is ``d0 = p - c``.
2. Associate.  A track's predicted box is its outline's bounding box moved by ``d0``; a
   cluster may pair with it when the boxes are at most ``gate`` apart and both or neither
   are structure (below), at a cost of the mean distance between their corresponding
   corners (a stray point near a box costs its distance to both corners; a centroid would
   move with the lit side).  Pairs that are each other's only candidate go together; the
   rest is solved by ``scipy.optimize.linear_sum_assignment`` on squared costs, where a
   track or a cluster may also stay unpaired at ``gate^2`` (so that no pair is forced).
3. Measure the displacement d: translation-only point-to-line registration (ICP) of the new
   cluster onto the track's outline.  Both are first smoothed alike: each point is replaced
   by the centroid c of its window, the run of chain neighbours symmetric about it whose
   ends lie within ``span`` of each other, and given the unit tangent t of the chord across
   that window without the point itself (so that its range noise does not tilt its own
   line).  A window cut short by an end of the chain is not used (the ends of a cluster move
   as the view changes), nor one where the chain turns by more than 45 degrees (a corner,
   whose line is ambiguous).  Smoothing divides the range noise by about the square root of
   the window's size, and a window's curvature bias (its centroid lies ``w^2 / (6 rho)``
   inside an arc of radius rho for a half-width w) is the same on both sides and cancels.
   Each new centroid (every k-th one, weighted by k, where windows are dense: k = a third of
   the mean window size, for neighbouring centroids share most of their points), moved by
   ``-d``, pairs with the outline centroid ``c_j`` nearest it (searched along the outline
   from the previous pair) and its residual is its distance to that centroid's line,
   ``r_i = n_j . (c_i - d - c_j)``, n the normal.  A pair is trimmed
   when ``|r_i|`` exceeds the trim distance: ``reach`` at the first iteration (``trim`` plus
   3 sigma of the predicted displacement, at most ``gate``), halving down to ``trim``.
   Gauss-Newton from ``d0`` (and, while the prediction is uncertain, its standard deviation
   above ``trim`` as in a young track, also from the shift of the boxes' centres, keeping the
   start that pairs more points)::

       A = sum n_j n_j^T,   g = sum n_j r_i,   (A + lambda I) delta = g - lambda (d - d0)

   (``lambda = 1e-3``, a thousandth of one point's information, keeps unmeasured directions
   at ``d0``), up to ``iterations`` times with new pairs, until a step under 0.1 mm.  It
   fails with fewer than 3 pairs or fewer than ``min_overlap`` of the smaller side's usable
   windows.  Rest is tested last: a displacement longer than ``trim`` gives way to the
   registration from d = 0 (first trim distance ``trim``) when that keeps at least as many
   pairs at most ``REST_VARIANCE`` times the residual variance.  (A row of small posts, as
   BARN's, matches itself shifted by one post: a standing row so registered got 2.4 m/s in
   one scan, its track then failed every later registration and kept that velocity, and
   the robot drove into the row.)

   Its information.  A smoothed residual's variance is ``sigma^2 (1 / m_i + 1 / m_j)`` for
   window sizes m and range noise sigma, so ``sigma^2 = max(point_std^2, sum r^2 / sum(1 /
   m_i + 1 / m_j) k / (k - 2))`` over the k pairs.  A normal taken from a chord of length l
   between two noisy points turns by about ``sqrt(2) sigma / l``, which lends A spurious
   information along the outline, where a straight wall has none; that expected leak ``L =
   sum 2 sigma^2 / l_j^2 t_j t_j^T`` is removed twice over, and eigenvalues of ``A - 2 L``
   below 2 (two points' worth) are set to 0: H.  The filter then takes d as a displacement,
   ``d = p - c`` (``update_relative``), with covariance ``R = sigma^2 (H + lambda I)^-1``,
   and its clone restarts at p.  Along a straight wall H is 0 and R huge, so the wall's
   velocity along itself keeps its prior, 0.  When H measures one direction only (a wall, a
   box face-on) the update moves the filter along that direction only (``free``, a consider
   update): the registration measures along the face's true normal, not along its noisy
   estimate, and the estimate's wobble from scan to scan would otherwise let the filter read
   the along-face velocity out of noise.  Not the centroid of the raw cluster: a wall passed
   by a moving robot, or a cylinder whose lit side turns as the robot drives round it, moves
   its centroid without moving (``test_scan_tracker`` measures such a centroid's speed).
   (Measured on simulated scans with 1 cm range noise: displacement errors 2-3 mm per scan,
   their normalised squares averaging 0.7-0.9, so R is honest.)  A failed registration leaves
   the filter predicted and restarts the clone.
4. Classify.  The known velocity ``v`` is the filter's without its components along
   eigenvectors of ``P_vv`` whose standard deviation exceeds ``max_velocity_std``;
   ``sigma_v = sqrt(v^T P_vv v) / |v|`` is its standard deviation along itself.  A
   registration passes when ``|v| > max(moving_speed, n_sigma sigma_v)``; after
   ``moving_scans`` successive registrations that pass, the track is moving, after as many
   that do not (a failed registration does not pass), it is still again.  The published
   velocity is v for a confirmed moving track and exactly 0 otherwise; ``with_velocities``
   gives it to the obstacles of the cluster.
   (Along v, not along the worst axis: a box seen face-on is measured only across its face,
   and its approach speed is known though its sideways speed is not.)
   A standing track must also show that it moved, not only register so: at least
   ``EVIDENCE_POINTS`` of its cluster's points lie where the oldest scan kept (at most
   ``evidence_age`` s back, ``ScanView.seen_through``) saw empty space, or as many of its
   track's points in that scan lie where this scan sees through, by the points' noise
   (3 sigma of two scans' ``point_std``, ``pose_std`` and ``heading_std`` at their range).
   An object that moves fills space that was seen empty or empties space that was seen
   filled; a standing one seen from elsewhere does neither, however its lit side and its
   registration change.  (Measured, BARN from the laser, a Jackal at 2 m/s: posts a few cm
   beside the box, their lit arcs turning as it passed, registered at 0.2-0.3 m/s with a
   velocity std of 0.08 m/s, became untrusted moving tracks, and the braking check, allowing
   them ``scan_unknown_speed``, refused every input, standing still included: the box stood
   until the run timed out.)  A moving track keeps moving without it: the test is for
   starting to move.
5. Trust.  A track that has been moving (step 4) within the last ``distrust_time`` s is
   trusted only while its last ``trust_scans`` registrations each paired at least
   ``trust_share`` of the cluster's whole windows; a registration that fails or explains
   less ends the streak.  An untrusted track's velocity, 0 or not, may be wrong by
   anything: its registrations fail (it took another object's cluster), or its cluster
   holds more than the outline it follows (two objects that meet make one cluster, which
   keeps one track and one velocity, and the one that is not followed may come at the
   robot).  The obstacle pipeline gives its obstacles an unknown velocity
   (``scan_unknown_speed``), which the braking check allows for.  Every other track
   (standing structure, clutter, a post seen for the first time) is trusted as before:
   its view grows and shrinks as the robot drives, so its registrations often explain
   less than ``trust_share``, and distrusting every young or short track kept the robot
   off BARN's posts (57 % of 30 worlds from scans instead of 100 %); a single
   registration fast enough to pass step 4 is no better a sign (standing posts pass now
   and then: 93-95 % of BARN).  Nor is a track that was moving long ago: a row of BARN's
   posts, once misregistered into a moving track, kept a robot off it for good.
   (Measured in the dynamic suite from scans: the 9 at-fault contacts came from merged or
   failing moving tracks, and none is left.)
   Nor can a trusted moving track promise that nothing else moves behind or inside its
   cluster: a cylinder hidden there comes out as a new track, published still until it has
   been registered moving, or inside the cluster, each often under a second before it
   reaches the robot.  So a track born within ``beside_mover`` of a moving track's
   predicted box counts as moving at birth: it is untrusted until ``trust_scans``
   registrations explain it, as after a merge.  And ``with_velocities`` gives a moving
   track's obstacles an unknown velocity too (``scan_hidden_speed``), as does
   ``unseen_obstacles`` to a moving track the scan misses (its cluster may come back as a
   new track).  (Measured from scans on three seeds of the dynamic suite, 60 worlds each,
   with neither: 0, 3 and 6 at-fault contacts.  The birth rule alone: 0, 0 and 1, the last
   a cylinder passing through the cluster the robot followed.  With both, at 1 m/s: none
   on five seeds.)  The same unknown velocity stays on a confirmed track for
   ``distrust_time`` after it was last moving (``TrackEstimate.moved_lately``), though it
   publishes 0: two movers that meet in one cluster register as one outline whose
   displacement averages theirs, and the track can fall below ``moving_speed`` and be
   trusted again while one of them still comes on.  (Measured: dynamic world 16 of
   generator seed 2029, from scans; a cylinder at 0.6 m/s published still and trusted for
   0.8 s, and the robot sped up into it, at fault.)

Birth, confirmation, deletion.  A cluster no track takes starts a track at its centroid
(position variance ``point_std^2``, velocity ``speed_std`` per axis) with one hit; each
successful registration is a hit, and a track is confirmed from ``confirm_hits`` hits on.  A
track not matched for more than ``max_coast`` seconds is dropped; until then a confirmed
moving one stays an obstacle where its prediction puts it (``unseen_obstacles``).  A
cluster whose bounding box's diagonal exceeds ``static_extent`` is structure: its track is
matched, but neither registered nor classified (it keeps no outline), and publishes 0.
Why: such clusters are walls and room corners (or objects linked to them); a phantom
velocity on the wall beside the robot would let the filter drive into it, while moving
objects that large are outside what this tracker is for; they hold most of a scan's
points, so skipping them keeps the cost down; and keeping them away from small tracks keeps
the room's box, which overlaps every object in it, out of every assignment.

Accuracy (1081-beam scans at 10-20 Hz, ``test_scan_tracker``): a box or cylinder 2-4 m
away moving at 0.3-2 m/s, seen from a robot standing or driving, gets its velocity within
0.1 m/s from the fourth scan on with 5 mm range noise (the largest error in 40 random runs:
0.055 m/s); with 1 cm noise the error is about 0.05 m/s rms and exceeded 0.1 m/s on 3 scans
in 820.  A person accelerating at 1.5 m/s^2 is followed about 0.1 m/s behind.  Standing
objects seen from a robot driving at up to 2 m/s and turning at up to 1 rad/s stay below
``moving_speed`` (their filter's velocity peaks near 0.1 m/s with 1 cm noise), so they
publish 0.

Limits.  Clusters, not objects, are tracked: an object within ``cluster_tolerance`` of
another (a person beside a wall) shares its cluster and track and loses its velocity until
they part; of a cluster that splits, the part nearest the prediction keeps the track and the
others start new ones, which publish after ``confirm_hits`` and ``moving_scans`` more scans.
An outline shorter than ``span`` has no whole window and is never measured (it publishes 0);
a box seen face-on publishes its velocity across the face only.  The measurement is a
translation: a turning object registers with a small bias.  Several scan sources share the
tracks, so a source that sees another side of an object registers it against the other
source's outline (trimmed to their overlap).  A scan is not de-skewed.  A velocity that
changes abruptly (a bounce) takes about a second to follow.

Cost.  Two compiled kernels per scan, ``_gate`` (cluster boxes, prediction, gated costs,
unique pairs, the padded matrix) and ``_advance`` (smoothing, in linear time and once per
cluster, registration, filter update, classification, births, deletion, outlines), about
thirty numpy calls around them, the evidence of step 4 in numpy (about 0.18 ms a scan with
30 objects, half the tracker's time: the first thing to compile if it must get cheaper),
and ``linear_sum_assignment`` with ``_assign`` only when pairs are ambiguous:
``bench/bench_tracking.py``.  ``scipy.optimize`` (about half a second
to import on the benchmark VM) is imported by the first ``ScanTracker`` made, not with this
module.
"""
import collections
import dataclasses
import math
import numbers
from dataclasses import dataclass
from itertools import repeat
from typing import NamedTuple

import numpy as np

from polyc2bf_ros.core.kernels.tracking import (
    _advance,
    _assign,
    _gate,
    _known_velocity,
    ACCEL,
    BESIDE,
    COAST,
    CONFIRM,
    DISTRUST,
    EXTENT,
    FIRST,
    GATE,
    HEADING,
    HITS,
    ID,
    ITERATIONS,
    KNOWN,
    LINK,
    MOVING,
    MOVING_SPEED,
    ORIGIN_X,
    ORIGIN_Y,
    OVERLAP,
    PARAMETERS,
    POINT,
    POSE,
    SCANS,
    SEEN,
    SHARE,
    SIGMAS,
    SIZE,
    SPAN,
    SPEED,
    TRACK_FLOATS,
    TRACK_INTS,
    TRIM,
    TRUSTED,
)
from polyc2bf_ros.core.obstacles.marker_tracker import outline_polygon
from polyc2bf_ros.core.obstacles.obstacle_set import Obstacle

EVIDENCE_POINTS = 3
"""Points that must lie in space the other scan saw empty for evidence of motion (step 4).

More than one: a point at a silhouette's edge may fall between beams of the other scan."""
EVIDENCE_SIGMAS = 3.0
"""Standard deviations of two scans' point noise a point must lie past a beam's return."""
UNSEEN_VERTICES = 8
"""Vertices of an unseen moving track's polygon at most (``unseen_obstacles``)."""
UNSEEN_THICKNESS = 0.05
"""m: the thickness given to an unseen track's outline when it is straight."""
ZERO = np.zeros(2)  # the velocity of every track that is not published: shared, read-only
ZERO.flags.writeable = False


class TrackEstimate(NamedTuple):
    """A cluster's track: its id, published velocity (2,), and the filter's confidence.

    ``velocity`` [m/s]: zeros unless the track is ``confirmed`` and ``moving``;
    ``velocity_std`` [m/s]: the filter's velocity standard deviation along its worst axis;
    ``trusted``: the velocity may be relied on (module docstring, step 5);
    ``moved_lately``: the track was moving within the last ``distrust_time`` s (step 5).
    """

    track_id: int
    velocity: np.ndarray
    velocity_std: float
    confirmed: bool
    moving: bool
    trusted: bool
    moved_lately: bool


@dataclass(frozen=True)
class TrackerSettings:
    """How clusters are tracked (module docstring); checked when made (``validate``).

    - ``gate`` [m] 0.3, > 0: the largest gap between a track's predicted bounding box and a
      cluster's (an object at 2 m/s moves 0.2 m between scans at 10 Hz before its track
      knows its speed).
    - ``accel_std`` [m s^-3/2] 0.3, > 0: the filter's white-noise acceleration, whose
      spectral density ``accel_std^2`` lets the velocity wander 0.3 m/s in a second (one
      sigma).  With 1 cm range noise it follows a person accelerating at 1.5 m/s^2 about
      0.1 m/s behind and holds a constant velocity to about 0.05 m/s (rms); larger values
      follow faster and hold worse.
    - ``speed_std`` [m/s] 2.0, > 0: the velocity's standard deviation at birth.
    - ``point_std`` [m] 0.01, > 0: the least range noise assumed of a point (the noise is
      estimated from the residuals; this keeps noise-free data from being trusted blindly).
    - ``trim`` [m] 0.05, > 0: the final trim distance of a residual.
    - ``span`` [m] 0.1, > 0: the width of the windows an outline is smoothed over and its
      normals taken across (longer: less noise, more of each end unused).
    - ``iterations`` 8, >= 1: Gauss-Newton iterations at most.
    - ``min_overlap`` 0.3, in [0, 1]: the fewest pairs of a registration, as a share of the
      whole windows of the smaller side.
    - ``confirm_hits`` 3, >= 1: hits (birth and successful registrations) to confirm.
    - ``max_coast`` [s] 0.5, >= 0: how long an unmatched track is kept.
    - ``moving_speed`` [m/s] 0.15, >= 0: the least speed of a moving track; standing
      objects are measured well below it.
    - ``n_sigma`` 2.5, >= 0: the least speed of a moving track, in standard deviations.
    - ``moving_scans`` 3, >= 1: successive registrations to start or stop moving.
    - ``max_velocity_std`` [m/s] 0.3, > 0: a velocity component known worse than this is
      not used (taken as 0) to classify or publish.
    - ``static_extent`` [m] 3.0, > 0: clusters with a longer bounding-box diagonal are
      structure.
    - ``trust_share`` 0.9, in [0, 1]: the least share of a cluster's whole windows a
      registration pairs to count towards trust (step 5).
    - ``trust_scans`` 3, >= 1: successive such registrations to trust a track.
    - ``distrust_time`` [s] 2.0, >= 0: how long after it was last moving a track needs
      them (step 5).
    - ``beside_mover`` [m] 1.0, >= 0: a track born this near a moving track's predicted
      bounding box counts as moving at birth (step 5): it may be an object that was hidden
      behind or inside the mover.
    - ``evidence_age`` [s] 0.3, >= 0: how far back the scan lies that a standing track's
      cluster is compared with for evidence that it moved (step 4); the newest scan before
      this one when none is as recent.  Longer: slow movers show more, odometry drifts more.
    - ``max_backstep`` [s] 0.25, >= 0: a stamp this much before the newest resets the
      tracker.
    - ``pose_std`` [m] 0, >= 0, and ``heading_std`` [rad] 0, >= 0: the noise of the
      odometry pose each scan is placed at.  Two scans' poses err independently, so a
      displacement measured between them gains ``2 (pose_std^2 + r^2 heading_std^2)`` of
      variance per axis, r the cluster's range from the sensor (``update``'s ``view``):
      with it, a standing object shaken by the pose noise is not taken for a moving one.
    """

    gate: float = 0.3
    accel_std: float = 0.3
    speed_std: float = 2.0
    point_std: float = 0.01
    trim: float = 0.05
    span: float = 0.1
    iterations: int = 8
    min_overlap: float = 0.3
    confirm_hits: int = 3
    max_coast: float = 0.5
    moving_speed: float = 0.15
    n_sigma: float = 2.5
    moving_scans: int = 3
    max_velocity_std: float = 0.3
    static_extent: float = 3.0
    trust_share: float = 0.9
    trust_scans: int = 3
    distrust_time: float = 2.0
    beside_mover: float = 1.0
    evidence_age: float = 0.3
    max_backstep: float = 0.25
    pose_std: float = 0.0
    heading_std: float = 0.0

    def __post_init__(self):
        """Refuse settings out of range (``validate``)."""
        self.validate()

    def validate(self):
        """Raise ValueError naming the first field out of range, in one line."""
        for name, positive in (('gate', True), ('accel_std', True), ('speed_std', True),
                               ('point_std', True), ('trim', True), ('span', True),
                               ('max_coast', False), ('moving_speed', False),
                               ('n_sigma', False), ('max_velocity_std', True),
                               ('static_extent', True), ('distrust_time', False),
                               ('beside_mover', False), ('evidence_age', False),
                               ('max_backstep', False), ('pose_std', False),
                               ('heading_std', False)):
            value = getattr(self, name)
            if (isinstance(value, bool) or not isinstance(value, numbers.Real)
                    or not math.isfinite(value) or value < 0 or (positive and value == 0)):
                bound = '> 0' if positive else '>= 0'
                raise ValueError(f'{name} must be a finite number {bound}, got {value!r}')
        for name in ('iterations', 'confirm_hits', 'moving_scans', 'trust_scans'):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < 1:
                raise ValueError(f'{name} must be an integer >= 1, got {value!r}')
        for name in ('min_overlap', 'trust_share'):
            value = getattr(self, name)
            if (isinstance(value, bool) or not isinstance(value, numbers.Real)
                    or not 0 <= value <= 1):
                raise ValueError(f'{name} must be a number in [0, 1], got {value!r}')

    def vector(self, link):
        """Return the settings as the kernels read them (``link``: the cluster tolerance)."""
        values = np.zeros(PARAMETERS)  # ORIGIN_X, ORIGIN_Y: set per scan (``update``)
        values[[GATE, ACCEL, SPEED, POINT, TRIM, SPAN, ITERATIONS, OVERLAP, CONFIRM, COAST,
                MOVING_SPEED, SIGMAS, SCANS, KNOWN, EXTENT, LINK, POSE, HEADING, SHARE,
                TRUSTED, DISTRUST, BESIDE]] = (
            self.gate, self.accel_std, self.speed_std, self.point_std, self.trim, self.span,
            self.iterations, self.min_overlap, self.confirm_hits, self.max_coast,
            self.moving_speed, self.n_sigma, self.moving_scans, self.max_velocity_std,
            self.static_extent, link, self.pose_std, self.heading_std, self.trust_share,
            self.trust_scans, self.distrust_time, self.beside_mover)
        return values


DEFAULT_TRACKER_SETTINGS = TrackerSettings()


class ScanTracker:
    """Tracks of scan clusters with constant-velocity estimates (module docstring).

    ``update(stamp, clusters)`` per scan; ``link`` [m]: the scan conversion's
    ``cluster_tolerance`` (how far a paired centroid may lie from its outline centroid
    beyond the trim distance).
    """

    def __init__(self, settings=DEFAULT_TRACKER_SETTINGS, link=0.15):
        """Start with no tracks."""
        settings.validate()
        if not (isinstance(link, numbers.Real) and math.isfinite(link) and link >= 0):
            raise ValueError(f'link must be a finite number >= 0, got {link!r}')
        # scipy.optimize takes about half a second to import: paid by the first tracker made,
        # not by every process that imports this module.
        from scipy.optimize import linear_sum_assignment
        self._solve = linear_sum_assignment
        self.settings = settings
        self._params = settings.vector(float(link))
        self._next_id = np.zeros(1, dtype=np.int64)
        self.reset()

    def reset(self):
        """Drop every track (ids keep counting)."""
        self._stamp = None
        self._count = 0
        # (stamp, ScanView, points, cluster per point, {track id: cluster}) per recent scan
        self._history = collections.deque()
        self._allocate(16)
        self._storage = np.zeros((0, 7))

    def _allocate(self, capacity):
        """Make room for ``capacity`` tracks, keeping the live ones."""
        arrays = (np.zeros((capacity, 6)), np.zeros((capacity, 6, 6)),
                  np.zeros((capacity, TRACK_FLOATS)), np.zeros((capacity, TRACK_INTS),
                                                               dtype=np.int64))
        if self._count:
            for new, old in zip(arrays, (self._states, self._covariances, self._floats,
                                         self._ints)):
                new[:self._count] = old[:self._count]
        self._states, self._covariances, self._floats, self._ints = arrays

    def __len__(self):
        """Return the number of tracks held."""
        return self._count

    def update(self, stamp, clusters, view):
        """Take one scan's clusters at ``stamp`` [s]; return one ``TrackEstimate`` per cluster.

        ``clusters``: (n_i, 2) arrays of points in chain order, n_i >= 1 (``scan_obstacles``
        with ``with_clusters=True``); ``view``: the scan's ``scan_memory.ScanView`` (its
        sensor's position gives ranges for ``heading_std``, its beams the evidence of
        step 4).  Malformed input raises ValueError.
        """
        stamp = float(stamp)
        if not math.isfinite(stamp):
            raise ValueError(f'stamp must be a finite number, got {stamp!r}')
        self._params[ORIGIN_X], self._params[ORIGIN_Y] = view.x, view.y
        if self._stamp is not None and stamp < self._stamp - self.settings.max_backstep:
            self.reset()
        dt = 0.0 if self._stamp is None else max(stamp - self._stamp, 0.0)
        self._stamp = stamp if self._stamp is None else max(stamp, self._stamp)
        history = self._history
        while len(history) > 1 and history[0][0] < stamp - self.settings.evidence_age:
            history.popleft()
        cluster_count = len(clusters)
        starts = np.zeros(cluster_count + 1, dtype=np.int64)
        if cluster_count:
            np.cumsum(np.fromiter(map(len, clusters), dtype=np.int64, count=cluster_count),
                      out=starts[1:])
            points = np.concatenate(clusters).astype(np.float64, order='C', copy=False)
            if points.ndim != 2 or points.shape[1] != 2:
                raise ValueError('clusters must be non-empty (n, 2) arrays of finite numbers')
        else:
            points = np.zeros((0, 2))
        count = self._count
        if count + cluster_count > len(self._states):
            self._allocate(2 * (count + cluster_count))
        stats = np.empty((cluster_count, 6))
        structure = np.empty(cluster_count, dtype=bool)
        cost = np.empty((count, cluster_count))
        match = np.empty(count, dtype=np.int64)
        claimed = np.empty(cluster_count, dtype=np.int64)
        rows = np.empty(count, dtype=np.int64)
        columns = np.empty(cluster_count, dtype=np.int64)
        padded = np.empty((count + cluster_count) ** 2)
        ambiguous, width = _gate.unchecked(points, starts, self._states, self._covariances,
                                           self._floats, count, dt, self._params, stats,
                                           structure, cost, match, claimed, rows, columns,
                                           padded)
        if ambiguous < 0:
            raise ValueError('clusters must be non-empty (n, 2) arrays of finite numbers')
        if ambiguous:
            size = ambiguous + width
            chosen_rows, chosen_columns = self._solve(padded[:size * size].reshape(size, size))
            _assign.unchecked(chosen_rows, chosen_columns, rows, columns, ambiguous, width,
                              padded, match, claimed)
        owners = np.repeat(np.arange(cluster_count), np.diff(starts))  # cluster per point
        evidence = self._evidence(points, owners, structure, claimed, view)
        storage = np.empty((len(points) + len(self._storage), 7))
        out = np.empty((cluster_count, 3))
        flags = np.empty((cluster_count, 5), dtype=bool)
        ids = np.empty(cluster_count, dtype=np.int64)
        self._count, used = _advance.unchecked(
            points, starts, stats, structure, evidence, match, claimed, self._states,
            self._covariances, self._floats, self._ints, count, stamp, self._params,
            self._storage, storage, self._next_id, out, flags, ids)
        self._storage = storage[:used]
        history.append((stamp, view, points, owners,
                        dict(zip(ids.tolist(), range(cluster_count)))))
        velocities = out[:, :2]
        velocities.flags.writeable = False
        published = flags[:, 2].nonzero()[0].tolist()
        shown = [ZERO] * cluster_count
        for c in published:
            shown[c] = velocities[c]
        # tuple.__new__ straight from C: a NamedTuple's own constructor is a Python call.
        return list(map(tuple.__new__, repeat(TrackEstimate),
                        zip(ids.tolist(), shown, out[:, 2].tolist(), flags[:, 0].tolist(),
                            flags[:, 1].tolist(), flags[:, 3].tolist(), flags[:, 4].tolist())))

    def _evidence(self, points, owners, structure, claimed, view):
        """Return (clusters,) True where a cluster shows that it moved (module step 4).

        Against the oldest scan in the history, for the clusters that need it: those a
        standing track took (``claimed``: each cluster's track row, -1 for none), structure
        left out.  ``owners``: each point's cluster.
        """
        count = len(claimed)
        evidence = np.zeros(count, dtype=bool)
        tested = (claimed >= 0) & ~structure
        if not self._history or not tested.any():
            return evidence
        tested[tested] = self._ints[claimed[tested], MOVING] == 0
        if not tested.any():
            return evidence
        _, before, old_points, old_owners, old_clusters = self._history[0]
        chosen = tested[owners]
        ranges, after = before.bearings(points[chosen])
        filled = before.seen_through(ranges, after, self._noise(ranges))
        rows = tested.nonzero()[0]
        evidence[rows] = (np.bincount(owners[chosen], weights=filled, minlength=count)[rows]
                          >= EVIDENCE_POINTS)
        earlier = np.array([old_clusters.get(i, -1) for i in
                            self._ints[claimed[rows], ID].tolist()], dtype=np.int64)
        seen = earlier >= 0
        if seen.any():
            kept = np.zeros(len(old_clusters), dtype=bool)
            kept[earlier[seen]] = True
            chosen = kept[old_owners]
            ranges, after = view.bearings(old_points[chosen])
            emptied = view.seen_through(ranges, after, self._noise(ranges))
            old_counts = np.bincount(old_owners[chosen], weights=emptied,
                                     minlength=len(old_clusters))
            evidence[rows[seen]] |= old_counts[earlier[seen]] >= EVIDENCE_POINTS
        return evidence

    def _noise(self, ranges):
        """Return how far past a beam's return points at ``ranges`` [m] may lie by noise."""
        settings = self.settings
        return EVIDENCE_SIGMAS * np.sqrt(2.0 * (settings.point_std ** 2 + settings.pose_std ** 2
                                                + (ranges * settings.heading_std) ** 2))

    def unseen_moving(self):
        """Return (outline (k, 2), velocity (2,)) of each moving track the last scan missed.

        A confirmed moving track that no cluster of the newest scan took (hidden behind or
        inside another object, out of view, or merged into another track's cluster) is
        kept for up to ``max_coast`` s; here its outline (the smoothed centroids it last
        matched) is moved to its predicted position, ``+ p - c``, with its known velocity.
        (Moving cylinders that pass through each other merge into one cluster that keeps
        one track's velocity; the other, unpublished, came out of it at the robot.)
        """
        count, known = self._count, self._params[KNOWN]
        if not count:
            return []
        ints, floats = self._ints[:count], self._floats[:count]
        unseen = ((floats[:, SEEN] < self._stamp) & (ints[:, MOVING] == 1)
                  & (ints[:, HITS] >= self._params[CONFIRM]) & (ints[:, SIZE] > 0))
        result = []
        for t in unseen.nonzero()[0].tolist():
            state, first = self._states[t], ints[t, FIRST]
            outline = self._storage[first:first + ints[t, SIZE], :2] + (state[:2] - state[4:6])
            result.append((outline, np.array(_known_velocity(state, self._covariances[t],
                                                             known))))
        return result

    def tracks(self):
        """Return (ids (T,), states (T, 4), covariances (T, 4, 4)) of the tracks held (copies).

        States are [x, y, vx, vy] (the filter's, the clone left out).
        """
        count = self._count
        return (self._ints[:count, ID].copy(), self._states[:count, :4].copy(),
                self._covariances[:count, :4, :4].copy())


def with_velocities(obstacles, owner, estimates, unknown_speed=0.0, hidden_speed=0.0):
    """Return the scan's obstacles with what their clusters' tracks say of their velocity.

    ``obstacles``, ``owner``: from ``scan_to_obstacles(..., with_clusters=True)``;
    ``estimates``: ``ScanTracker.update`` of its clusters.  An obstacle of a published
    track gets velocity ``(vx, vy, 0)`` and ``velocity_error`` (``Obstacle.velocity_error``)
    ``hidden_speed`` [m/s]: a moving cluster may hide another object behind or inside it
    (step 5), and so may a confirmed track that moved within ``distrust_time`` and now
    publishes 0 (two movers merged into its cluster register as one outline whose
    displacement averages theirs out).  One of an untrusted track (step 5) gets
    ``unknown_speed`` [m/s] (the larger of the two when both hold); the others are returned
    as they are (the shared zero velocity).
    """
    changed = {}
    for index, estimate in enumerate(estimates):
        published = estimate.moving and estimate.confirmed and estimate.velocity.any()
        # A moving track has moved lately: this holds for every published one too.
        hiding = estimate.confirmed and estimate.moved_lately
        error = max(hidden_speed if hiding else 0.0,
                    0.0 if estimate.trusted else unknown_speed)
        if published or error > 0.0:
            changed[index] = (estimate.velocity if published else ZERO, float(error))
    if not changed:
        return list(obstacles)
    result = []
    for obstacle, index in zip(obstacles, owner.tolist()):
        change = changed.get(index)
        if change is not None:
            velocity = np.zeros(3)
            velocity[:2] = change[0]
            velocity.flags.writeable = False
            obstacle = dataclasses.replace(obstacle, velocity=velocity,
                                           velocity_error=change[1])
        result.append(obstacle)
    return result


def unseen_obstacles(tracker, prefix='', velocity_error=0.0):
    """Return obstacles for the moving tracks the last scan missed (``unseen_moving``).

    Each is its outline's enclosing polygon (at most ``UNSEEN_VERTICES`` vertices; a
    straight outline ``UNSEEN_THICKNESS`` thick) with the track's velocity and
    ``velocity_error`` [m/s] (``Obstacle.velocity_error``: what a moving track may hide,
    ``with_velocities``), keyed ``<prefix>unseen/<i>``; an outline that makes no polygon
    is left out.
    """
    result = []
    for index, (outline, velocity) in enumerate(tracker.unseen_moving()):
        try:
            polygon = outline_polygon(outline, UNSEEN_THICKNESS, UNSEEN_VERTICES)
        except ValueError:
            continue
        result.append(Obstacle(polygon=polygon, velocity=np.array([*velocity, 0.0]),
                               key=f'{prefix}unseen/{index}',
                               velocity_error=float(velocity_error)))
    return result
