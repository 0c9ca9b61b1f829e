"""Obstacle-set kernels agree with plain numpy formulations of the same geometry.

References: the Minkowski sum as the convex hull of all vertex sums (the
formulation the kernel replaced), the minimum enclosing circle by brute force,
the convexity test by turns and winding number in numpy, the thin axis by
trying every edge normal, exits by signed distances; the set construction
against the per-obstacle ``is_convex`` / ``decompose_convex`` path.
"""
import itertools
import math

import numpy as np
import pytest
from hypothesis import given, HealthCheck, settings, strategies as st

from polyc2bf_ros.core.barrier.cones import CircleCone, InflatedCone, PaperCone
from polyc2bf_ros.core.geometry.polygons import (
    convex_hull,
    decompose_convex,
    is_convex,
    PolygonBatch,
    signed_area,
    signed_distance,
    signed_distance_batch,
)
from polyc2bf_ros.core.geometry.views import prepare_views
from polyc2bf_ros.core.obstacles.obstacle_set import Obstacle, ObstacleSet
from strategies import convex_polygons, examples

SETTINGS = settings(max_examples=examples(150), deadline=None,
                    suppress_health_check=[HealthCheck.too_slow])
polygon_lists = st.lists(convex_polygons(centre_range=5.0), min_size=1, max_size=6)


def reference_minkowski(polygon, radius, segments):
    """Return hull{v_i + q_j}: the sum with the circumscribing regular ``segments``-gon."""
    angles = 2.0 * np.pi * np.arange(segments) / segments
    reach = radius / np.cos(np.pi / segments)
    offsets = reach * np.column_stack((np.cos(angles), np.sin(angles)))
    return convex_hull((polygon[:, None, :] + offsets).reshape(-1, 2))


@pytest.mark.parametrize('segments', [3, 4, 7, 16, 32])
@SETTINGS
@given(polygons=polygon_lists, radius=st.floats(0.01, 1.0))
def test_minkowski_kernel_is_the_hull_of_vertex_sums(segments, polygons, radius):
    """Same polygon as hull{v_i + q_j}: same area, vertices on each other's boundary."""
    cone_model = InflatedCone(radius, segments)
    prepared = cone_model.prepare(PolygonBatch.from_polygons(polygons))
    assert prepared.batch.convex_ccw().all()
    for n, polygon in enumerate(polygons):
        inflated = np.column_stack((prepared.x[n, :prepared.counts[n]],
                                    prepared.y[n, :prepared.counts[n]]))
        reference = reference_minkowski(polygon, radius, segments)
        assert prepared.counts[n] <= len(polygon) + segments
        assert signed_area(inflated) == pytest.approx(signed_area(reference), rel=1e-9)
        scale = 1e-9 * (1.0 + np.abs(reference).max())
        for vertex in inflated:
            assert abs(signed_distance(vertex, reference)) <= scale
        for vertex in reference:
            assert np.min(np.hypot(*(inflated - vertex).T)) <= scale


def brute_force_circle(points):
    """Return (centre, radius): the smallest 1-, 2- or 3-point circle holding all points."""
    candidates = [(points[0], 0.0)]
    candidates += [(0.5 * (a + b), 0.5 * np.hypot(*(a - b)))
                   for a, b in itertools.combinations(points, 2)]
    for a, b, c in itertools.combinations(points, 3):
        matrix = np.array([b - a, c - a])
        if abs(np.linalg.det(matrix)) > 1e-9:
            offset = np.linalg.solve(matrix, 0.5 * np.sum(matrix ** 2, axis=1))
            candidates.append((a + offset, np.hypot(*offset)))
    holding = [(centre, r) for centre, r in candidates
               if np.all(np.hypot(*(points - centre).T) <= r * (1 + 1e-9) + 1e-9)]
    return min(holding, key=lambda circle: circle[1])


@SETTINGS
@given(polygons=polygon_lists)
def test_enclosing_circle_kernel_matches_brute_force(polygons):
    """C3BF circles: the unique minimum enclosing circle of each polygon, plus the radius."""
    prepared = CircleCone(0.25).prepare(PolygonBatch.from_polygons(polygons))
    for n, polygon in enumerate(polygons):
        centre, radius = brute_force_circle(polygon)
        assert prepared.radii[n] == pytest.approx(radius + 0.25, abs=1e-9)
        np.testing.assert_allclose(prepared.centres[:, n], centre, atol=1e-7)


def reference_convex_ccw(polygon):
    """Return the convexity test in numpy: edges, turns, area and winding number."""
    edges = np.roll(polygon, -1, axis=0) - polygon
    incoming = np.roll(edges, 1, axis=0)
    turn = incoming[:, 0] * edges[:, 1] - incoming[:, 1] * edges[:, 0]
    dot = np.einsum('ij,ij->i', incoming, edges)
    tol = 1e-12 * np.hypot(*incoming.T) * np.hypot(*edges.T)
    winding = np.sum(np.arctan2(turn, dot)) / (2 * np.pi)
    return bool(len(polygon) >= 3 and np.all(np.hypot(*edges.T) > 0) and np.all(turn >= -tol)
                and signed_area(polygon) > 0 and abs(winding - 1.0) < 1e-6)


def _shapes(seed):
    """Return convex, clockwise, non-convex, star-shaped and degenerate test polygons."""
    rng = np.random.default_rng(seed)
    hull = convex_hull(rng.uniform(-3, 3, (rng.integers(3, 12), 2)))
    star = np.array([[np.cos(a), np.sin(a)] for a in 4 * np.pi / 5 * np.arange(5)])
    dent = np.vstack((hull, hull.mean(axis=0, keepdims=True)))
    repeat = np.vstack((hull[:1], hull))
    straight = np.vstack((hull[:1], 0.5 * (hull[:1] + hull[1:2]), hull[1:]))
    spike = np.vstack((hull[:1], hull[:1] + 2 * (hull[1:2] - hull[:1]), hull[1:]))
    return [hull, hull[::-1], star, dent, repeat, straight, spike]


@settings(max_examples=examples(100), deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1))
def test_convexity_kernel_matches_numpy(seed):
    """Convex CCW and simple, exactly where the numpy turns-and-winding test says so."""
    shapes = [s for s in _shapes(seed) if len(s) >= 3]
    batch = PolygonBatch.pack(shapes)
    expected = [reference_convex_ccw(shape) for shape in shapes]
    assert list(batch.convex_ccw()) == expected
    assert expected[0] and not expected[1] and not expected[2]


@settings(max_examples=examples(100), deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1))
def test_obstacle_set_equals_the_per_obstacle_path(seed):
    """Fast path for convex footprints, decomposition for the others: parts as before."""
    rng = np.random.default_rng(seed)
    hull, _, _, dent, _, straight, _ = _shapes(seed)
    ell = np.array([[0, 0], [4, 0], [4, 1], [1, 1], [1, 3], [0, 3]], dtype=float) + 7.0
    shapes = [hull, straight, dent, ell]
    rng.shuffle(shapes)
    obstacles = [Obstacle(polygon=s, velocity=rng.uniform(-1, 1, int(rng.integers(2, 4))),
                          z_min=-1.0, z_max=float(i), key=str(i)) for i, s in enumerate(shapes)]
    built = ObstacleSet.from_obstacles(obstacles)
    parts, owner = [], []
    for index, obstacle in enumerate(obstacles):
        pieces = [obstacle.polygon] if is_convex(obstacle.polygon) else decompose_convex(
            obstacle.polygon)
        parts += pieces
        owner += [index] * len(pieces)
    reference = PolygonBatch.from_polygons(parts)
    np.testing.assert_array_equal(built.owner, owner)
    np.testing.assert_array_equal(built.footprints.counts, reference.counts)
    np.testing.assert_array_equal(built.footprints.vertices, reference.vertices)
    for row, index in zip(built.velocities, owner):
        given_velocity = obstacles[index].velocity
        np.testing.assert_array_equal(row[:len(given_velocity)], given_velocity)
        assert not row[len(given_velocity):].any()
    np.testing.assert_array_equal(built.z_ranges[:, 1], np.array(owner, dtype=float))
    assert built.keys == tuple(o.key for o in obstacles)


@SETTINGS
@given(polygons=polygon_lists, seed=st.integers(0, 2 ** 32 - 1))
def test_vertical_view_kernel_matches_numpy(polygons, seed):
    """Thin axis of minimum width, exact shadow rectangle, band and enabled flags."""
    rng = np.random.default_rng(seed)
    z = np.sort(rng.uniform(-1, 3, (len(polygons), 2)), axis=1)
    z[rng.random(len(polygons)) < 0.3] = [-np.inf, np.inf]
    z[rng.random(len(polygons)) < 0.2, 1] = z[0, 0]  # some empty or inverted ranges
    obstacles = ObstacleSet.from_obstacles([Obstacle(polygon=p, z_min=lo, z_max=hi)
                                            for p, (lo, hi) in zip(polygons, z)])
    view = prepare_views(obstacles, PaperCone(0.0), 3, 0.3)[1]
    shadows = view.prepared.batch
    for n, polygon in enumerate(polygons):
        axis = view.projections[n, 0, :2]
        widths = [np.ptp(polygon @ np.array([e[1], -e[0]]) / np.hypot(*e))
                  for e in np.roll(polygon, -1, axis=0) - polygon]
        assert np.ptp(polygon @ axis) == pytest.approx(min(widths), abs=1e-12)
        enabled = np.isfinite(z[n]).all() and z[n, 1] > z[n, 0]
        assert view.enabled[n] == enabled
        low, high = (polygon @ axis).min(), (polygon @ axis).max()
        z_low, z_high = z[n] if enabled else (-1.0, 1.0)
        np.testing.assert_allclose(shadows.vertices[n], [[low, z_low], [high, z_low],
                                                         [high, z_high], [low, z_high]],
                                   atol=1e-12)
        along = polygon @ view.long_axes[n]
        np.testing.assert_allclose(view.band[n], [along.min() - 0.3, along.max() + 0.3],
                                   atol=1e-12)
        np.testing.assert_array_equal(view.projections[n, 1], [0.0, 0.0, 1.0])


@pytest.mark.parametrize('cone_model', [PaperCone(0.0), PaperCone(0.3), InflatedCone(0.3)])
@SETTINGS
@given(polygons=polygon_lists, seed=st.integers(0, 2 ** 32 - 1))
def test_polygon_exits_are_the_shortest_way_out(cone_model, polygons, seed):
    """The depth is extension - signed distance; moving that far along the direction leaves."""
    prepared = cone_model.prepare(PolygonBatch.from_polygons(polygons))
    batch = prepared.batch
    rng = np.random.default_rng(seed)
    centres = np.array([p.mean(axis=0) for p in polygons])
    viewpoints = (centres + rng.uniform(-1.0, 1.0, centres.shape)).T.copy()
    exits = cone_model.exits(prepared, viewpoints)
    np.testing.assert_allclose(np.hypot(*exits[:2]), 1.0, rtol=1e-12)
    for n in range(len(polygons)):
        signed = signed_distance_batch(viewpoints[:, n], batch)[n]
        assert exits[2, n] == pytest.approx(cone_model.extension - signed, abs=1e-9)
        if exits[2, n] > 1e-6:
            assert not cone_model.cones(prepared, viewpoints).valid[n]
            out = viewpoints[:, n] + (exits[2, n] + 1e-6) * exits[:2, n]
            moved = viewpoints.copy()
            moved[:, n] = out
            assert cone_model.cones(prepared, moved).valid[n]


def test_circle_exits_point_away_from_the_centre():
    """C3BF: depth R - |q - c| along (q - c) / |q - c|."""
    cone_model = CircleCone(0.5)
    square = np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])
    prepared = cone_model.prepare(PolygonBatch.from_polygons([square]))
    exits = cone_model.exits(prepared, np.array([0.3, -0.4]))
    np.testing.assert_allclose(exits[:, 0], [0.6, -0.8, math.sqrt(2) + 0.5 - 0.5], rtol=1e-12)
