"""The horizon-aware barrier: eq. 7 at tau = inf, the time-to-contact reading, the exact cone."""
import math

import numpy as np
import pytest
from hypothesis import assume, given, settings, strategies as st

from oracles import inflate_polygon, min_h_along_by_rows
from polyc2bf_ros.core.barrier.cones import InflatedCone
from polyc2bf_ros.core.barrier.horizon_cone import HorizonCone
from polyc2bf_ros.core.geometry.polygons import PolygonBatch, signed_distance
from polyc2bf_ros.core.models import make_model, MODEL_NAMES
from polyc2bf_ros.core.obstacles.obstacle_set import Obstacle, ObstacleSet
from polyc2bf_ros.core.safety_filter import FilterConfig, SafetyFilter
from strategies import convex_polygons, examples, long_path, random_state

viewpoints = st.tuples(st.floats(-8, 8), st.floats(-8, 8)).map(np.array)


def _filter(model_name, **config):
    return SafetyFilter(make_model(model_name), FilterConfig(robot_radius=0.25, **config))


@pytest.mark.parametrize('model_name', MODEL_NAMES)
@settings(max_examples=examples(40), deadline=None)
@given(polygon=convex_polygons(centre_range=5.0), seed=st.integers(0, 2 ** 32 - 1),
       moving=st.booleans())
def test_infinite_horizon_is_the_papers_barrier_bit_for_bit(model_name, polygon, seed, moving):
    """At tau = inf, midpoint axis: viewpoints, cones, h, Lf h, Lg h equal polyc2bf_inflated's."""
    rng = np.random.default_rng(seed)
    velocity = rng.uniform(-1.0, 1.0, 3) if moving else np.zeros(3)
    obstacles = ObstacleSet.from_obstacles([Obstacle(polygon=polygon, velocity=velocity,
                                                     z_min=-1.0, z_max=1.5)])
    x = random_state(model_name, rng)
    paper = _filter(model_name, barrier='polyc2bf_inflated').evaluate(x, obstacles)
    horizon = _filter(model_name, barrier='polyc2bf_horizon', horizon=math.inf,
                      cone_axis='midpoint').evaluate(x, obstacles)
    assert np.array_equal(paper.block, horizon.block)
    assert np.array_equal(paper.valid, horizon.valid)


@pytest.mark.parametrize('axis', ['midpoint', 'bisector'])
@settings(max_examples=examples(200), deadline=None)
@given(polygon=convex_polygons(), viewpoint=viewpoints, closing=st.floats(0.01, 3.0),
       horizon=st.floats(0.1, 10.0))
def test_head_on_closing_is_allowed_exactly_when_contact_is_beyond_the_horizon(
        axis, polygon, viewpoint, closing, horizon):
    """V = -c p_hat: h_tau >= 0 iff d / c >= tau (the ORCA truncation of the cone)."""
    radius = 0.2
    distance = signed_distance(viewpoint, polygon) - radius
    assume(distance > 0.05)
    # The distance is to the inflated polygon the model uses, whose segments circumscribe
    # the disc: recompute it on that polygon.
    inflated = inflate_polygon(polygon, radius, 16)
    distance = signed_distance(viewpoint, inflated)
    assume(abs(distance / closing - horizon) > 1e-6 * horizon)
    obstacles = ObstacleSet.from_obstacles([Obstacle(polygon=polygon)])
    filt = SafetyFilter(make_model('point_mass_2d'), FilterConfig(
        barrier='polyc2bf_horizon', robot_radius=radius, horizon=horizon, cone_axis=axis,
        velocity_epsilon=1e-9))
    axis_vector = filt.evaluate(np.r_[viewpoint, 0.0, 0.0], obstacles).cones.p[:, 0]
    towards = axis_vector / np.linalg.norm(axis_vector)
    evaluation = filt.evaluate(np.r_[viewpoint, closing * towards], obstacles)
    assume(evaluation.valid[0])
    h = evaluation.terms.h[0]
    assert (h >= 0) == (distance / closing >= horizon), (h, distance / closing, horizon)


@settings(max_examples=examples(300), deadline=None)
@given(polygon=convex_polygons(), viewpoint=viewpoints, radius=st.floats(0.01, 0.5))
def test_bisector_cone_is_the_exact_silhouette(polygon, viewpoint, radius):
    """Both rays of the bisector cone touch the inflated polygon, and it lies inside."""
    assume(signed_distance(viewpoint, polygon) > radius + 1e-3)
    model = HorizonCone(radius, axis='bisector')
    prepared = model.prepare(PolygonBatch.from_polygons([polygon]))
    cones = model.cones(prepared, viewpoint)
    assert cones.valid[0]
    vertices = np.column_stack([prepared.x[0, :prepared.counts[0]],
                                prepared.y[0, :prepared.counts[0]]]) - viewpoint
    p = cones.p[:, 0]
    cos_half = cones.s[0] / np.linalg.norm(p)
    cosines = vertices @ p / (np.linalg.norm(vertices, axis=1) * np.linalg.norm(p))
    assert np.all(cosines >= cos_half - 1e-9)
    # Tight: the extreme vertices on either side of the axis sit on the boundary rays.
    side = p[0] * vertices[:, 1] - p[1] * vertices[:, 0]  # the 2-D cross product p x v
    assert np.isclose(cosines[side >= 0].min(), cos_half, atol=1e-9)
    assert np.isclose(cosines[side <= 0].min(), cos_half, atol=1e-9)


@settings(max_examples=examples(200), deadline=None)
@given(polygon=convex_polygons(), viewpoint=viewpoints)
def test_bisector_cone_is_no_wider_than_the_papers(polygon, viewpoint):
    """The half-angle of the exact cone never exceeds the midpoint cone's."""
    assume(signed_distance(viewpoint, polygon) > 0.3)
    batch = PolygonBatch.from_polygons([polygon])
    bisector = HorizonCone(0.2, axis='bisector')
    paper = InflatedCone(0.2)
    exact = bisector.cones(bisector.prepare(batch), viewpoint)
    midpoint = paper.cones(paper.prepare(batch), viewpoint)
    assert exact.s[0] / np.linalg.norm(exact.p[:, 0]) >= (
        midpoint.s[0] / np.linalg.norm(midpoint.p[:, 0]) - 1e-12)


def test_bisector_barrier_is_continuous_where_the_papers_jumps():
    """Crossing an edge's line switches a silhouette vertex: eq. 7's h jumps, the exact one not.

    Robot beside a long wall, moving parallel to it; at x = 0 the viewpoint crosses the line
    of the wall's short near edge (radius 0: sharp corners; an inflated corner is a fan of
    short edges, whose switches move p by little).
    """
    wall = np.array([[0.0, 0.5], [6.0, 0.5], [6.0, 0.7], [0.0, 0.7]])
    obstacles = ObstacleSet.from_obstacles([Obstacle(polygon=wall)])
    jumps = {}
    for axis in ('midpoint', 'bisector'):
        filt = SafetyFilter(make_model('point_mass_2d'), FilterConfig(
            barrier='polyc2bf_horizon', robot_radius=0.0, horizon=1.0, cone_axis=axis))
        h = [filt.evaluate(np.array([x, 0.0, 0.8, 0.0]), obstacles).terms.h[0]
             for x in (-1e-7, 1e-7)]
        jumps[axis] = abs(h[1] - h[0])
    assert jumps['bisector'] < 1e-5
    assert jumps['midpoint'] > 1e-2


def test_far_obstacles_do_not_constrain_a_short_horizon():
    """A box 8 m straight ahead closes the way under eq. 7, not with tau = 1 s at 1 m/s."""
    box = np.array([[8.0, -0.5], [9.0, -0.5], [9.0, 0.5], [8.0, 0.5]])
    obstacles = ObstacleSet.from_obstacles([Obstacle(polygon=box)])
    state = np.array([0.0, 0.0, 1.0, 0.0])
    paper = _filter('point_mass_2d', barrier='polyc2bf_inflated').evaluate(state, obstacles)
    horizon = _filter('point_mass_2d', barrier='polyc2bf_horizon').evaluate(state, obstacles)
    assert paper.terms.h[0] < 0 < horizon.terms.h[0]


@pytest.mark.parametrize('field, value', [('horizon', 0.0), ('horizon', -1.0),
                                          ('horizon', math.nan), ('cone_axis', 'diagonal')])
def test_bad_horizon_settings_are_refused(field, value):
    """A horizon that is not positive or an unknown axis is refused, naming the field."""
    with pytest.raises(ValueError, match=field):
        FilterConfig(barrier='polyc2bf_horizon', **{field: value}).validate()


def _min_h_by_evaluation(filt, obstacles, start, path, age, period):
    """Return min h over the usable parts at ``start`` and each path row (``evaluate``)."""
    best = math.inf
    for k, point in enumerate([start, *path]):
        evaluation = filt.evaluate(point, obstacles, age + k * period)
        if evaluation.valid.any():
            best = min(best, float(evaluation.terms.h[evaluation.valid].min()))
    return best


@pytest.mark.parametrize('axis', ['midpoint', 'bisector'])
@settings(max_examples=examples(120), deadline=None)
@given(polygons=st.lists(convex_polygons(centre_range=2.5), min_size=1, max_size=3),
       seed=st.integers(0, 2 ** 32 - 1), horizon=st.sampled_from([0.3, 1.0, math.inf]))
def test_min_h_along_a_path_is_the_smallest_h_the_filter_evaluates(axis, polygons, seed,
                                                                     horizon):
    """The braking check's kernel against ``evaluate`` point by point.

    Where some h along the path is negative the kernel finds that minimum; pruned points
    have h >= 0, so it never reports a negative h the filter would not, and without
    pruning (midpoint axis) it is the minimum itself.
    """
    rng = np.random.default_rng(seed)
    velocities = rng.uniform(-0.5, 0.5, (len(polygons), 3)) * rng.integers(0, 2)
    velocities[:, 2] = 0.0
    obstacles = ObstacleSet.from_obstacles([Obstacle(polygon=p, velocity=v)
                                            for p, v in zip(polygons, velocities)])
    filt = SafetyFilter(make_model('point_mass_2d'), FilterConfig(
        robot_radius=0.2, horizon=horizon, cone_axis=axis))
    period, age = 0.01, float(rng.uniform(0.0, 0.1))
    start = np.r_[rng.uniform(-3.0, 3.0, 2), rng.uniform(-1.5, 1.5, 2)]
    rows = int(rng.integers(1, 30))
    path = start + np.cumsum(rng.uniform(-0.05, 0.05, (rows, 4)), axis=0)
    model = HorizonCone(0.2, horizon=horizon, axis=axis)
    prepared = model.prepare(PolygonBatch.from_polygons(polygons))
    kernel = model.min_h_along(prepared, np.ascontiguousarray(velocities[:, :2]),
                               np.zeros((len(polygons), 2)), age, start, path, period,
                               filt.config.velocity_epsilon)
    expected = _min_h_by_evaluation(filt, obstacles, start, path, age, period)
    assert kernel >= expected - 1e-9
    if expected < 0.0 or axis == 'midpoint':
        assert kernel == pytest.approx(expected, rel=1e-9, abs=1e-9)


@pytest.mark.parametrize('axis', ['midpoint', 'bisector'])
@settings(max_examples=examples(120), deadline=None)
@given(polygons=st.lists(convex_polygons(centre_range=1.5), min_size=1, max_size=3),
       seed=st.integers(0, 2 ** 32 - 1), horizon=st.sampled_from([0.3, 1.0, math.inf]))
def test_min_h_along_is_its_row_by_row_form_bit_for_bit(axis, polygons, seed, horizon):
    """Skipping groups of rows whose every row the point tests skip changes no bit.

    Against the tests taken at every row (``oracles.min_h_along_by_rows``): long braking
    paths and random walks near and through the parts, static and moving, with offsets
    and ages.
    """
    rng = np.random.default_rng(seed)
    path = long_path(rng, polygons[0][0])
    count = len(polygons)
    velocities = rng.uniform(-1.0, 1.0, (count, 2)) * (rng.random((count, 1)) < 0.5)
    offsets = rng.uniform(-0.5, 0.5, (count, 2)) * rng.integers(0, 2)
    start = np.r_[path[0, :2] - 0.01 * path[0, 2:], path[0, 2:]]
    age, period = float(rng.uniform(-0.05, 0.3)), float(rng.choice([0.001, 0.01, 0.05]))
    model = HorizonCone(0.2, horizon=horizon, axis=axis)
    prepared = model.prepare(PolygonBatch.from_polygons(polygons))
    kernel = model.min_h_along(prepared, velocities, offsets, age, start, path, period, 0.05)
    rows = min_h_along_by_rows(prepared.x, prepared.y, prepared.edge_x, prepared.edge_y,
                               prepared.inv_sq, prepared.counts, prepared.boxes,
                               1.0 / horizon, axis == 'bisector', velocities, offsets, age,
                               start, path, period, 0.05 * 0.05)
    assert kernel == rows


@settings(max_examples=examples(300), deadline=None)
@given(polygon=convex_polygons(centre_range=2.0), viewpoint=viewpoints,
       heading=st.floats(-math.pi, math.pi), speed=st.floats(0.0, 3.0),
       horizon=st.sampled_from([0.3, 1.0, math.inf]))
def test_a_point_heading_past_the_bounding_box_has_h_of_at_least_zero(
        polygon, viewpoint, heading, speed, horizon):
    """The bisector axis's h >= 0 wherever ``min_h_along`` skips the point as heading past.

    The robot's velocity relative to the part: its ray from the point misses the part's
    bounding box.  The path is the point alone; a skipped point gives +inf.
    """
    radius = 0.2
    velocity = speed * np.array([math.cos(heading), math.sin(heading)])
    obstacles = ObstacleSet.from_obstacles([Obstacle(polygon=polygon)])
    filt = SafetyFilter(make_model('point_mass_2d'), FilterConfig(
        robot_radius=radius, horizon=horizon, cone_axis='bisector'))
    evaluation = filt.evaluate(np.r_[viewpoint, velocity], obstacles)
    model = HorizonCone(radius, horizon=horizon, axis='bisector')
    kernel = model.min_h_along(model.prepare(PolygonBatch.from_polygons([polygon])),
                               np.zeros((1, 2)), np.zeros((1, 2)), 0.0,
                               np.r_[viewpoint, velocity], np.zeros((0, 4)), 0.01,
                               filt.config.velocity_epsilon)
    if evaluation.valid[0]:
        assert kernel >= evaluation.terms.h[0] - 1e-9
        if evaluation.terms.h[0] < 0.0:
            assert kernel == pytest.approx(evaluation.terms.h[0], rel=1e-9, abs=1e-9)
    if kernel == math.inf:
        assert not evaluation.valid[0] or evaluation.terms.h[0] >= -1e-12


def test_the_papers_cone_models_leave_the_barrier_test_out():
    """Only the horizon cone has a path minimum; the others answer inf (clearance alone)."""
    box = PolygonBatch.from_polygons([np.array([[1.0, -1.0], [2.0, -1.0], [2.0, 1.0],
                                                [1.0, 1.0]])])
    start, path = np.array([0.0, 0.0, 2.0, 0.0]), np.array([[0.02, 0.0, 2.0, 0.0]])
    for barrier in ('polyc2bf_paper', 'polyc2bf_inflated', 'c3bf', 'polyc2bf_horizon'):
        model = _filter('point_mass_2d', barrier=barrier).cone_model
        value = model.min_h_along(model.prepare(box), np.zeros((1, 2)), np.zeros((1, 2)),
                                  0.0, start, path, 0.01, 0.05)
        assert (value == math.inf) == (barrier != 'polyc2bf_horizon')
        if barrier == 'polyc2bf_horizon':
            assert value < 0.0  # 2 m/s straight at a box 0.55 m away: inside the horizon
