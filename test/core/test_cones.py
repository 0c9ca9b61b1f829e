"""Cone geometry: every obstacle point lies inside its cone; cones agree with the paper."""
import numpy as np
import pytest
from hypothesis import assume, given, settings, strategies as st

from oracles import inflate_polygon
from polyc2bf_ros.core.barrier.cones import CircleCone, InflatedCone, PaperCone, PlanarPolygons
from polyc2bf_ros.core.geometry.polygons import (
    minimum_enclosing_circle,
    PolygonBatch,
    signed_distance,
)
from polyc2bf_ros.core.kernels.cones import (
    hinted_seen_edge,
    hinted_silhouette,
    nearest_edge,
    nearest_seen_edge,
    silhouette,
)
from strategies import convex_polygons, examples

viewpoints = st.tuples(st.floats(-8, 8), st.floats(-8, 8)).map(np.array)


def _inside_cone(points, cones, tol=1e-9):
    """Return True when every point (relative to the apex) is within the cone's half-angle."""
    p, s = cones.p[:, 0], cones.s[0]
    p_norm = np.linalg.norm(p)
    cos_phi = s / p_norm
    cos_points = points @ p / (np.linalg.norm(points, axis=1) * p_norm)
    return bool(np.all(cos_points >= cos_phi - tol))


@settings(max_examples=examples(300), deadline=None)
@given(polygon=convex_polygons(), viewpoint=viewpoints, radius=st.floats(0.0, 0.5))
def test_polygon_and_extension_inside_paper_cone(polygon, viewpoint, radius):
    """Vertices and the segment extended by w/2 lie in the paper's cone."""
    assume(signed_distance(viewpoint, polygon) > radius + 1e-3)
    cone_model = PaperCone(radius)
    cones = cone_model.cones(cone_model.prepare(PolygonBatch.from_polygons([polygon])),
                             viewpoint)
    assert cones.valid[0]
    assert _inside_cone(polygon - viewpoint, cones)
    # The cone is symmetric about p with half-angle angle(p, k): k is on its boundary.
    k = cones.k[:, 0]
    assert np.isclose(cones.s[0], k @ cones.p[:, 0] / np.linalg.norm(k))


@settings(max_examples=examples(300), deadline=None)
@given(polygon=convex_polygons(), viewpoint=viewpoints, radius=st.floats(0.01, 0.5))
def test_inflated_obstacle_inside_inflated_cone(polygon, viewpoint, radius):
    """Every point within ``radius`` of the polygon lies in the inflated-silhouette cone."""
    inflated = inflate_polygon(polygon, radius, 16)
    assume(signed_distance(viewpoint, inflated) > 1e-3)
    cone_model = InflatedCone(radius, 16)
    cones = cone_model.cones(cone_model.prepare(PolygonBatch.from_polygons([polygon])),
                             viewpoint)
    assert cones.valid[0]
    angles = np.linspace(0, 2 * np.pi, 64, endpoint=False)
    disk = radius * np.column_stack([np.cos(angles), np.sin(angles)])
    offset_points = (polygon[:, None, :] + disk[None]).reshape(-1, 2)
    assert _inside_cone(offset_points - viewpoint, cones)


def _polygon_and_viewpoint(polygon, radius, viewpoint, near):
    """Return (prepared, vertex count, viewpoint): raw or inflated by ``radius``.

    ``near`` puts the viewpoint within 5 cm of a vertex (where ties between edges happen).
    """
    prepared = InflatedCone(radius, 16).prepare(PolygonBatch.from_polygons([polygon])) \
        if radius else PlanarPolygons.from_batch(PolygonBatch.from_polygons([polygon]))
    count = int(prepared.counts[0])
    if near:
        k = int(abs(viewpoint[0]) * 1000) % count
        vertex = np.array([prepared.x[0, k], prepared.y[0, k]])
        outward = vertex - np.array([prepared.x[0, :count].mean(), prepared.y[0, :count].mean()])
        viewpoint = vertex + 0.05 * (abs(viewpoint[1]) / 8.0) * outward / np.linalg.norm(outward)
    return prepared, count, viewpoint


@settings(max_examples=examples(500), deadline=None)
@given(polygon=convex_polygons(), viewpoint=viewpoints, radius=st.sampled_from([0.0, 0.2, 0.3]),
       near=st.booleans())
def test_the_seen_edges_give_the_nearest_edge_bit_for_bit(polygon, viewpoint, radius, near):
    """``nearest_seen_edge`` (the horizon barrier's distance) is ``nearest_edge``'s, exactly.

    Raw and inflated polygons, from anywhere outside; ``near`` puts the viewpoint within
    5 cm of the boundary, where the nearest point is most often a vertex (ties).
    """
    prepared, count, viewpoint = _polygon_and_viewpoint(polygon, radius, viewpoint, near)
    qx, qy = float(viewpoint[0]), float(viewpoint[1])
    a, b, seen = silhouette(prepared.x, prepared.y, count, 0, qx, qy)
    assume(seen)
    square, _, dx, dy, _ = nearest_edge(prepared.x, prepared.y, prepared.edge_x, prepared.edge_y,
                                        prepared.inv_sq, count, 0, qx, qy)
    assert nearest_seen_edge(prepared.x, prepared.y, prepared.edge_x, prepared.edge_y,
                             prepared.inv_sq, count, 0, qx, qy, a, b) == (square, dx, dy)


@settings(max_examples=examples(500), deadline=None)
@given(polygon=convex_polygons(), viewpoint=viewpoints, radius=st.sampled_from([0.0, 0.2, 0.3]),
       near=st.booleans(), hint=st.integers(-3, 40), step=st.floats(-0.05, 0.05))
def test_hinted_silhouettes_and_nearest_edges_are_the_scans_bit_for_bit(
        polygon, viewpoint, radius, near, hint, step):
    """``hinted_silhouette`` and ``hinted_seen_edge`` (the horizon step's) from any hints.

    ``silhouette``'s ends and ``nearest_edge``'s distance, exactly, twice: from ``hint``
    (out of range too), then from the hints the first call left, with the viewpoint moved
    by ``step`` on both axes, as between two control steps.
    """
    prepared, count, viewpoint = _polygon_and_viewpoint(polygon, radius, viewpoint, near)
    hints = np.array([[hint, hint + 1, hint - 2]], dtype=np.int64)
    for qx, qy in ((float(viewpoint[0]), float(viewpoint[1])),
                   (float(viewpoint[0]) + step, float(viewpoint[1]) + step)):
        a, b, seen = silhouette(prepared.x, prepared.y, count, 0, qx, qy)
        assert hinted_silhouette(prepared.x, prepared.y, count, 0, qx, qy, hints) \
            == (a, b, seen)
        assume(seen)
        square, _, dx, dy, _ = nearest_edge(prepared.x, prepared.y, prepared.edge_x,
                                            prepared.edge_y, prepared.inv_sq, count, 0, qx, qy)
        assert hinted_seen_edge(prepared.x, prepared.y, prepared.edge_x, prepared.edge_y,
                                prepared.inv_sq, count, 0, qx, qy, a, b, hints) \
            == (square, dx, dy)
        assert ((0 <= hints[0]) & (hints[0] < count)).all()


@settings(max_examples=examples(200), deadline=None)
@given(polygon=convex_polygons(), viewpoint=viewpoints, radius=st.floats(0.0, 0.5))
def test_c3bf_cone_is_tangent_to_circle(polygon, viewpoint, radius):
    """C3BF: cos(phi) = sqrt(|p|^2 - r^2)/|p| and the polygon lies inside the cone."""
    centre, circle_radius = minimum_enclosing_circle(polygon)
    big = circle_radius + radius
    assume(np.linalg.norm(centre - viewpoint) > big + 1e-3)
    cone_model = CircleCone(radius)
    cones = cone_model.cones(cone_model.prepare(PolygonBatch.from_polygons([polygon])),
                             viewpoint)
    p = centre - viewpoint
    assert np.isclose(cones.s[0], np.sqrt(p @ p - big ** 2))
    assert _inside_cone(polygon - viewpoint, cones)
    assert np.isclose(np.linalg.norm(cones.k[:, 0]), cones.s[0])


@pytest.mark.parametrize('cone_model', [PaperCone(0.3), InflatedCone(0.3), CircleCone(0.3)])
def test_inside_inflated_obstacle_is_flagged(cone_model):
    """A viewpoint inside the obstacle, or within the robot radius of it, has no valid cone."""
    square = np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])
    prepared = cone_model.prepare(PolygonBatch.from_polygons([square]))
    for viewpoint, valid in (((0.0, 0.0), False), ((1.2, 0.0), False), ((5.0, 0.0), True)):
        cones = cone_model.cones(prepared, np.array(viewpoint))
        assert cones.valid[0] == valid, viewpoint
