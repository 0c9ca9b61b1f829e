"""Laser scan to convex obstacles (core.obstacles.scan_conversion), checked independently.

Endpoints, point-to-polygon distances and convexity are recomputed here from their
definitions; scenes are ray-cast against wall segments.
"""
import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from oracles import front_by_arrays, split_to_tolerance_by_levels
from polyc2bf_ros.core.obstacles.obstacle_set import ObstacleSet
from polyc2bf_ros.core.obstacles.scan_conversion import (
    _front,
    _rectangles,
    _split_to_tolerance,
    beam_endpoints,
    pose_at,
    scan_obstacles,
    scan_points,
    scan_to_obstacles,
    scan_wraps,
    ScanSettings,
)
from strategies import examples

SETTINGS = settings(max_examples=examples(100), deadline=None)
ORIGIN = (0.0, 0.0, 0.0)
ROOM = [((2.0, -2.0), (2.0, 2.0)), ((2.0, 2.0), (-2.0, 2.0)), ((-2.0, 2.0), (-2.0, -2.0)),
        ((-2.0, -2.0), (2.0, -2.0))]


def _cast(walls, count, angle_min, increment):
    """Return the range from the origin to the nearest wall segment per beam (inf: no hit).

    Beam k leaves at ``angle_min + k increment``; ``r d = a + s (b - a)`` is solved with
    cross products.
    """
    angles = angle_min + increment * np.arange(count)
    dx, dy = np.cos(angles), np.sin(angles)
    ranges = np.full(count, np.inf)
    for (wx, wy), b in walls:
        ex, ey = b[0] - wx, b[1] - wy
        denominator = dx * ey - dy * ex
        with np.errstate(divide='ignore', invalid='ignore'):
            r = (wx * ey - wy * ex) / denominator
            s = (wx * dy - wy * dx) / denominator
        hit = (denominator != 0) & (r > 0) & (s >= 0) & (s <= 1)
        ranges = np.where(hit, np.minimum(ranges, r), ranges)
    return ranges


def _distances(points, polygon):
    """Return the distance from each point (K, 2) to a CCW convex polygon, 0 inside or on it."""
    start = np.asarray(polygon, dtype=float)
    edge = np.roll(start, -1, axis=0) - start
    rel = np.asarray(points, dtype=float)[:, None, :] - start[None]
    side = edge[:, 0] * rel[..., 1] - edge[:, 1] * rel[..., 0]
    along = np.clip(np.sum(rel * edge, axis=2) / np.sum(edge * edge, axis=1), 0.0, 1.0)
    nearest = np.linalg.norm(rel - along[..., None] * edge, axis=2).min(axis=1)
    return np.where((side >= 0).all(axis=1), 0.0, nearest)


def _nearest_polygon_distances(points, obstacles):
    """Return, per point, the distance to the nearest obstacle polygon (inf when none)."""
    best = np.full(len(points), np.inf)
    for obstacle in obstacles:
        best = np.minimum(best, _distances(points, obstacle.polygon))
    return best


def _signed_area(polygon):
    """Return the shoelace area of a polygon, positive when counter-clockwise."""
    pts = np.asarray(polygon, dtype=float) - polygon[0]
    return 0.5 * np.sum(pts[:, 0] * np.roll(pts[:, 1], -1) - pts[:, 1] * np.roll(pts[:, 0], -1))


def _convex_ccw_problem(polygon):
    """Return why the polygon is not a finite, convex, CCW one with positive area, or None."""
    pts = np.asarray(polygon, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 3:
        return f'shape {pts.shape}'
    if not np.isfinite(pts).all():
        return 'not finite'
    incoming = pts - np.roll(pts, 1, axis=0)
    outgoing = np.roll(incoming, -1, axis=0)
    turn = incoming[:, 0] * outgoing[:, 1] - incoming[:, 1] * outgoing[:, 0]
    dot = np.sum(incoming * outgoing, axis=1)
    if not (turn > 0).all():
        return f'turns {turn}'
    winding = np.sum(np.arctan2(turn, dot))
    if not math.isclose(winding, 2 * math.pi, rel_tol=1e-9):
        return f'winds {winding / (2 * math.pi)} times'
    area = _signed_area(pts)
    return None if area > 0 else f'area {area}'


def _rays(scan, count):
    """Return the odometry-frame origin (2,) and headings (count,) of a scan's beams."""
    sensor_x, sensor_y, sensor_yaw = scan['sensor_pose']
    x, y, yaw = scan['robot_pose']
    origin = np.array([x + math.cos(yaw) * sensor_x - math.sin(yaw) * sensor_y,
                       y + math.sin(yaw) * sensor_x + math.cos(yaw) * sensor_y])
    return origin, yaw + sensor_yaw + scan['angle_min'] + scan['angle_increment'] * np.arange(
        count)


def _endpoints(scan):
    """Return the odometry-frame endpoints of every beam, computed from the definition."""
    ranges = np.asarray(scan['ranges'])
    origin, headings = _rays(scan, len(ranges))
    with np.errstate(invalid='ignore'):
        return origin + ranges[:, None] * np.column_stack([np.cos(headings), np.sin(headings)])


def _line_ranges(scan, count, offset, direction):
    """Return the ranges to a line passing ``offset`` from the base (inf: parallel or behind)."""
    origin, headings = _rays(scan, count)
    ux, uy = math.cos(direction), math.sin(direction)
    qx = scan['robot_pose'][0] - offset * uy - origin[0]
    qy = scan['robot_pose'][1] + offset * ux - origin[1]
    with np.errstate(divide='ignore'):
        ranges = (qx * uy - qy * ux) / (np.cos(headings) * uy - np.sin(headings) * ux)
    return np.where(ranges > 0, ranges, np.inf)


@st.composite
def scans(draw):
    """Draw a scan, poses and settings with a robot body.

    Ranges are a random walk with jumps, or hits on a line passing through the footprint
    (whose beams straddle the body), with NaN, inf, negative and out-of-range values mixed in.
    """
    rng = np.random.default_rng(draw(st.integers(0, 2 ** 32 - 1)))
    count = draw(st.integers(1, 400))
    walk = draw(st.booleans())  # else the line through the body, seen by sparse beams
    if draw(st.booleans()):
        increment = 2 * math.pi / count
    else:
        increment = rng.uniform(0.002, 0.3) if walk else rng.uniform(0.05, 0.3)
    thickness = rng.uniform(0.005, 0.1)
    cluster_tolerance = rng.uniform(thickness, 0.4)
    footprint_radius = rng.uniform(0.01, 0.6) if walk else rng.uniform(0.01, 0.15)
    scan = {
        'angle_min': rng.uniform(-math.pi, math.pi),
        'angle_increment': increment * rng.choice([-1.0, 1.0]),
        'range_min': rng.uniform(0.0, 0.2), 'range_max': rng.uniform(3.0, 8.0),
        'sensor_pose': (*rng.uniform(-0.5, 0.5, 2), rng.uniform(-math.pi, math.pi)),
        'robot_pose': (*rng.uniform(-20.0, 20.0, 2), rng.uniform(-math.pi, math.pi)),
        'settings': ScanSettings(
            cluster_tolerance=cluster_tolerance, segment_thickness=thickness,
            depth=rng.uniform(thickness, 0.3),
            split_tolerance=rng.uniform(0.0, cluster_tolerance - thickness / 2),
            footprint_radius=footprint_radius, max_obstacles=100_000),
    }
    if walk:
        level, roughness = rng.uniform(0.1, 5.0), rng.choice([0.002, 0.03, 0.3])
        ranges = np.abs(level + np.cumsum(rng.normal(0.0, roughness, count)))
        jumps = rng.random(count) < 0.05
        ranges[jumps] = rng.uniform(0.05, 6.0, jumps.sum())
    else:
        offset = rng.uniform(-1.0, 1.0) * footprint_radius
        ranges = _line_ranges(scan, count, offset, rng.uniform(-math.pi, math.pi))
    bad = rng.random(count) < draw(st.sampled_from([0.0, 0.1, 0.5]))
    ranges[bad] = rng.choice([np.nan, np.inf, -np.inf, -1.0, 0.0, 0.001, 50.0], bad.sum())
    return {'ranges': ranges, **scan}


def _obstacles(scan):
    """Return scan_to_obstacles of a drawn scan."""
    return scan_to_obstacles(**scan)


# -- properties ------------------------------------------------------------------------------

@SETTINGS
@given(scans())
def test_every_kept_endpoint_is_within_tolerance_of_a_polygon(scan):
    """Valid endpoints outside the footprint are within split_tolerance + t / 2 of a polygon.

    That bound is at most cluster_tolerance (ScanSettings requires it).
    """
    setup = scan['settings']
    ranges = scan['ranges']
    with np.errstate(invalid='ignore'):
        valid = (np.isfinite(ranges) & (ranges > 0) & (ranges >= scan['range_min'])
                 & (ranges <= scan['range_max']))
    points = _endpoints(scan)[valid]
    reach = np.linalg.norm(points - np.asarray(scan['robot_pose'][:2]), axis=1)
    points = points[reach > setup.footprint_radius + 1e-9]
    bound = setup.split_tolerance + setup.segment_thickness / 2
    gaps = _nearest_polygon_distances(points, _obstacles(scan))
    assert bound <= setup.cluster_tolerance
    assert (gaps <= bound + 1e-9).all(), f'uncovered endpoints {points[gaps > bound + 1e-9]}'


@SETTINGS
@given(scans())
def test_no_polygon_comes_within_the_footprint(scan):
    """Every polygon is farther than footprint_radius from the base, so none contains it."""
    base = np.asarray(scan['robot_pose'][:2])[None]
    for obstacle in _obstacles(scan):
        distance = _distances(base, obstacle.polygon)[0]
        assert distance > 0, f'{obstacle.key} contains the base'
        assert distance >= scan['settings'].footprint_radius - 1e-9, obstacle.key


@SETTINGS
@given(scans())
def test_polygons_are_convex_ccw_finite_and_not_degenerate(scan):
    """Every polygon is a finite convex CCW polygon of area >= t D; obstacles are static."""
    area = scan['settings'].segment_thickness * scan['settings'].depth
    obstacles = _obstacles(scan)
    for obstacle in obstacles:
        problem = _convex_ccw_problem(obstacle.polygon)
        assert problem is None, f'{obstacle.key}: {problem}'
        assert _signed_area(obstacle.polygon) >= area * (1 - 1e-6)
        assert not obstacle.velocity.any()
        assert (obstacle.z_min, obstacle.z_max) == (-np.inf, np.inf)
    assert [o.key for o in obstacles] == [f'scan/{i}' for i in range(len(obstacles))]


# -- endpoints -------------------------------------------------------------------------------

def test_nan_inf_negative_and_out_of_range_beams_are_dropped():
    """Only finite positive ranges within [range_min, range_max] (bounds included) are kept."""
    ranges = [1.0, np.nan, np.inf, -np.inf, 0.05, 20.0, -1.0, 0.0, 0.1, 10.0]
    increment = 2 * math.pi / len(ranges)
    args = (ranges, 0.0, increment, 0.1, 10.0, ORIGIN, ORIGIN)
    kept = [0, 8, 9]
    expected = [[ranges[i] * math.cos(i * increment), ranges[i] * math.sin(i * increment)]
                for i in kept]
    np.testing.assert_allclose(scan_points(*args), expected, atol=1e-12)
    endpoints = beam_endpoints(*args)
    assert endpoints.shape == (10, 2)
    assert np.flatnonzero(~np.isnan(endpoints).any(axis=1)).tolist() == kept
    assert np.isnan(np.delete(endpoints, kept, axis=0)).all()
    assert len(scan_to_obstacles(*args)) == 3


def test_sensor_pose_and_robot_pose_are_applied():
    """Sensor at (0.2, 0, pi/2) on a robot at (1, 2, pi/2): it sits at (1, 2.2) facing -x."""
    points = scan_points([1.0, 1.0], 0.0, math.pi / 2, 0.0, 5.0, (0.2, 0.0, math.pi / 2),
                         (1.0, 2.0, math.pi / 2))
    np.testing.assert_allclose(points, [[0.0, 2.2], [1.0, 1.2]], atol=1e-12)


def test_empty_and_all_nan_scans_give_no_obstacles():
    """No returns, no obstacles."""
    assert scan_to_obstacles([], 0.0, 0.01, 0.1, 10.0, ORIGIN, ORIGIN) == []
    assert scan_to_obstacles(np.full(1081, np.nan), -2.36, 0.0044, 0.1, 30.0, ORIGIN,
                             ORIGIN) == []


# -- clustering and pieces -------------------------------------------------------------------

def _scene(walls):
    """Return the obstacles of walls seen by 181 beams over 180 degrees from the origin."""
    ranges = _cast(walls, 181, 0.0, math.pi / 180)
    return scan_to_obstacles(ranges, 0.0, math.pi / 180, 0.05, 10.0, ORIGIN, ORIGIN)


def test_a_straight_wall_becomes_one_thin_rectangle_behind_it():
    """A wall at y = 2: one rectangle from the first to the last hit, D deep, beyond y = 2."""
    obstacles = _scene([((-1.0, 2.0), (1.0, 2.0))])
    assert len(obstacles) == 1
    polygon = obstacles[0].polygon
    assert len(polygon) == 4
    np.testing.assert_allclose(polygon[:, 1].min(), 2.0, atol=1e-9)
    np.testing.assert_allclose(polygon[:, 1].max(), 2.0 + ScanSettings().depth, atol=1e-9)
    assert polygon[:, 0].min() == pytest.approx(-1.0, abs=0.04)
    assert polygon[:, 0].max() == pytest.approx(1.0, abs=0.04)


def test_two_walls_with_a_gap_are_separate_obstacles():
    """Beams through a gap reach a far wall: the near walls are one obstacle each."""
    obstacles = _scene([((-1.5, 2.0), (-0.3, 2.0)), ((0.3, 2.0), (1.5, 2.0)),
                        ((-1.0, 4.0), (1.0, 4.0))])
    near = [o.polygon for o in obstacles if o.polygon[:, 1].max() < 3.0]
    assert len(near) == 2
    left, right = sorted(near, key=lambda polygon: polygon[:, 0].min())
    assert left[:, 0].max() < -0.25 and right[:, 0].min() > 0.25


def test_beams_without_return_break_a_cluster():
    """Two collinear walls 0.1 m apart (less than cluster_tolerance) with nothing behind."""
    obstacles = _scene([((-1.5, 2.0), (-0.05, 2.0)), ((0.05, 2.0), (1.5, 2.0))])
    assert len(obstacles) == 2


def test_an_l_shaped_wall_becomes_two_pieces():
    """A corner at (1, 2): one rectangle along each wall (ending at the hits nearest it)."""
    obstacles = _scene([((-1.0, 2.0), (1.0, 2.0)), ((1.0, 2.0), (1.0, 0.5))])
    assert len(obstacles) == 2
    flat, upright = sorted((o.polygon for o in obstacles), key=lambda p: np.ptp(p[:, 1]))
    depth = ScanSettings().depth
    assert np.ptp(flat[:, 0]) > 1.9 and np.ptp(flat[:, 1]) < depth + 0.03
    assert np.ptp(upright[:, 1]) > 1.4 and np.ptp(upright[:, 0]) < depth + 0.03
    assert upright[:, 0].min() == pytest.approx(1.0, abs=0.03)


def test_a_360_degree_scan_joins_the_cluster_across_its_seam():
    """A room with a doorway: the east wall, across the seam, is one piece only when wrapped."""
    walls = [ROOM[0], ROOM[1], ((-2.0, 2.0), (-2.0, 0.5)), ((-2.0, -0.5), (-2.0, -2.0)),
             ROOM[3]]
    increment = 2 * math.pi / 360
    ranges = _cast(walls, 360, 0.0, increment)
    assert scan_wraps(360, increment)
    wrapped = scan_to_obstacles(ranges, 0.0, increment, 0.05, 10.0, ORIGIN, ORIGIN)
    endpoints = beam_endpoints(ranges, 0.0, increment, 0.05, 10.0, ORIGIN, ORIGIN)
    assert len(wrapped) == 5
    assert len(scan_obstacles(endpoints, (0.0, 0.0), wraps=False)) == 6
    east = [o.polygon for o in wrapped if o.polygon[:, 0].min() > 1.9]
    assert len(east) == 1 and np.ptp(east[0][:, 1]) > 3.9


def test_a_closed_ring_is_opened_at_a_corner():
    """All 360 beams hit a square room: four walls, four pieces (five without the wrap)."""
    increment = 2 * math.pi / 360
    ranges = _cast(ROOM, 360, 0.0, increment)
    assert np.isfinite(ranges).all()
    obstacles = scan_to_obstacles(ranges, 0.0, increment, 0.05, 10.0, ORIGIN, ORIGIN)
    assert len(obstacles) == 4
    endpoints = beam_endpoints(ranges, 0.0, increment, 0.05, 10.0, ORIGIN, ORIGIN)
    assert len(scan_obstacles(endpoints, (0.0, 0.0), wraps=False)) == 5
    assert _nearest_polygon_distances(endpoints, obstacles).max() <= 1e-9


def test_a_ring_leaves_no_gap_between_linked_points():
    """Points 0.14 m apart round a square, wrapping: every link's midpoint is covered too."""
    perimeter = np.linspace(0.0, 8.0, 57, endpoint=False)
    side, along = perimeter // 2, perimeter % 2 - 1
    corners = np.array([[1.0, -1.0], [1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0]])
    directions = np.array([[0.0, 1.0], [-1.0, 0.0], [0.0, -1.0], [1.0, 0.0]])
    points = corners[side.astype(int)] + (along + 1)[:, None] * directions[side.astype(int)]
    setup = ScanSettings()
    obstacles = scan_obstacles(points, (0.0, 0.0), setup, wraps=True)
    midpoints = (points + np.roll(points, -1, axis=0)) / 2
    gaps = _nearest_polygon_distances(midpoints, obstacles)
    assert gaps.max() <= setup.split_tolerance + setup.segment_thickness / 2 + 1e-9
    assert len(obstacles) >= 4


def test_a_partial_scan_does_not_wrap():
    """A 270 degree scan's ends are not neighbours."""
    assert not scan_wraps(1081, math.radians(0.25))
    assert scan_wraps(1440, -math.radians(0.25))
    assert not scan_wraps(1, 2 * math.pi)


def test_footprint_hits_are_ignored():
    """A beam ending on the robot's own body (within footprint_radius of the base) is ignored."""
    ranges = [2.0, 0.4]  # sensor 0.3 m ahead of the base: beam 1 looks back at (-0.1, 0)
    obstacles = scan_to_obstacles(ranges, 0.0, math.pi, 0.05, 10.0, (0.3, 0.0, 0.0), ORIGIN,
                                  ScanSettings(footprint_radius=0.25))
    assert len(obstacles) == 1 and obstacles[0].polygon[:, 0].min() > 2.0
    assert len(scan_to_obstacles(ranges, 0.0, math.pi, 0.05, 10.0, (0.3, 0.0, 0.0),
                                 ORIGIN)) == 2


def test_a_link_across_the_footprint_is_cut():
    """Two endpoints 0.14 m apart either side of the base are not linked; 0.2 m off, they are."""
    setup = ScanSettings(footprint_radius=0.05)
    across = scan_obstacles([[-0.07, 0.0], [0.07, 0.0]], (0.0, 0.0), setup)
    beside = scan_obstacles([[-0.07, 0.2], [0.07, 0.2]], (0.0, 0.0), setup)
    assert len(across) == 2 and len(beside) == 1
    for obstacle in across:
        assert _distances(np.zeros((1, 2)), obstacle.polygon)[0] >= 0.05


def test_a_chord_across_the_footprint_is_split():
    """Three points within split_tolerance of a chord passing 0.01 m from the base: split."""
    points = [[-0.1, 0.01], [0.0, 0.058], [0.1, 0.01]]
    assert len(scan_obstacles(points, (0.0, 0.0), ScanSettings(footprint_radius=0.0))) == 1
    split = scan_obstacles(points, (0.0, 0.0), ScanSettings(footprint_radius=0.05))
    assert len(split) == 2
    for obstacle in split:
        assert _distances(np.zeros((1, 2)), obstacle.polygon)[0] >= 0.05
    assert _nearest_polygon_distances(np.array(points), split).max() <= 0.05 + 0.01


def test_min_cluster_points_drops_small_clusters():
    """Lone returns are noise when clusters need two points; the wall stays."""
    ranges = _cast([((-1.0, 2.0), (1.0, 2.0))], 181, 0.0, math.pi / 180)
    ranges[[10, 20, 170]] = 3.0  # isolated returns far from their neighbours
    args = (ranges, 0.0, math.pi / 180, 0.05, 10.0, ORIGIN, ORIGIN)
    assert len(scan_to_obstacles(*args)) == 4
    assert len(scan_to_obstacles(*args, ScanSettings(min_cluster_points=2))) == 1


def test_max_obstacles_keeps_the_closest():
    """Ten isolated returns at ranges 1..10 m: a cap of 3 keeps those at 1, 2 and 3 m."""
    ranges = np.arange(1.0, 11.0)
    np.random.default_rng(3).shuffle(ranges)
    args = (ranges, 0.0, 2 * math.pi / 10, 0.05, 20.0, ORIGIN, ORIGIN)
    assert len(scan_to_obstacles(*args)) == 10
    capped = scan_to_obstacles(*args, ScanSettings(max_obstacles=3))
    reach = sorted(np.linalg.norm(o.polygon, axis=1).min() for o in capped)
    np.testing.assert_allclose(reach, [1.0, 2.0, 3.0], atol=0.011)
    assert [o.key for o in capped] == ['scan/0', 'scan/1', 'scan/2']


def test_obstacles_feed_an_obstacle_set():
    """ObstacleSet.from_obstacles takes the obstacles as they are: one convex part each."""
    walls = ROOM + [((0.5, 0.5), (1.0, 0.6)), ((1.0, 0.6), (0.9, 1.2)), ((-1.0, -1.0),
                                                                        (-0.8, -1.2))]
    ranges = _cast(walls, 1081, -math.radians(135), math.radians(0.25))
    ranges += np.random.default_rng(1).normal(0.0, 0.01, len(ranges))
    obstacles = scan_to_obstacles(ranges, -math.radians(135), math.radians(0.25), 0.05, 30.0,
                                  ORIGIN, (0.5, -0.5, 0.3))
    obstacle_set = ObstacleSet.from_obstacles(obstacles)
    assert len(obstacles) > 4
    assert len(obstacle_set) == len(obstacles)
    assert obstacle_set.is_finite() and obstacle_set.capped == ()
    assert obstacle_set.keys == tuple(o.key for o in obstacles)
    assert not obstacle_set.velocities.any()


# -- malformed arguments -----------------------------------------------------------------------

GOOD = {'ranges': [1.0, 2.0], 'angle_min': 0.0, 'angle_increment': 0.01, 'range_min': 0.1,
        'range_max': 10.0, 'sensor_pose': ORIGIN, 'robot_pose': ORIGIN}


@pytest.mark.parametrize('name, value, message', [
    ('angle_increment', 0.0, 'angle_increment must not be zero'),
    ('angle_increment', np.nan, 'angle_increment'),
    ('angle_increment', np.inf, 'angle_increment'),
    ('angle_min', np.nan, 'angle_min'),
    ('range_min', 11.0, 'range_min 11.0 must not exceed range_max'),
    ('range_max', np.nan, 'range_max'),
    ('sensor_pose', (0.0, np.nan, 0.0), 'sensor_pose'),
    ('robot_pose', (0.0, 0.0, np.inf), 'robot_pose'),
    ('robot_pose', (0.0, 0.0), 'robot_pose'),
    ('ranges', [[1.0, 2.0]], 'ranges must be a 1-D array'),
    ('ranges', ['a', 'b'], 'ranges'),
])
def test_malformed_scan_arguments_raise(name, value, message):
    """Each malformed argument is refused with a message naming it."""
    with pytest.raises(ValueError, match=message):
        scan_to_obstacles(**{**GOOD, name: value})
    with pytest.raises(ValueError, match=message):
        scan_points(**{**GOOD, name: value})


@pytest.mark.parametrize('endpoints, position, message', [
    (np.zeros((3, 3)), (0.0, 0.0), 'endpoints must have shape'),
    (np.zeros(4), (0.0, 0.0), 'endpoints must have shape'),
    (np.zeros((3, 2)), (0.0, np.nan), 'robot_position'),
])
def test_malformed_endpoints_raise(endpoints, position, message):
    """scan_obstacles refuses endpoints not shaped (N, 2) and a non-finite position."""
    with pytest.raises(ValueError, match=message):
        scan_obstacles(endpoints, position)


@pytest.mark.parametrize('field, value', [
    ('cluster_tolerance', 0.0), ('cluster_tolerance', np.inf), ('segment_thickness', -0.1),
    ('segment_thickness', 0.0), ('depth', 0.01), ('depth', np.nan), ('split_tolerance', -0.01),
    ('split_tolerance', 0.2),
    ('footprint_radius', np.nan), ('footprint_radius', -1.0), ('min_cluster_points', 0),
    ('min_cluster_points', 1.5), ('max_obstacles', 0), ('max_obstacles', True),
    ('cluster_tolerance', '0.1'),
])
def test_bad_settings_raise_naming_the_field(field, value):
    """ScanSettings refuses out-of-range fields, naming them (split_tolerance: coverage)."""
    with pytest.raises(ValueError, match=field):
        ScanSettings(**{field: value})


def test_default_settings_are_valid():
    """The defaults pass validate() and keep the coverage bound below cluster_tolerance."""
    setup = ScanSettings()
    setup.validate()
    assert setup.split_tolerance + setup.segment_thickness / 2 <= setup.cluster_tolerance


@pytest.mark.parametrize('radius, distance', [(0.3, 1.0), (0.1, 0.6), (1.0, 3.0)])
def test_a_cylinder_is_no_farther_than_its_surface(radius, distance):
    """Every hit lies in a polygon: no near edge lags behind the surface's bulge.

    1081 beams over 270 degrees (0.25 degree spacing) on a cylinder straight ahead.  Each
    piece's chord lies up to ``split_tolerance`` (5 cm) behind the surface; its near edge
    is brought forward to its points, so the nearest polygon is as near as the cylinder (up
    to the surface's sagitta between two beams), and nearer by at most that tolerance.
    """
    count, increment = 1081, math.radians(0.25)
    angle_min = -math.radians(135.0)
    angles = angle_min + increment * np.arange(count)
    along = distance * np.cos(angles)
    across = distance ** 2 * np.sin(angles) ** 2
    ranges = np.where(across <= radius ** 2, along - np.sqrt(np.maximum(radius ** 2 - across,
                                                                       0.0)), np.inf)
    ranges = np.where(along > 0, ranges, np.inf)
    obstacles = scan_to_obstacles(ranges, angle_min, increment, 0.05, 10.0, ORIGIN, ORIGIN)
    assert obstacles
    nearest = min(_distances(np.zeros((1, 2)), o.polygon)[0] for o in obstacles)
    sagitta = distance * increment ** 2 / 8.0 * distance / radius
    # The deepest point is a corner: the rest of the arc bulges about a quarter as far.
    tolerance = ScanSettings().split_tolerance / 2
    assert distance - radius - tolerance - 1e-9 <= nearest <= distance - radius + sagitta + 1e-9
    kept = np.isfinite(ranges)
    hits = ranges[kept, None] * np.column_stack([np.cos(angles[kept]), np.sin(angles[kept])])
    gaps = _nearest_polygon_distances(hits, obstacles)
    assert (gaps <= 1e-9).all(), f'hits in front of every polygon: {hits[gaps > 1e-9][:3]}'


@pytest.mark.parametrize('sides, radius', [(4, 0.7), (8, 0.25), (12, 0.4)])
@pytest.mark.parametrize('turn', [0.0, 0.1, 0.2, 0.3])
def test_a_polygon_corner_is_followed_not_cut_off(sides, radius, turn):
    """No polygon corner stands more than t / 2 in front of a box's or pillar's faces.

    A regular polygon 2 m ahead, turned by ``turn``: a piece spanning one of its corners
    takes the corner as its fifth vertex, so its near side follows both faces (moved as a
    whole, it stood up to ``split_tolerance`` in front of them next to the corner: a gap
    between two pillars narrowed by twice that).  t / 2: a face seen at a grazing angle has
    hits too far apart to link, each a t x t square centred on its hit.
    """
    angles = turn + 2.0 * math.pi * np.arange(sides) / sides
    corners = np.array([2.0, 0.1]) + radius * np.column_stack([np.cos(angles),
                                                               np.sin(angles)])
    walls = [(tuple(corners[k]), tuple(corners[(k + 1) % sides])) for k in range(sides)]
    count, increment = 1081, math.radians(0.25)
    ranges = _cast(walls, count, -math.radians(135.0), increment)
    obstacles = scan_to_obstacles(ranges, -math.radians(135.0), increment, 0.05, 10.0,
                                  ORIGIN, ORIGIN)
    assert obstacles
    vertices = np.concatenate([o.polygon for o in obstacles])
    outside = _distances(vertices, corners)  # counter-clockwise
    assert outside.max() <= ScanSettings().segment_thickness / 2 + 1e-9, \
        f'a corner {outside.max():.4f} m in front of the faces: {vertices[outside.argmax()]}'


def test_pose_at_interpolates_the_odometry_around_the_scan():
    """Between the samples around the stamp, linearly; the yaw along the shorter arc.

    At a sample's stamp: that sample (the later of two with one stamp); outside the
    samples' span the nearest end; all stamps 0 or an unstamped scan (0): the latest; no
    sample: None.  The order of the samples does not matter.
    """
    odometry = ((1.0, 0.0, 0.0, 0.0), (2.0, 1.0, 0.0, 0.5), (3.0, 2.0, 1.0, 1.0))
    assert pose_at(odometry, 2.25) == pytest.approx((1.25, 0.25, 0.625))
    assert pose_at(odometry[::-1], 2.25) == pytest.approx((1.25, 0.25, 0.625))
    assert pose_at(odometry, 2.0) == (1.0, 0.0, 0.5)
    assert pose_at(odometry, 0.5) == (0.0, 0.0, 0.0)
    assert pose_at(odometry, 9.0) == (2.0, 1.0, 1.0)
    assert pose_at(odometry, 0.0) == (2.0, 1.0, 1.0)  # an unstamped scan
    across = ((0.0, 0.0, 0.0, math.pi - 0.1), (1.0, 0.0, 0.0, -math.pi + 0.1))
    assert math.remainder(pose_at(across, 0.5)[2] - math.pi, math.tau) == pytest.approx(0.0)
    twice = ((2.0, 0.0, 0.0, 0.0), (2.0, 5.0, 0.0, 0.0))
    assert pose_at(twice, 2.0) == (5.0, 0.0, 0.0)  # same stamp: the later sample
    unstamped = tuple((0.0, float(x), 0.0, 0.0) for x in range(3))
    assert pose_at(unstamped, 7.0) == (2.0, 0.0, 0.0)
    assert pose_at((), 2.0) is None and pose_at((), 0.0) is None


@SETTINGS
@given(st.floats(-10, 10), st.floats(-10, 10), st.floats(-math.pi, math.pi),
       st.floats(-2.5, 2.5), st.floats(-2.5, 2.5), st.floats(-3.0, 3.0),
       st.floats(0.001, 0.1), st.floats(0.0, 1.0), st.floats(1.0, 1e5))
def test_pose_at_follows_a_base_between_two_odometry_messages(x, y, yaw, vx, vy, omega, period,
                                                              share, start):
    """A base moving at a constant velocity and turn rate is placed where it was at the stamp.

    Odometry at ``start`` and ``start + period``; the yaw wrapped to (-pi, pi] as a message
    carries it, and turning less than half a turn per period (3 rad/s, 0.1 s at most).
    """
    def at(t):
        return (x + vx * t, y + vy * t, math.remainder(yaw + omega * t, math.tau))

    odometry = ((start, *at(0.0)), (start + period, *at(period)))
    pose = pose_at(odometry, start + share * period)
    truth = at(share * period)
    assert pose[:2] == pytest.approx(truth[:2], abs=1e-9)
    assert math.remainder(pose[2] - truth[2], math.tau) == pytest.approx(0.0, abs=1e-9)


def test_a_chord_beside_the_robot_is_still_brought_to_its_points():
    """A chord whose line passes within the footprint, though the chord does not.

    Its points bulge 3 cm towards the robot; the near edge must still come forward past
    them (capped by the edge's line it stayed on the chord: a BARN graze in scan mode),
    and the polygon must stay outside the footprint.
    """
    a, b = np.array([0.25, 0.05]), np.array([0.55, 0.35])
    along = np.linspace(0.0, 1.0, 30)
    direction = (b - a) / np.linalg.norm(b - a)
    towards = np.array([direction[1], -direction[0]])
    if towards @ -a < 0:
        towards = -towards
    points = a + along[:, None] * (b - a) + 0.03 * np.sin(np.pi * along)[:, None] * towards
    assert np.linalg.norm(points, axis=1).min() > 0.2
    settings = ScanSettings(footprint_radius=0.2)
    obstacles = scan_obstacles(points, (0.0, 0.0), settings)
    assert _nearest_polygon_distances(points, obstacles).max() <= 1e-9
    assert min(_distances(np.zeros((1, 2)), o.polygon)[0] for o in obstacles) >= 0.2 - 1e-9


def test_a_surface_lit_at_grazing_incidence_reaches_away_from_the_laser():
    """The laser 5.5 cm ahead of the base; a wall whose line runs between the two.

    The beams crossed the laser's side of the wall, so every polygon lies on the other side,
    ``depth`` deep, though the base is on that side (away from the base, the polygons
    reached 10 cm into the space the beams had crossed).
    """
    point, direction = np.array([-0.0275, 0.0]), np.array([0.5, math.sqrt(0.75)])
    wall = (tuple(point + 0.3 * direction), tuple(point + 0.7 * direction))
    increment = math.pi / 720
    ranges = _cast([wall], 1081, -0.75 * math.pi, increment)
    settings = ScanSettings(footprint_radius=0.2)
    obstacles = scan_to_obstacles(ranges, -0.75 * math.pi, increment, 0.05, 10.0,
                                  (0.055, 0.0, 0.0), (-0.055, 0.0, 0.0), settings)
    assert obstacles

    def side(points):
        """Signed distance from the wall's line, positive on the base's side."""
        rel = np.asarray(points) - point
        return direction[0] * rel[..., 1] - direction[1] * rel[..., 0]

    assert side(np.zeros(2)) < 0 < side(np.array([-0.055, 0.0]))  # laser / base
    vertices = np.concatenate([o.polygon for o in obstacles])
    assert side(vertices).min() >= -1e-6
    assert side(vertices).max() == pytest.approx(settings.depth, abs=1e-6)


@st.composite
def _chains(draw):
    """Random point chains (noisy arcs and corners, repeated points) and their cluster ends."""
    count = draw(st.integers(2, 120))
    seed = draw(st.integers(0, 2 ** 32 - 1))
    rng = np.random.default_rng(seed)
    angles = np.cumsum(rng.normal(0.0, draw(st.sampled_from([0.0, 0.05, 0.5])), count))
    steps = np.where(rng.random(count) < 0.1, 0.0, rng.uniform(0.001, 0.05, count))
    points = np.cumsum(np.column_stack((np.cos(angles), np.sin(angles))) * steps[:, None],
                       axis=0)
    points = np.round(points, draw(st.sampled_from([2, 3, 12])))  # ties between deviations
    inner = rng.choice(np.arange(1, count - 1), size=min(count - 2, draw(st.integers(0, 4))),
                       replace=False) if count > 2 else np.zeros(0, dtype=np.int64)
    ends = np.unique(np.concatenate(([0, count - 1], inner))).astype(np.int64)
    return points, ends, draw(st.sampled_from([0.0, 0.001, 0.01, 0.05]))


@SETTINGS
@given(_chains())
def test_the_compiled_split_gives_the_ends_of_splitting_a_level_at_a_time(chain):
    """``kernels.scan.split_to_tolerance`` against its numpy form, bit for bit.

    Depth first, left first, every piece split at its first farthest point: the same sorted
    ends as the numpy oracle that splits every piece one level at a time.
    """
    points, ends, tolerance = chain
    px, py = np.ascontiguousarray(points[:, 0]), np.ascontiguousarray(points[:, 1])
    expected = split_to_tolerance_by_levels(px, py, ends.copy(), tolerance)
    got = _split_to_tolerance(px, py, ends, tolerance)
    assert np.array_equal(got, expected)
    assert np.all(np.diff(got) > 0) and got[0] == ends[0] and got[-1] == ends[-1]


@SETTINGS
@given(_chains(), st.floats(-1.5, 1.5), st.floats(0.3, 2.0), st.floats(0.0, 0.3),
       st.sampled_from([(0.0, 0.0), (0.3, 0.0), (0.0, 0.6), (-0.2, 2.0)]))
def test_the_compiled_front_gives_the_polygons_of_the_numpy_steps(chain, across, away, radius,
                                                                  laser):
    """``kernels.scan.front`` against its numpy form, bit for bit, on pieces of random chains.

    The chain's pieces (split at 1 cm) become ``_rectangles`` seen from a laser at the base
    beside the chain or off it (then some have the base on their far side); both bring
    their near sides to the points (step 6) and agree on every corner.
    """
    points, ends, _ = chain
    px, py = np.ascontiguousarray(points[:, 0]), np.ascontiguousarray(points[:, 1])
    ends = _split_to_tolerance(px, py, ends, 0.01)
    first, last = ends[:-1].copy(), ends[1:].copy()
    base = np.array([points[:, 0].mean() + across, points[:, 1].min() - away])
    polygons = _rectangles(px[first], py[first], px[last], py[last], base + laser, 0.02, 0.1)
    got = _front(polygons, px, py, first, last, base, radius)
    expected = front_by_arrays(polygons, px, py, first, last, base, radius)
    assert len(got) == len(expected) == len(first)
    assert all(a.shape == b.shape and np.array_equal(a, b) for a, b in zip(got, expected))
