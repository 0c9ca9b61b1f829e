"""Property tests for polyc2bf_ros.core.geometry.polygons against brute-force references."""
import itertools
import math

import numpy as np
import pytest
from hypothesis import assume, example, given, settings, strategies as st
from scipy.spatial import ConvexHull

from oracles import inflate_polygon, silhouette_pair
from polyc2bf_ros.core.geometry.polygons import (
    clean_polygon,
    convex_hull,
    decompose_convex,
    InvalidPolygonError,
    is_convex,
    minimum_enclosing_circle,
    point_in_polygon,
    PolygonBatch,
    signed_area,
    signed_distance,
    signed_distance_batch,
    silhouette_indices,
    thin_axis,
    vertical_shadow,
)
from strategies import examples

SETTINGS = settings(max_examples=examples(100), deadline=None)
SQUARE = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])

small_ints = st.integers(-20, 20)
int_points = st.lists(st.tuples(small_ints, small_ints), min_size=3, max_size=14)
float_coords = st.floats(-10.0, 10.0, allow_nan=False, allow_infinity=False)


@st.composite
def integer_convex_polygons(draw):
    """Draw a convex CCW polygon with integer vertices (so orientation tests are exact)."""
    hull = convex_hull(draw(int_points))
    assume(len(hull) >= 3)
    return hull


@st.composite
def float_convex_polygons(draw):
    """Draw a convex CCW polygon with float vertices, non-negligible area and edges.

    Edges of ~1e-200 m (hypothesis finds them) square to zero: PolygonBatch rejects them.
    """
    hull = convex_hull(draw(st.lists(st.tuples(float_coords, float_coords), min_size=3,
                                     max_size=14)))
    assume(len(hull) >= 3 and signed_area(hull) > 0.5)
    assume(np.linalg.norm(np.roll(hull, -1, axis=0) - hull, axis=1).min() > 1e-9)
    return hull


@st.composite
def star_polygons(draw):
    """Draw a simple, usually non-convex, CCW polygon that is star-shaped about its centre."""
    n = draw(st.integers(3, 14))
    # No angular gap exceeds pi, so the vertices in angular order form a simple polygon.
    gaps = np.array(draw(st.lists(st.floats(0.5, 1.0), min_size=n, max_size=n)))
    angles = np.cumsum(gaps) * (2.0 * np.pi / gaps.sum())
    radii = np.array(draw(st.lists(st.floats(0.1, 3.0), min_size=n, max_size=n)))
    centre = np.array(draw(st.tuples(float_coords, float_coords)))
    return clean_polygon(centre + radii[:, None] * np.column_stack((np.cos(angles),
                                                                     np.sin(angles))))


def cross(u, v):
    """Return the z-component of u x v."""
    return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]


def reference_tangents(viewpoint, polygon):
    """Return the tangent vertices by exhaustive exact checks (integer input only).

    Vertex a bounds the view clockwise when every vertex is counter-clockwise of (or on) the
    ray to a; among several such vertices the one nearest the viewpoint is taken.
    """
    rays = polygon - viewpoint
    sides = cross(rays[:, None, :], rays[None, :, :])
    dist = np.hypot(*rays.T)
    cw = [a for a in range(len(polygon)) if np.all(sides[a] >= 0)]
    ccw = [a for a in range(len(polygon)) if np.all(sides[a] <= 0)]
    return min(cw, key=dist.__getitem__), min(ccw, key=dist.__getitem__)


def angles_from_centroid_ray(viewpoint, polygon):
    """Return each vertex's signed angle from the ray viewpoint -> vertex centroid."""
    axis = polygon.mean(axis=0) - viewpoint
    rays = polygon - viewpoint
    return np.arctan2(cross(axis, rays), rays @ axis)


def segment_distance(point, a, b):
    """Return the distance from point to segment ab, by projection."""
    ab = b - a
    t = min(1.0, max(0.0, float(np.dot(point - a, ab) / np.dot(ab, ab))))
    return float(np.hypot(*(point - a - t * ab)))


def boundary_distance(point, polygon):
    """Return the distance from point to the polygon boundary by looping over edges."""
    return min(segment_distance(point, polygon[k], polygon[(k + 1) % len(polygon)])
               for k in range(len(polygon)))


def winding_inside(point, polygon):
    """Return True when the angles subtended by the edges sum to 2 pi (point inside)."""
    rays = polygon - point
    turns = np.arctan2(cross(rays, np.roll(rays, -1, 0)), np.sum(rays * np.roll(rays, -1, 0), 1))
    return abs(turns.sum()) > np.pi


def seeded_rng(data):
    """Return a numpy generator seeded by hypothesis (cheaper than drawing every number)."""
    return np.random.default_rng(data.draw(st.integers(0, 2 ** 32 - 1), label='seed'))


def sample_points(source, polygon, count=15, margin=1.0):
    """Draw points uniformly from the polygon's bounding box grown by margin.

    ``source`` is hypothesis's ``data`` or a numpy generator (tests pinned with @example).
    """
    rng = source if isinstance(source, np.random.Generator) else seeded_rng(source)
    low, high = polygon.min(0) - margin, polygon.max(0) + margin
    return rng.uniform(low, high, size=(count, 2))


def outside_viewpoint(data, polygon, integer):
    """Draw a viewpoint strictly outside the polygon."""
    if integer:
        p = np.array(data.draw(st.tuples(st.integers(-40, 40), st.integers(-40, 40))), float)
    else:
        p = np.array(data.draw(st.tuples(st.floats(-30, 30), st.floats(-30, 30))))
    assume(signed_distance(p, polygon) > (0 if integer else 1e-6))
    return p


# --- silhouette ---------------------------------------------------------------------------

@SETTINGS
@given(integer_convex_polygons(), st.data())
def test_silhouette_matches_exhaustive_tangent_search_with_ties(polygon, data):
    """Tangent vertices equal an exact exhaustive search, ties going to the nearer vertex."""
    p = outside_viewpoint(data, polygon, integer=True)
    assert silhouette_pair(p, polygon) == reference_tangents(p, polygon)


@SETTINGS
@given(float_convex_polygons(), st.data())
def test_every_vertex_lies_in_the_cone_of_the_silhouette_pair(polygon, data):
    """All vertices lie angle-wise between the two tangent rays, on the inner side of each."""
    p = outside_viewpoint(data, polygon, integer=False)
    i, j = silhouette_pair(p, polygon)
    theta = angles_from_centroid_ray(p, polygon)
    assert theta[i] == pytest.approx(theta.min(), abs=1e-9)
    assert theta[j] == pytest.approx(theta.max(), abs=1e-9)
    assert np.all(theta >= theta[i] - 1e-9) and np.all(theta <= theta[j] + 1e-9)
    assert 0 <= theta[j] - theta[i] < np.pi
    rays = polygon - p
    scale = np.hypot(*rays.T).max() ** 2
    assert np.all(cross(rays[i], rays) >= -1e-9 * scale)
    assert np.all(cross(rays[j], rays) <= 1e-9 * scale)


@pytest.mark.parametrize('viewpoint, expected', [
    ((0.5, -1.0), (1, 0)),   # below: bottom edge faces the viewpoint
    ((1.0, -1.0), (1, 0)),   # right edge on the cw tangent ray: nearer vertex 1, not 2
    ((0.0, -2.0), (1, 0)),   # left edge on the ccw tangent ray: nearer vertex 0, not 3
    ((3.0, 1.0), (2, 1)),    # top edge on the cw tangent ray seen from the right
])
def test_silhouette_ties_pick_the_vertex_nearer_the_viewpoint(viewpoint, expected):
    """An edge lying on a tangent ray yields its endpoint nearer the viewpoint."""
    assert silhouette_pair(viewpoint, SQUARE) == expected


def test_silhouette_pair_rejects_inside_boundary_and_clockwise_input():
    """Viewpoints inside or on the polygon and clockwise polygons are refused."""
    for p in [(0.5, 0.5), (1.0, 0.5), (1.0, 1.0)]:
        with pytest.raises(ValueError, match='inside or on'):
            silhouette_pair(p, SQUARE)
    with pytest.raises(InvalidPolygonError):
        silhouette_pair((3.0, 3.0), SQUARE[::-1])


@SETTINGS
@given(st.lists(integer_convex_polygons(), min_size=1, max_size=6), st.data())
def test_silhouette_indices_agree_with_pair_on_ragged_batches(polygons, data):
    """The batched silhouette equals the single-polygon one for every padded polygon."""
    batch = PolygonBatch.from_polygons(polygons)
    p = np.array(data.draw(st.tuples(st.integers(-30, 30), st.integers(-30, 30))), float)
    i, j, outside = silhouette_indices(p, batch)
    assert i.shape == j.shape == outside.shape == (len(polygons),)
    for n, polygon in enumerate(polygons):
        assert outside[n] == (signed_distance(p, polygon) > 0)
        assert 0 <= i[n] < len(polygon) and 0 <= j[n] < len(polygon)
        if outside[n]:
            assert (i[n], j[n]) == silhouette_pair(p, polygon)


def test_silhouette_indices_of_empty_batch():
    """An empty batch gives empty index arrays."""
    i, j, outside = silhouette_indices((0.0, 0.0), PolygonBatch.from_polygons([]))
    assert i.shape == j.shape == outside.shape == (0,)


# --- polygon batch ------------------------------------------------------------------------

def test_batch_pads_with_last_vertex_and_translates():
    """Padding, translation and distances of a small ragged batch."""
    triangle = np.array([[0.0, 0.0], [2.0, 0.0], [0.0, 2.0]])
    batch = PolygonBatch.from_polygons([triangle, SQUARE + 5.0])
    assert batch.vertices.shape == (2, 4, 2) and len(batch) == 2
    assert np.array_equal(batch.vertices[0, 3], triangle[2])
    np.testing.assert_array_equal(batch.counts, [3, 4])
    moved = batch.translated([[1.0, 0.0], [0.0, -1.0]])
    assert np.allclose(moved.vertices[1], SQUARE + [5.0, 4.0])
    assert np.allclose(signed_distance_batch((1.5, 0.5), moved), [-0.5, 3.5 * np.sqrt(2)])
    rebuilt = PolygonBatch(moved.vertices, moved.counts)
    assert all(np.allclose(*pair) for pair in zip(rebuilt.edge_table, moved.edge_table))
    empty = PolygonBatch.from_polygons([])
    assert empty.vertices.shape == (0, 3, 2) and empty.counts.shape == (0,)
    assert len(empty) == 0


@pytest.mark.parametrize('polygons, reason', [
    ([SQUARE[::-1]], 'convex CCW'),
    ([np.array([[0, 0], [2, 0], [1, 0.5], [2, 2], [0, 2]])], 'convex CCW'),
    ([SQUARE[:2]], 'fewer than 3'),
    ([np.array([[0, 0], [1, 0], [1, 0], [0, 1]])], 'convex CCW'),
    ([SQUARE * np.nan], 'NaN'),
    ([np.zeros((4, 3))], 'shape'),
])
def test_batch_rejects_unusable_polygons(polygons, reason):
    """Clockwise, non-convex, short, repeated-vertex and non-finite polygons are refused."""
    with pytest.raises(InvalidPolygonError, match=reason):
        PolygonBatch.from_polygons(polygons)


# --- hull, convexity, decomposition -------------------------------------------------------

@SETTINGS
@given(int_points)
def test_convex_hull_matches_scipy(points):
    """The hull has the same vertex set as scipy ConvexHull and turns strictly left."""
    points = np.array(points, float)
    hull = convex_hull(points)
    if len(hull) < 3:
        assert np.linalg.matrix_rank(points - points[0]) < 2
        return
    reference = {tuple(points[k]) for k in ConvexHull(points).vertices}
    assert {tuple(v) for v in hull} == reference and len(hull) == len(reference)
    turn = cross(hull - np.roll(hull, 1, 0), np.roll(hull, -1, 0) - hull)
    assert np.all(turn > 0)


def test_convex_hull_of_degenerate_input():
    """Coincident or collinear points give a 1- or 2-point hull."""
    assert convex_hull([[1, 1], [1, 1]]).shape == (1, 2)
    assert np.array_equal(convex_hull([[0, 0], [2, 2], [1, 1]]), [[0, 0], [2, 2]])


def test_is_convex():
    """Squares of either orientation are convex; an L-shape and a pentagram are not."""
    assert is_convex(SQUARE) and is_convex(SQUARE[::-1])
    assert not is_convex([[0, 0], [2, 0], [2, 1], [1, 1], [1, 2], [0, 2]])
    pentagram = [(math.cos(a), math.sin(a)) for a in np.arange(5) * 4 * np.pi / 5]
    assert not is_convex(pentagram)


@SETTINGS
@given(star_polygons(), st.data())
def test_decompose_convex_partitions_the_polygon(polygon, data):
    """Parts are convex, tile the polygon and number at most 2r + 1."""
    parts = decompose_convex(polygon)
    for part in parts:
        assert is_convex(part) and signed_area(part) > 0
        assert {tuple(v) for v in part} <= {tuple(v) for v in polygon}
    assert sum(signed_area(part) for part in parts) == pytest.approx(signed_area(polygon),
                                                                     rel=1e-9)
    turn = cross(polygon - np.roll(polygon, 1, 0), np.roll(polygon, -1, 0) - polygon)
    assert len(parts) <= 2 * np.count_nonzero(turn < 0) + 1
    for q in sample_points(data, polygon, margin=0.5):
        d = signed_distance(q, polygon)
        if abs(d) > 1e-9:
            assert (d < 0) == any(point_in_polygon(q, part) for part in parts)


def test_decompose_convex_examples():
    """Hand-made convex, L-shaped and comb polygons split as expected."""
    assert len(decompose_convex(SQUARE)) == 1
    ell = np.array([[0, 0], [2, 0], [2, 1], [1, 1], [1, 2], [0, 2]], float)
    assert len(decompose_convex(ell)) == 2
    comb = np.array([[0, 0], [5, 0], [5, 2], [4, 2], [4, 1], [3, 1], [3, 2], [2, 2], [2, 1],
                     [1, 1], [1, 2], [0, 2]], float)
    parts = decompose_convex(comb)
    assert sum(map(signed_area, parts)) == pytest.approx(signed_area(comb))
    assert len(parts) <= 2 * 4 + 1


# --- inside test and distances ------------------------------------------------------------

@SETTINGS
@given(star_polygons(), st.data())
def test_signed_distance_and_point_in_polygon_match_brute_force(polygon, data):
    """Distance matches a per-edge loop and the sign matches a winding-angle test."""
    for q in sample_points(data, polygon):
        d = signed_distance(q, polygon)
        assert abs(d) == pytest.approx(boundary_distance(q, polygon), rel=1e-9, abs=1e-12)
        if abs(d) > 1e-9:
            assert point_in_polygon(q, polygon) == (d < 0) == winding_inside(q, polygon)


def test_boundary_points_count_as_inside():
    """Points on edges and vertices are inside at distance 0."""
    ell = np.array([[0, 0], [2, 0], [2, 1], [1, 1], [1, 2], [0, 2]], float)
    for q in [(1, 0), (2, 0.5), (1.5, 1), (1, 1), (0, 2), (0, 1)]:
        assert point_in_polygon(q, ell) and signed_distance(q, ell) == 0
    for q in [(1.5, 1.5), (3, 0), (-1, 1)]:
        assert not point_in_polygon(q, ell)


@SETTINGS
@given(st.lists(float_convex_polygons(), min_size=1, max_size=5), st.data())
def test_signed_distance_batch_matches_signed_distance(polygons, data):
    """The batched signed distance equals the single-polygon one."""
    batch = PolygonBatch.from_polygons(polygons)
    for q in sample_points(data, np.concatenate(polygons), count=10):
        expected = [signed_distance(q, polygon) for polygon in polygons]
        assert np.allclose(signed_distance_batch(q, batch), expected, rtol=1e-9, atol=1e-12)


# --- clean_polygon ------------------------------------------------------------------------

@pytest.mark.parametrize('points, reason', [
    ([[0, 0], [1, np.nan], [0, 1]], 'NaN or infinite'),
    ([[0, 0], [1, np.inf], [0, 1]], 'NaN or infinite'),
    ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], 'shape'),
    ([[[0, 0]], [[1, 0]], [[0, 1]]], 'shape'),
    ([[0, 0], [1, 0], [1, 0], [0, 0]], 'at least 3 distinct'),
    ([[0, 0], [1, 1], [2, 2], [3, 3]], 'collinear'),
    ([[0, 0], [1, 0], [1, 1], [1, 0]], 'zero area'),
    ([[0, 0], [1, 1], [1, 0], [0, 1]], 'self-intersecting'),
    ([[0, 0], [2, 0], [2, 2], [1, 0], [0, 2]], 'self-intersecting'),
    ([[0, 0], [2, 0], [1, 1], [2, 2], [0, 2], [1, 1]], 'self-intersecting'),
    ('not a polygon', 'numeric'),
])
def test_clean_polygon_rejects_with_a_reason(points, reason):
    """Unusable input raises InvalidPolygonError naming the reason."""
    with pytest.raises(InvalidPolygonError, match=reason):
        clean_polygon(points)


def test_clean_polygon_orients_and_removes_redundant_points():
    """A clockwise square with repeats, midpoints and a closing point comes back CCW."""
    messy = [[0, 0], [0, 1], [0, 1], [1, 1], [1, 0.5], [1, 0], [0.5, 0], [0, 0]]
    cleaned = clean_polygon(messy)
    assert cleaned.dtype == np.float64 and signed_area(cleaned) == pytest.approx(1.0)
    assert {tuple(v) for v in cleaned} == {tuple(v) for v in SQUARE} and len(cleaned) == 4


@SETTINGS
@given(star_polygons(), st.data())
def test_clean_polygon_recovers_a_polygon_from_redundant_input(polygon, data):
    """Repeats, edge midpoints, rotation, reversal and closing points are undone."""
    n = len(polygon)
    redundant = []
    for k in range(n):
        redundant.extend([polygon[k]] * data.draw(st.integers(1, 3)))
        if data.draw(st.booleans()):
            redundant.append(0.5 * (polygon[k] + polygon[(k + 1) % n]))
    redundant = np.roll(redundant, data.draw(st.integers(0, n)), axis=0)
    if data.draw(st.booleans()):
        redundant = redundant[::-1]
    cleaned = clean_polygon(np.vstack((redundant, redundant[:1])))
    assert signed_area(cleaned) == pytest.approx(signed_area(polygon), rel=1e-9)
    assert {tuple(v) for v in cleaned} == {tuple(v) for v in polygon}


# --- inflation, enclosing circle, thin axis, vertical shadow ------------------------------

@SETTINGS
@given(polygon=float_convex_polygons(), radius=st.floats(0.01, 2.0),
       segments=st.integers(3, 32), seed=st.integers(0, 2 ** 32 - 1))
# Issue 14: the bottom edge is parallel to one of the 14-gon's, and the merge left a
# straight vertex where the arc meets it.
@example(polygon=np.array([[0.0, -10.0], [4.0, -10.0], [0.0, 0.0]]), radius=1.0, segments=14,
         seed=0)
def test_inflate_polygon_contains_offset_set_and_is_tight(polygon, radius, segments, seed):
    """The inflated polygon turns left at every vertex, holds the offset set, stays within R.

    Strictly left: ``cross(e_in, e_out) > 1e-12 |e_in| |e_out|`` (no straight or repeated
    vertex, the tolerance of is_convex and PolygonBatch).
    """
    inflated = inflate_polygon(polygon, radius, segments)
    assert is_convex(inflated) and signed_area(inflated) > 0
    incoming = inflated - np.roll(inflated, 1, axis=0)
    outgoing = np.roll(incoming, -1, axis=0)
    turn = cross(incoming, outgoing)
    assert np.all(turn > 1e-12 * np.hypot(*incoming.T) * np.hypot(*outgoing.T)), turn
    reach = radius / math.cos(math.pi / segments)
    for vertex in inflated:
        assert signed_distance(vertex, polygon) <= reach + 1e-9
    rng = np.random.default_rng(seed)
    directions = rng.uniform(0, 2 * np.pi, 20)
    units = np.column_stack((np.cos(directions), np.sin(directions)))
    support = polygon[np.argmax(units @ polygon.T, axis=1)]
    for q in np.vstack((support + radius * units, sample_points(rng, polygon, 20, radius))):
        if signed_distance(q, polygon) <= radius:
            assert signed_distance(q, inflated) <= 1e-9


def test_inflate_polygon_zero_radius_copies_and_bad_arguments_raise():
    """Radius 0 returns a copy; negative radii and too few segments raise."""
    copy = inflate_polygon(SQUARE, 0.0)
    assert np.array_equal(copy, SQUARE) and copy is not SQUARE
    with pytest.raises(ValueError):
        inflate_polygon(SQUARE, -1.0)
    with pytest.raises(ValueError):
        inflate_polygon(SQUARE, 1.0, segments=2)


def brute_force_enclosing_radius(points):
    """Return the smallest circle through 2 or 3 of the points that contains them all."""
    candidates = [(0.5 * (a + b), 0.5 * np.hypot(*(a - b)))
                  for a, b in itertools.combinations(points, 2)]
    for a, b, c in itertools.combinations(points, 3):
        det = 2 * cross(b - a, c - a)
        if abs(det) > 1e-12:
            matrix = np.array([b - a, c - a])
            offset = np.linalg.solve(matrix, 0.5 * np.sum(matrix ** 2, axis=1))
            candidates.append((a + offset, np.hypot(*offset)))
    return min(r for centre, r in candidates
               if np.all(np.hypot(*(points - centre).T) <= r * (1 + 1e-9) + 1e-9))


@SETTINGS
@given(st.lists(st.tuples(float_coords, float_coords), min_size=1, max_size=10))
def test_minimum_enclosing_circle_is_enclosing_and_minimal(points):
    """The circle contains all points and is no larger than any 2- or 3-point circle that does."""
    points = np.array(points)
    centre, radius = minimum_enclosing_circle(points)
    assert np.all(np.hypot(*(points - centre).T) <= radius + 1e-9)
    if len(np.unique(points, axis=0)) > 1:
        assert radius <= brute_force_enclosing_radius(points) + 1e-9
    else:
        assert radius == 0


@SETTINGS
@given(float_convex_polygons())
def test_thin_axis_gives_the_minimum_width(polygon):
    """No sampled direction gives a smaller width than the thin axis."""
    axis = thin_axis(polygon)
    assert np.hypot(*axis) == pytest.approx(1.0)
    angles = np.linspace(0, np.pi, 721)
    along = polygon @ np.array([np.cos(angles), np.sin(angles)])
    width = np.ptp(polygon @ axis)
    assert width <= np.min(np.ptp(along, axis=0)) + 1e-9
    assert thin_axis([[0, 0], [4, 0], [4, 1], [0, 1]]) @ [0, 1] == pytest.approx(-1.0)


@SETTINGS
@given(float_convex_polygons(), st.floats(-5, 5), st.floats(0, 5), st.floats(0, 2 * np.pi),
       st.data())
def test_vertical_shadow_is_a_conservative_projection(footprint, z_min, height, angle, data):
    """Points of the prism project into the shadow, whose s-range is tight."""
    axis = np.array([math.cos(angle), math.sin(angle)])
    shadow = vertical_shadow(footprint, z_min, z_min + height, axis)
    assert shadow.shape == (4, 2) and signed_area(shadow) >= 0
    assert shadow[:, 0].min() == pytest.approx((footprint @ axis).min())
    assert shadow[:, 0].max() == pytest.approx((footprint @ axis).max())
    weights = seeded_rng(data).dirichlet(np.ones(len(footprint)), size=10)
    for point in weights @ footprint:
        s = point @ axis
        assert shadow[0, 0] - 1e-9 <= s <= shadow[1, 0] + 1e-9
        for z in np.linspace(z_min, z_min + height, 3):
            assert point_in_polygon((np.clip(s, shadow[0, 0], shadow[1, 0]), z), shadow)


def test_vertical_shadow_rejects_bad_arguments():
    """A zero axis and an inverted z range raise."""
    with pytest.raises(ValueError):
        vertical_shadow(SQUARE, 0.0, 1.0, (0.0, 0.0))
    with pytest.raises(ValueError):
        vertical_shadow(SQUARE, 1.0, 0.0, (1.0, 0.0))
