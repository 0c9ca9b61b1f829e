"""Tracked scan obstacles (polyc2bf_ros.core.obstacles.scan_tracker), on ray-cast scans.

Scans are 1081 beams over 270 degrees (``scan_simulator``), turned into clusters by
``scan_to_obstacles(..., with_clusters=True)`` and fed to a ``ScanTracker`` at 10 or 20 Hz.
The truth (each object's velocity) comes from the simulation, never from the tracker.
"""
import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from polyc2bf_ros.core.kernels.tracking import register_outline
from polyc2bf_ros.core.obstacles.scan_conversion import (
    beam_endpoints,
    scan_obstacles,
    scan_to_obstacles,
    scan_wraps,
    ScanSettings,
)
from polyc2bf_ros.core.obstacles.scan_memory import ScanView
from polyc2bf_ros.core.obstacles.scan_tracker import (
    ScanTracker,
    TrackerSettings,
    TrackEstimate,
    unseen_obstacles,
    with_velocities,
)
from scan_simulator import box, sensor_pose_in_world, simulate_ranges
from strategies import examples

BEAMS = 1081
ANGLE_MIN, INCREMENT = math.radians(-135.0), math.radians(0.25)
RANGE_MIN, RANGE_MAX = 0.05, 30.0
SCAN = ScanSettings(footprint_radius=0.3)
SETTLED = 3
"""From this scan on (the fourth) a moving object's published velocity is within 0.1 m/s."""
SIMULATIONS = settings(max_examples=examples(16), deadline=None)
AROUND = ScanView(0.0, 0.0, 0.0, -math.pi, math.pi - INCREMENT, INCREMENT, RANGE_MIN, RANGE_MAX,
                  (0.0, 0.0))
"""A full turn whose beams all passed: the view of hand-made clusters."""


def _clusters(pose, polygons=(), circles=(), noise=0.0, rng=None, settings=SCAN, placed=None):
    """Return (obstacles, owner, clusters, view) of the scan a robot at ``pose`` takes.

    ``placed``: the pose the scan is placed at (default ``pose``; noisy odometry); the
    sensor sits at the base.
    """
    ranges = simulate_ranges(sensor_pose_in_world(pose), BEAMS, ANGLE_MIN, INCREMENT, RANGE_MAX,
                             polygons, circles, noise, rng)
    placed = pose if placed is None else placed
    view = ScanView(placed[0], placed[1], placed[2], ANGLE_MIN,
                    ANGLE_MIN + (BEAMS - 1) * INCREMENT, INCREMENT, RANGE_MIN, RANGE_MAX,
                    tuple(placed[:2]), ranges)
    return (*scan_to_obstacles(ranges, ANGLE_MIN, INCREMENT, RANGE_MIN, RANGE_MAX,
                               (0.0, 0.0, 0.0), placed, settings, with_clusters=True), view)


def _cluster_of(clusters, centre, reach):
    """Return the index of the cluster with most points within ``reach`` of ``centre``."""
    near = [int(np.sum(np.linalg.norm(cluster - centre, axis=1) <= reach))
            for cluster in clusters]
    return int(np.argmax(near)) if near and max(near) else None


@st.composite
def moving_objects(draw):
    """Draw a box or cylinder 2-4 m away moving at 0.3-2 m/s, and the robot's motion.

    The robot stands, or drives at up to 1 m/s turning at up to 0.5 rad/s.  A box is turned
    so that its corner faces the robot (two faces lit: a face seen alone says nothing of
    the speed along it); trajectories that leave 1.5-5.5 m or 100 degrees either side of
    the robot's heading within 1.5 s are drawn again.
    """
    rng = np.random.default_rng(draw(st.integers(0, 2 ** 32 - 1)))
    kind = draw(st.sampled_from(['box', 'cylinder']))
    rate = draw(st.sampled_from([10, 20]))
    moving_robot = draw(st.booleans())
    while True:
        speed, heading = rng.uniform(0.3, 2.0), rng.uniform(0, 2 * math.pi)
        velocity = speed * np.array([math.cos(heading), math.sin(heading)])
        drive = rng.uniform(0.0, 1.0) if moving_robot else 0.0
        turn = rng.uniform(-0.5, 0.5) if moving_robot else 0.0
        distance, bearing = rng.uniform(2.0, 4.0), rng.uniform(-1.0, 1.0)
        start = distance * np.array([math.cos(bearing), math.sin(bearing)])
        valid = True
        for t in np.linspace(0.0, 1.5, 16):
            offset = start + velocity * t - np.array([drive * t, 0.0])
            seen = math.remainder(math.atan2(offset[1], offset[0]) - turn * t, 2 * math.pi)
            valid &= 1.5 <= np.linalg.norm(offset) <= 5.5 and abs(seen) < math.radians(100)
        if valid:
            break
    size = rng.uniform(0.25, 0.4, 2) if kind == 'box' else rng.uniform(0.25, 0.5)
    yaw = bearing + math.pi / 4 + rng.uniform(-0.15, 0.15)
    return {'kind': kind, 'rate': rate, 'velocity': velocity, 'drive': drive, 'turn': turn,
            'start': start, 'size': size, 'yaw': yaw, 'seed': int(rng.integers(2 ** 31))}


@given(case=moving_objects())
@SIMULATIONS
def test_moving_object_gets_its_velocity(case):
    """From the fourth scan on, the object's cluster publishes its velocity within 0.1 m/s.

    5 mm range noise (with 1 cm the error is about 0.05 m/s rms and passes 0.1 m/s on about
    one scan in 300: module docstring).  The object moves at 0.3 m/s or more, so a tracker
    that published nothing, or lagged by a scan, would fail.
    """
    rng = np.random.default_rng(case['seed'])
    tracker = ScanTracker(link=SCAN.cluster_tolerance)
    rate, velocity = case['rate'], case['velocity']
    reach = (np.hypot(*case['size']) if case['kind'] == 'box' else case['size']) + 0.1
    for k in range(int(1.5 * rate) + 1):
        t = k / rate
        pose = (case['drive'] * t, 0.0, case['turn'] * t)
        centre = case['start'] + velocity * t
        shapes = (([box(centre, *case['size'], case['yaw'])], ()) if case['kind'] == 'box'
                  else ((), [(centre, case['size'])]))
        _, _, clusters, view = _clusters(pose, *shapes, noise=0.005, rng=rng)
        estimates = tracker.update(t, clusters, view)
        index = _cluster_of(clusters, centre, reach)
        assert index is not None, f'scan {k}: the object is not seen'
        estimate = estimates[index]
        if k >= SETTLED:
            error = np.linalg.norm(estimate.velocity - velocity)
            assert error <= 0.1, (f'scan {k}: published {estimate.velocity}, true {velocity}, '
                                  f'{estimate}')
            assert estimate.confirmed and estimate.moving


@st.composite
def drives(draw):
    """Draw a robot drive: speed 0-2 m/s, turn rate -1..1 rad/s, 10 or 20 Hz, 2 s."""
    return {'speed': draw(st.floats(0.0, 2.0)), 'turn': draw(st.floats(-1.0, 1.0)),
            'rate': draw(st.sampled_from([10, 20])), 'seed': draw(st.integers(0, 2 ** 31))}


STATIC_POLYGONS = [
    np.array([[-1.0, 1.6], [1.5, 1.6], [1.5, 1.8], [-1.0, 1.8]]),  # a 2.5 m wall: measured
    np.array([[-6.0, -2.8], [6.0, -2.8], [6.0, -2.6], [-6.0, -2.6]]),  # 12 m: structure
    box((2.5, -1.0), 0.3, 0.2, 0.5),
]
STATIC_CIRCLES = [((0.8, -1.1), 0.3)]


@given(drive=drives())
@SIMULATIONS
def test_standing_objects_publish_no_velocity(drive):
    """A wall, a long wall, a box and a cylinder seen from a driving, turning robot stay still.

    Every estimate of every scan publishes a speed below 0.1 m/s (in fact exactly 0: no track
    is classified moving), with 1 cm range noise.  The robot starts at (-2, 0) heading +x and
    stops 0.5 m short of an object (a robot driving through a wall would see its far face
    jump to its near face); ``test_a_centroid_would_move`` shows that the clusters'
    centroids do move.
    """
    rng = np.random.default_rng(drive['seed'])
    tracker = ScanTracker(link=SCAN.cluster_tolerance)
    for k in range(2 * drive['rate'] + 1):
        t = k / drive['rate']
        heading = drive['turn'] * t
        if abs(drive['turn']) > 1e-6:
            x = -2.0 + drive['speed'] / drive['turn'] * math.sin(heading)
            y = drive['speed'] / drive['turn'] * (1.0 - math.cos(heading))
        else:
            x, y = -2.0 + drive['speed'] * t, 0.0
        if _clearance((x, y)) < 0.5:
            break
        _, _, clusters, view = _clusters((x, y, heading), STATIC_POLYGONS, STATIC_CIRCLES,
                                         noise=0.01, rng=rng)
        for estimate in tracker.update(t, clusters, view):
            assert np.linalg.norm(estimate.velocity) < 0.1, (k, estimate)
            assert not estimate.moving, (k, estimate)


def _phantom_tracks(settings, seed):
    """Return how many scans publish a moving track of the standing scene, placed noisily.

    A robot drives past ``STATIC_POLYGONS`` and ``STATIC_CIRCLES`` at 1 m/s for 2 s at
    10 Hz; each scan is placed at its pose plus 1 cm and 0.01 rad of white noise.
    """
    rng = np.random.default_rng(seed)
    tracker, phantoms = ScanTracker(settings, link=SCAN.cluster_tolerance), 0
    for k in range(21):
        pose = (-2.0 + 0.1 * k, 0.0, 0.0)
        placed = (pose[0] + rng.normal(0.0, 0.01), pose[1] + rng.normal(0.0, 0.01),
                  pose[2] + rng.normal(0.0, 0.01))
        _, _, clusters, view = _clusters(pose, STATIC_POLYGONS, STATIC_CIRCLES, noise=0.01,
                                         rng=rng, placed=placed)
        estimates = tracker.update(k / 10, clusters, view)
        phantoms += any(np.linalg.norm(e.velocity) > 0.0 for e in estimates)
    return phantoms


def test_told_the_pose_noise_standing_objects_stay_still():
    """Scans placed at noisy odometry shake standing objects; told the noise, none moves.

    Over five seeds, the tracker not told the noise publishes phantom velocities (which
    is why the setting exists); told ``pose_std`` 1 cm and ``heading_std`` 0.01 rad, no
    scan publishes any.
    """
    told = TrackerSettings(pose_std=0.01, heading_std=0.01)
    assert sum(_phantom_tracks(TrackerSettings(), seed) for seed in range(5)) > 0
    assert sum(_phantom_tracks(told, seed) for seed in range(5)) == 0


def test_a_track_starts_moving_only_where_its_cluster_fills_or_empties_space_seen():
    """A cylinder at 1 m/s registers as moving either way; it starts moving only with evidence.

    Given its scans' views it is moving from the fourth scan on.  Given views whose every
    beam stopped 0.5 m out, no point of it lies where a scan saw empty space, and it never
    starts moving (the test a standing post seen from a passing robot fails, module step 4).
    """
    for blind in (False, True):
        rng = np.random.default_rng(11)
        tracker = ScanTracker(link=SCAN.cluster_tolerance)
        moving = []
        for k in range(16):
            centre = np.array([3.0, -1.0 + 0.1 * k])
            _, _, clusters, view = _clusters((0.0, 0.0, 0.0), (), [(centre, 0.3)], noise=0.005,
                                             rng=rng)
            if blind:
                view = view._replace(ranges=np.full(BEAMS, 0.5))
            estimate = tracker.update(k / 10, clusters, view)[_cluster_of(clusters, centre, 0.4)]
            moving.append(estimate.moving)
        assert moving == ([False] * 16 if blind else [False] * SETTLED + [True] * (16 - SETTLED))


def test_with_velocities_gives_moving_obstacles_their_track_velocity():
    """Obstacles of a moving cylinder's cluster get (vx, vy, 0); the wall's stay as they were."""
    rng = np.random.default_rng(5)
    tracker = ScanTracker(link=SCAN.cluster_tolerance)
    velocity = np.array([0.0, 1.0])
    wall = [np.array([[3.5, -2.0], [3.7, -2.0], [3.7, 2.0], [3.5, 2.0]])]
    for k in range(12):
        centre = np.array([2.0, -0.6]) + velocity * k / 20
        obstacles, owner, clusters, view = _clusters((0.0, 0.0, 0.0), wall, [(centre, 0.3)],
                                                     noise=0.005, rng=rng)
        estimates = tracker.update(k / 20, clusters, view)
    moved = with_velocities(obstacles, owner, estimates)
    cylinder = _cluster_of(clusters, centre, 0.4)
    assert len(moved) == len(obstacles) and (owner == cylinder).any()
    hiding = with_velocities(obstacles, owner, estimates, unknown_speed=1.5, hidden_speed=0.7)
    for before, after, hidden, index in zip(obstacles, moved, hiding, owner):
        if index == cylinder:
            assert after.key == before.key and after.polygon is before.polygon
            assert np.linalg.norm(after.velocity - [*velocity, 0.0]) <= 0.1
            assert after.velocity_error == 0.0 and hidden.velocity_error == 0.7
            assert np.array_equal(hidden.velocity, after.velocity)
        else:
            assert after is before and hidden is before


def test_a_track_is_trusted_only_while_its_registrations_explain_its_cluster():
    """Two cylinders close on each other: trusted while apart, not once they meet.

    Two 0.3 m cylinders 2.5 m ahead close on each other at 1 m/s each; a third stands.  The
    standing one, never moving, is always trusted; so are the moving ones while each
    registration explains its own cluster.  When they touch, the scan shows one cluster
    whose track keeps one velocity (the other cylinder's points do not register onto its
    outline), and it is no longer trusted: ``with_velocities`` gives its obstacles the
    unknown speed.
    """
    rng = np.random.default_rng(3)
    tracker = ScanTracker(link=SCAN.cluster_tolerance)
    post = np.array([2.0, 2.0])
    for k in range(11):
        up, down = np.array([2.5, -1.0 + k / 10]), np.array([2.6, 1.0 - k / 10])
        obstacles, owner, clusters, view = _clusters((0.0, 0.0, 0.0), (),
                                                     [(up, 0.3), (down, 0.3), (post, 0.3)],
                                                     noise=0.005, rng=rng)
        estimates = tracker.update(k / 10, clusters, view)
        first, second = _cluster_of(clusters, up, 0.35), _cluster_of(clusters, down, 0.35)
        assert estimates[_cluster_of(clusters, post, 0.35)].trusted
        apart = first != second
        if apart and k < tracker.settings.moving_scans:  # not yet moving: trusted
            assert estimates[first].trusted and estimates[second].trusted
        if apart and k >= 4:  # moving, each registration explaining its cluster
            assert estimates[first].moving and estimates[second].moving
            assert estimates[first].trusted and estimates[second].trusted
        if first == second:
            assert k >= 7 and not estimates[first].trusted
    assert first == second
    marked = with_velocities(obstacles, owner, estimates, unknown_speed=1.5)
    assert all((obstacle.velocity_error == 1.5) == (index == first)
               for obstacle, index in zip(marked, owner))
    # The larger bound holds where a track is both moving and untrusted.
    for hidden_speed in (0.5, 2.5):
        marked = with_velocities(obstacles, owner, estimates, unknown_speed=1.5,
                                 hidden_speed=hidden_speed)
        expected = max(1.5, hidden_speed) if estimates[first].moving else 1.5
        assert all(obstacle.velocity_error == (expected if index == first else 0.0)
                   for obstacle, index in zip(marked, owner))
    assert not any(obstacle.velocity_error for obstacle in with_velocities(obstacles, owner,
                                                                           estimates))


@pytest.mark.parametrize('beside_mover', [1.0, 0.0])
def test_a_track_born_beside_a_mover_is_not_trusted_until_it_registers(beside_mover):
    """A cylinder that comes out beside a moving one is not trusted at once; a post far off is.

    A 0.3 m cylinder crosses 3 m ahead at 1 m/s until its track moves.  Then two clusters
    appear: a cylinder 0.7 m beyond the mover's box (as one hidden there would come out)
    and a post 3 m from it.  The post's new track is trusted at once, as every young track is.
    The other's is not, with ``beside_mover`` set: it counts as moving at birth and is
    trusted once ``trust_scans`` registrations each explain its cluster (it stands).  With
    ``beside_mover`` 0 it is trusted at once, as before.
    """
    rng = np.random.default_rng(11)
    tracker = ScanTracker(TrackerSettings(beside_mover=beside_mover),
                          link=SCAN.cluster_tolerance)
    post, behind = np.array([1.0, 3.0]), np.array([3.8, -1.3])
    for k in range(13):
        mover = np.array([3.0, 0.8 - k / 10])
        circles = [(mover, 0.3)] + ([(behind, 0.3), (post, 0.3)] if k >= 8 else [])
        _, _, clusters, view = _clusters((0.0, 0.0, 0.0), (), circles, noise=0.005, rng=rng)
        estimates = tracker.update(k / 10, clusters, view)
        moving = estimates[_cluster_of(clusters, mover, 0.35)]
        if k == 7:
            assert moving.moving and moving.trusted
        if k < 8:
            continue
        assert estimates[_cluster_of(clusters, post, 0.35)].trusted
        born = estimates[_cluster_of(clusters, behind, 0.35)]
        young = k - 8 < tracker.settings.trust_scans
        assert born.trusted == (not young or beside_mover == 0.0), (k, born)
    assert not born.moving


def test_a_track_that_stopped_moving_keeps_the_hidden_speed_for_distrust_time():
    """A cylinder crosses at 1 m/s, then stands: its track publishes 0 but may still hide one.

    Once its registrations stop passing, the track is still again and publishes velocity
    0.  For ``distrust_time`` after it last moved, ``moved_lately`` holds and
    ``with_velocities`` gives its obstacles ``hidden_speed``: two movers merged into one
    cluster register as one outline whose displacement averages theirs out, and such a
    track was published still while one of them came at the robot (dynamic world 16,
    generator seed 2029, from scans).  After that, nothing; a post never moved at all.
    """
    rng = np.random.default_rng(5)
    tracker = ScanTracker(link=SCAN.cluster_tolerance)
    post = np.array([1.0, 3.0])
    seen = []
    for k in range(45):
        t = k / 10
        mover = np.array([3.0, 0.8 - min(t, 1.0)])        # 1 m/s for 1 s, then stands
        obstacles, owner, clusters, view = _clusters((0.0, 0.0, 0.0), (),
                                                     [(mover, 0.3), (post, 0.3)],
                                                     noise=0.005, rng=rng)
        estimates = tracker.update(t, clusters, view)
        index = _cluster_of(clusters, mover, 0.35)
        estimate = estimates[index]
        assert not estimates[_cluster_of(clusters, post, 0.35)].moved_lately
        marked = with_velocities(obstacles, owner, estimates, hidden_speed=0.7)
        errors = {o.velocity_error for o, c in zip(marked, owner.tolist()) if c == index}
        seen.append((t, estimate.moving, estimate.moved_lately, errors))
    moving = [t for t, m, _, _ in seen if m]
    stopped = max(moving) + 0.1                              # the first scan still again
    assert 0.3 <= min(moving) and 1.0 <= stopped <= 1.6
    for t, m, lately, errors in seen:
        if t >= stopped:
            assert not m
            assert lately == (t - max(moving) <= tracker.settings.distrust_time + 1e-9), t
            assert errors == ({0.7} if lately else {0.0}), (t, errors)


def test_a_moving_track_the_scan_misses_is_kept_where_it_goes():
    """A cylinder hidden for a few scans stays an obstacle, moved along its velocity.

    While seen, no track is unseen.  Once the scans miss it, its outline comes back from
    ``unseen_obstacles`` at the predicted place (on the true cylinder, to 5 cm: the lit
    side's arc) with the track's velocity, until ``max_coast`` has passed.
    """
    rng = np.random.default_rng(7)
    tracker = ScanTracker(link=SCAN.cluster_tolerance)
    velocity, radius, rate = np.array([-0.5, 1.0]), 0.3, 20.0
    start = np.array([2.5, -1.0])
    for k in range(12):
        centre = start + velocity * k / rate
        _, _, clusters, view = _clusters((0.0, 0.0, 0.0), (), [(centre, radius)], noise=0.005,
                                         rng=rng)
        tracker.update(k / rate, clusters, view)
        assert unseen_obstacles(tracker) == []
    coast = tracker.settings.max_coast
    hidden = 0
    for k in range(12, 12 + round(2 * coast * rate)):
        centre = start + velocity * k / rate
        tracker.update(k / rate, [], AROUND)
        unseen = unseen_obstacles(tracker, 'front:')
        if k / rate - 11 / rate > coast + 1e-9:
            assert unseen == []
            continue
        hidden += 1
        (obstacle,) = unseen
        assert obstacle.key == 'front:unseen/0' and obstacle.velocity_error == 0.0
        assert np.linalg.norm(obstacle.velocity - [*velocity, 0.0]) <= 0.1
        (hiding,) = unseen_obstacles(tracker, 'front:', velocity_error=1.5)
        assert hiding.velocity_error == 1.5 and np.array_equal(hiding.polygon, obstacle.polygon)
        distances = np.linalg.norm(obstacle.polygon - centre, axis=1)
        assert distances.max() <= radius + 0.05 and distances.max() >= radius - 0.05
        assert np.linalg.norm(obstacle.polygon.mean(axis=0) - centre) <= radius
    assert hidden == round(coast * rate)


def test_memory_stays_bounded():
    """Outlines and tracks do not pile up over many scans of the same scene."""
    tracker = ScanTracker()
    clusters = [np.linspace([1.0, y], [1.0, y + 0.5], 40) for y in np.arange(-3.0, 3.0, 1.0)]
    for k in range(200):
        tracker.update(k * 0.05, clusters, AROUND)
    assert len(tracker) == len(clusters)
    assert len(tracker._storage) <= sum(map(len, clusters))


def _clearance(position):
    """Return the distance from ``position`` to the nearest standing object."""
    point = np.asarray(position, dtype=float)[None]
    return min(min(_nearest_polygon(point, [polygon])[0] for polygon in STATIC_POLYGONS),
               min(np.linalg.norm(point[0] - centre) - radius
                   for centre, radius in STATIC_CIRCLES))


def test_a_centroid_would_move():
    """The raw centroids of a standing cylinder and wall move with the robot: > 0.1 m/s.

    Why the tracker registers outlines instead: a tracker fed these centroids would give the
    standing objects of ``test_standing_objects_publish_no_velocity`` a velocity.  The robot
    drives past at 2 m/s; the cylinder's lit side turns and the wall's hits crowd nearer the
    robot.
    """
    rate = 20
    speeds = {'cylinder': [], 'wall': []}
    previous = {}
    for k in range(2 * rate):
        t = k / rate
        _, _, clusters, view = _clusters((-2.0 + 2.0 * t, 0.0, 0.0), STATIC_POLYGONS[:1],
                                         STATIC_CIRCLES)
        for name, centre, reach in (('cylinder', np.array(STATIC_CIRCLES[0][0]), 0.4),
                                    ('wall', np.array([0.25, 1.6]), 1.3)):
            index = _cluster_of(clusters, centre, reach)
            if index is None:
                previous.pop(name, None)
                continue
            centroid = clusters[index].mean(axis=0)
            if name in previous:
                speeds[name].append(np.linalg.norm(centroid - previous[name]) * rate)
            previous[name] = centroid
    assert max(speeds['cylinder']) > 0.1
    assert max(speeds['wall']) > 0.1


def test_wall_registers_across_itself_only():
    """A straight wall moved along and across itself: only the across part is measured.

    ``register_outline`` returns d = (across, guess along), H measures the normal only, and
    the free direction is the wall's.
    """
    rng = np.random.default_rng(3)
    xs = np.linspace(-1.0, 1.0, 200)
    old = np.column_stack([xs, 2.0 + rng.normal(0.0, 0.01, xs.size)])
    new = np.column_stack([xs + 0.013, 2.03 + rng.normal(0.0, 0.01, xs.size)])
    params = TrackerSettings().vector(SCAN.cluster_tolerance)
    result = np.zeros(10)
    register_outline(new, old, np.array([-0.2, 0.02]), 0.1, params, result)
    d, (hxx, hxy, hyy), kept = result[:2], result[2:5], result[5]
    assert kept > 100
    assert abs(d[1] - 0.03) < 0.003 and abs(d[0] + 0.2) < 0.05  # along: near the guess
    assert hyy > 10 and hxx < 0.01 * hyy and abs(hxx * hyy - hxy * hxy) <= 1e-9 * hyy * hyy
    assert abs(result[8]) > 0.999 and abs(result[9]) < 0.05  # free: along the wall
    with pytest.raises(ValueError):
        register_outline(new, old, np.zeros(2), 0.1, params, np.zeros(8))


def test_stamps_and_resets():
    """A repeated stamp is fine; a stamp back by more than ``max_backstep`` starts afresh."""
    tracker = ScanTracker()
    cluster = box((2.0, 0.0), 0.3, 0.3)[:2]  # one face: two points would not register
    face = np.linspace(cluster[0], cluster[1], 30)
    first = tracker.update(10.0, [face], AROUND)
    again = tracker.update(10.0, [face], AROUND)
    assert first[0].track_id == again[0].track_id
    tracker.update(10.05, [face], AROUND)
    back = tracker.update(9.9, [face], AROUND)  # 0.15 s back: kept
    assert back[0].track_id == first[0].track_id
    fresh = tracker.update(9.0, [face], AROUND)
    assert fresh[0].track_id != first[0].track_id and not fresh[0].confirmed
    assert len(tracker) == 1
    assert tracker.update(9.1, [], AROUND) == []
    assert len(tracker) == 1  # coasting
    assert tracker.update(20.0, [], AROUND) == [] and len(tracker) == 0


@pytest.mark.parametrize('clusters', [[np.zeros((0, 2))], [np.array([[0.0, math.nan]])],
                                      [np.zeros((3, 3))], [np.zeros(4)]])
def test_bad_clusters_are_refused(clusters):
    """Empty, non-finite or wrongly shaped clusters raise ValueError, in one line."""
    with pytest.raises(ValueError) as error:
        ScanTracker().update(0.0, clusters, AROUND)
    assert '\n' not in str(error.value)


def test_bad_stamp_is_refused():
    """A non-finite stamp raises ValueError."""
    with pytest.raises(ValueError):
        ScanTracker().update(math.nan, [], AROUND)


def test_estimates_are_read_only_and_typed():
    """Estimates are ``TrackEstimate``s of plain Python numbers with read-only velocities."""
    estimate = ScanTracker().update(0.0, [np.linspace([1.0, 0.0], [1.0, 1.0], 20)], AROUND)[0]
    assert isinstance(estimate, TrackEstimate)
    assert type(estimate.track_id) is int and type(estimate.velocity_std) is float
    assert type(estimate.confirmed) is bool and type(estimate.moving) is bool
    assert estimate.velocity.shape == (2,) and not estimate.velocity.flags.writeable


BAD_SETTINGS = [('gate', 0.0), ('gate', math.inf), ('accel_std', -1.0), ('speed_std', 0),
                ('point_std', math.nan), ('trim', 0.0), ('span', -0.1), ('iterations', 0),
                ('iterations', 2.5), ('min_overlap', 1.5), ('confirm_hits', True),
                ('max_coast', -1.0), ('moving_speed', 'fast'), ('n_sigma', -1.0),
                ('moving_scans', 0), ('max_velocity_std', 0.0), ('static_extent', 0.0),
                ('max_backstep', -0.1), ('pose_std', -0.01), ('heading_std', math.nan),
                ('trust_share', -0.1), ('trust_scans', 0), ('distrust_time', -1.0),
                ('beside_mover', -0.5), ('evidence_age', math.inf)]


@pytest.mark.parametrize('name, value', BAD_SETTINGS)
def test_settings_refuse_bad_values(name, value):
    """Every out-of-range field raises ValueError naming it, in one line."""
    with pytest.raises(ValueError) as error:
        TrackerSettings(**{name: value})
    message = str(error.value)
    assert message.startswith(name) and '\n' not in message, message


def test_every_setting_is_validated():
    """Each field of ``TrackerSettings`` appears in ``BAD_SETTINGS`` (none is left unchecked)."""
    assert {name for name, _ in BAD_SETTINGS} == set(TrackerSettings.__dataclass_fields__)


@st.composite
def scenes(draw):
    """Draw a scene (boxes, circles, a room or none), a pose, noise and scan settings."""
    rng = np.random.default_rng(draw(st.integers(0, 2 ** 32 - 1)))
    polygons = [box(rng.uniform(-5, 5, 2), *rng.uniform(0.05, 0.8, 2), rng.uniform(0, 3))
                for _ in range(rng.integers(0, 8))]
    if rng.random() < 0.5:
        polygons.append(box((0.0, 0.0), *rng.uniform(3.0, 8.0, 2)))  # a room round the robot
    circles = [(rng.uniform(-5, 5, 2), rng.uniform(0.05, 0.6)) for _ in range(rng.integers(0, 6))]
    tolerance = rng.uniform(0.05, 0.3)
    settings = ScanSettings(
        cluster_tolerance=tolerance, segment_thickness=0.02, depth=rng.uniform(0.02, 0.3),
        split_tolerance=rng.uniform(0.0, tolerance - 0.01),
        footprint_radius=rng.uniform(0.0, 0.4), min_cluster_points=int(rng.integers(1, 4)),
        max_obstacles=int(rng.choice([4, 512])))
    pose = (*rng.uniform(-0.5, 0.5, 2), rng.uniform(-math.pi, math.pi))
    ranges = simulate_ranges(sensor_pose_in_world(pose), BEAMS, ANGLE_MIN, INCREMENT, RANGE_MAX,
                             polygons, circles, rng.choice([0.0, 0.01]), rng)
    return ranges, pose, settings


@given(scene=scenes())
@settings(max_examples=examples(60), deadline=None)
def test_clusters_match_the_obstacles(scene):
    """``with_clusters`` leaves the obstacles as they were, and owners fit their clusters.

    Every vertex of an obstacle lies within ``depth + segment_thickness + split_tolerance``
    of a point of its cluster; while no polygon was dropped every point lies within
    ``cluster_tolerance`` of one of its cluster's polygons; the clusters are the kept
    endpoints, in linked chains of at least ``min_cluster_points`` points.
    """
    ranges, pose, settings = scene
    plain = scan_to_obstacles(ranges, ANGLE_MIN, INCREMENT, RANGE_MIN, RANGE_MAX,
                              (0.0, 0.0, 0.0), pose, settings)
    obstacles, owner, clusters = scan_to_obstacles(ranges, ANGLE_MIN, INCREMENT, RANGE_MIN,
                                                   RANGE_MAX, (0.0, 0.0, 0.0), pose, settings,
                                                   with_clusters=True)
    assert [o.key for o in obstacles] == [o.key for o in plain]
    for mine, theirs in zip(obstacles, plain):
        assert np.array_equal(mine.polygon, theirs.polygon)
    assert owner.dtype == np.int64 and owner.shape == (len(obstacles),)
    assert ((owner >= 0) & (owner < len(clusters))).all()
    reach = settings.depth + settings.segment_thickness + settings.split_tolerance + 1e-9
    for obstacle, index in zip(obstacles, owner):
        gaps = np.linalg.norm(obstacle.polygon[:, None] - clusters[index][None], axis=2)
        assert gaps.min(axis=1).max() <= reach
    for index, cluster in enumerate(clusters):
        assert cluster.shape[1] == 2 and not cluster.flags.writeable
        assert len(cluster) >= settings.min_cluster_points  # 270 degrees: no ring
        steps = np.linalg.norm(np.diff(cluster, axis=0), axis=1)
        assert (steps <= settings.cluster_tolerance + 1e-9).all()
        if len(obstacles) < settings.max_obstacles and (owner == index).any():
            polygons = [o.polygon for o, i in zip(obstacles, owner) if i == index]
            assert _nearest_polygon(cluster, polygons).max() <= settings.cluster_tolerance + 1e-9
    endpoints = beam_endpoints(ranges, ANGLE_MIN, INCREMENT, RANGE_MIN, RANGE_MAX,
                               (0.0, 0.0, 0.0), pose)
    kept = endpoints[np.linalg.norm(endpoints - pose[:2], axis=1) > settings.footprint_radius]
    found = np.concatenate(clusters) if clusters else np.zeros((0, 2))
    assert {tuple(p) for p in found} <= {tuple(p) for p in kept}
    if settings.min_cluster_points == 1:
        assert {tuple(p) for p in found} == {tuple(p) for p in kept}


def _nearest_polygon(points, polygons):
    """Return each point's distance to the nearest of the convex CCW polygons (0 inside)."""
    best = np.full(len(points), np.inf)
    for polygon in polygons:
        edges = np.roll(polygon, -1, axis=0) - polygon
        rel = points[:, None, :] - polygon[None]
        side = edges[:, 0] * rel[..., 1] - edges[:, 1] * rel[..., 0]
        along = np.clip(np.sum(rel * edges, axis=2) / np.sum(edges * edges, axis=1), 0, 1)
        distance = np.linalg.norm(rel - along[..., None] * edges, axis=2).min(axis=1)
        best = np.minimum(best, np.where((side >= 0).all(axis=1), 0.0, distance))
    return best


def test_clusters_of_an_empty_scan_and_of_a_ring():
    """No return: ([], empty owner, []); a closed room seen all round is one ring cluster."""
    obstacles, owner, clusters = scan_obstacles(np.full((5, 2), np.nan), (0.0, 0.0),
                                                with_clusters=True)
    assert obstacles == [] and owner.shape == (0,) and clusters == []
    count = 720
    angles = 2 * math.pi * np.arange(count) / count
    endpoints = np.column_stack([2.0 * np.cos(angles), 2.0 * np.sin(angles)])
    obstacles, owner, clusters = scan_obstacles(endpoints, (0.0, 0.0), wraps=scan_wraps(
        count, 2 * math.pi / count), with_clusters=True)
    assert len(clusters) == 1 and len(clusters[0]) == count + 1
    assert np.array_equal(clusters[0][0], clusters[0][-1])
    assert (owner == 0).all() and len(obstacles) > 1
