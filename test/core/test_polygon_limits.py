"""Bounded polygon sizes: the reductions contain their input and respect their caps."""
import math

import numpy as np
from hypothesis import given, strategies as st

from polyc2bf_ros.core.geometry.polygon_limits import (
    bounded_convex_parts,
    enclosing_polygon,
    reflex_count,
)
from polyc2bf_ros.core.geometry.polygons import (
    clean_polygon,
    convex_hull,
    is_convex,
    point_in_polygon,
    signed_area,
)
from polyc2bf_ros.core.obstacles.obstacle_set import Obstacle, ObstacleSet


def _star(points, inner=0.5, phase=0.0):
    """Return a star with ``points`` tips (2 * points vertices, ``points`` reflex ones)."""
    angles = phase + np.pi * np.arange(2 * points) / points
    radii = np.where(np.arange(2 * points) % 2 == 0, 1.0, inner)
    return np.column_stack([radii * np.cos(angles), radii * np.sin(angles)])


def _contains(polygon, points, tolerance=1e-9):
    """Return True when every point is in the convex CCW polygon (up to ``tolerance``)."""
    edges = np.roll(polygon, -1, axis=0) - polygon
    rel = points[:, None, :] - polygon[None, :, :]
    cross = edges[None, :, 0] * rel[..., 1] - edges[None, :, 1] * rel[..., 0]
    scale = np.hypot(*edges.T)[None, :]
    return bool(np.all(cross >= -tolerance * scale * (1.0 + np.abs(points).max())))


@given(st.integers(0, 2 ** 32 - 1), st.integers(3, 2000), st.integers(3, 64))
def test_enclosing_polygon_contains_every_point_within_the_cap(seed, count, max_vertices):
    """Convex, CCW, at most ``max_vertices`` vertices, every input point inside."""
    rng = np.random.default_rng(seed)
    points = rng.normal(size=(count, 2)) * rng.uniform(0.01, 10.0, 2) + rng.uniform(-50, 50, 2)
    polygon = enclosing_polygon(points, max_vertices)
    assert 3 <= len(polygon) <= max_vertices
    assert is_convex(polygon) and signed_area(polygon) > 0
    assert _contains(polygon, points)


def test_a_large_circle_becomes_a_tight_circumscribed_polygon():
    """10,000 points on a unit circle -> 64 vertices, within r (1/cos(pi/64) - 1) of it."""
    angles = np.linspace(0.0, 2.0 * np.pi, 10_000, endpoint=False)
    circle = np.column_stack([np.cos(angles), np.sin(angles)])
    polygon = enclosing_polygon(circle, 64)
    assert len(polygon) == 64 and _contains(polygon, circle)
    assert np.linalg.norm(polygon, axis=1).max() <= 1.0 / math.cos(math.pi / 64) + 1e-9


def test_a_small_hull_is_returned_as_it_is():
    """A hull within the cap is the convex hull itself."""
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0], [0.5, 0.5]])
    np.testing.assert_array_equal(enclosing_polygon(square, 8), convex_hull(square))


def test_reflex_count_of_a_star():
    """A star with k tips has k reflex vertices; a convex polygon none."""
    assert reflex_count(clean_polygon(_star(7))) == 7
    assert reflex_count(convex_hull(_star(7))) == 0


@given(st.integers(3, 40), st.integers(1, 40), st.floats(0.2, 0.8), st.floats(0.0, 1.0))
def test_bounded_parts_stay_within_the_cap_and_cover_the_polygon(tips, max_parts, inner, phase):
    """At most ``max_parts`` convex parts whose union covers the polygon (or its hull)."""
    polygon = clean_polygon(_star(tips, inner, phase))
    parts, capped = bounded_convex_parts(polygon, max_parts)
    assert 1 <= len(parts) <= max_parts
    assert all(is_convex(part) for part in parts)
    area = sum(signed_area(part) for part in parts)
    if capped:
        assert len(parts) == 1 and math.isclose(area, signed_area(convex_hull(polygon)))
    else:
        assert math.isclose(area, signed_area(polygon), rel_tol=1e-9)
    # Every vertex of the polygon lies in some part (closed sets).
    for vertex in polygon:
        nudged = vertex * (1.0 - 1e-9)
        assert any(point_in_polygon(nudged, part) or _contains(part, vertex[None])
                   for part in parts)


def test_a_star_of_many_tips_is_hulled_without_decomposing():
    """The reflex lower bound alone caps a 128-tip star at 16 parts: its hull, flagged."""
    star = Obstacle(polygon=_star(128), key='star')
    obstacles = ObstacleSet.from_obstacles([star], max_parts=16)
    assert len(obstacles) == 1 and obstacles.capped == ('star',)
    within = ObstacleSet.from_obstacles([Obstacle(polygon=_star(5), key='five')], max_parts=16)
    assert len(within) > 1 and within.capped == ()
