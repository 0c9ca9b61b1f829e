"""Translated obstacle sets: the filter reuses its base's geometry and answers as if fresh.

A filter fed ``ObstacleSet.translated`` sets reuses the views it prepared for the
base (inflated polygons, enclosing circles, vertical shadows) and sees each part
from a viewpoint moved back by the part's offset.  Its cones, barrier terms and
safe input must match a fresh filter's for the same polygons given without the
link to the base, to rounding.
"""
import numpy as np
import pytest
from hypothesis import given, HealthCheck, settings, strategies as st

from polyc2bf_ros.core.barrier.cone_models import CONE_MODELS, make_cone_model
from polyc2bf_ros.core.geometry.polygons import PolygonBatch
from polyc2bf_ros.core.models import make_model, MODEL_NAMES
from polyc2bf_ros.core.obstacles.obstacle_set import Obstacle, ObstacleSet
from polyc2bf_ros.core.safety_filter import FilterConfig, SafetyFilter
from strategies import convex_polygons, examples, random_state

SETTINGS = settings(max_examples=examples(25), deadline=None,
                    suppress_health_check=[HealthCheck.too_slow])
polygon_lists = st.lists(convex_polygons(centre_range=4.0), min_size=1, max_size=6)
# Rounding only: coordinates are O(10) m, so one ulp is ~2e-15.
TOLERANCE = {'rtol': 1e-9, 'atol': 1e-11}


def _base(polygons, rng):
    """Return a built set: random velocities, z ranges finite or open (no vertical view)."""
    obstacles = []
    for polygon in polygons:
        low = rng.uniform(-1.0, 1.0)
        high = low + rng.uniform(0.2, 2.0) if rng.random() < 0.7 else np.inf
        obstacles.append(Obstacle(polygon=polygon, velocity=rng.uniform(-0.5, 0.5, 3),
                                  z_min=low, z_max=high))
    return ObstacleSet.from_obstacles(obstacles)


def _unlinked(obstacles):
    """Return the same parts as a set with no base and no shared edge table."""
    batch = obstacles.footprints
    return ObstacleSet(footprints=PolygonBatch(batch.vertices.copy(), batch.counts.copy()),
                       velocities=obstacles.velocities.copy(),
                       z_ranges=obstacles.z_ranges.copy(), owner=obstacles.owner,
                       keys=obstacles.keys)


def _assert_same_evaluation(reused, fresh):
    """Cones, barrier terms, usability and planes agree to rounding."""
    np.testing.assert_array_equal(reused.usable, fresh.usable)
    np.testing.assert_array_equal(reused.cones.valid, fresh.cones.valid)
    if fresh.vertical is not None:
        np.testing.assert_array_equal(reused.vertical, fresh.vertical)
    for name in ('p', 'k', 's', 'ds_dp'):
        np.testing.assert_allclose(getattr(reused.cones, name), getattr(fresh.cones, name),
                                   **TOLERANCE, err_msg=name)
    for name in ('h', 'lf_h', 'lg_h'):
        np.testing.assert_allclose(getattr(reused.terms, name), getattr(fresh.terms, name),
                                   **TOLERANCE, err_msg=name)


@pytest.mark.parametrize('barrier', sorted(CONE_MODELS))
@pytest.mark.parametrize('model_name', MODEL_NAMES)
@SETTINGS
@given(polygons=polygon_lists, seed=st.integers(0, 2 ** 32 - 1))
def test_translated_sets_give_the_fresh_answer(model_name, barrier, polygons, seed):
    """Per step a new translation (some of a translation): same evaluation and safe input."""
    rng = np.random.default_rng(seed)
    model = make_model(model_name)
    config = FilterConfig(barrier=barrier)
    reused = SafetyFilter(model, config)
    base = _base(polygons, rng)
    moved = base
    for _ in range(3):
        offsets = rng.uniform(-3.0, 3.0, (len(base), 3))
        velocities = rng.uniform(-0.8, 0.8, (len(base), 3))
        origin = moved if rng.random() < 0.5 else base
        moved = origin.translated(offsets, velocities)
        assert moved.base is base
        state = random_state(model_name, rng)
        span = model.input_upper - model.input_lower
        u_nom = model.input_lower + rng.uniform(-0.5, 1.5, model.input_dim) * span
        age = rng.uniform(0.0, 0.2)
        fresh = SafetyFilter(model, config)
        unlinked = _unlinked(moved)
        _assert_same_evaluation(reused.evaluate(state, moved, age),
                                fresh.evaluate(state, unlinked, age))
        u_reused, info_reused = reused.step(state, moved, u_nom, age)
        u_fresh, info_fresh = fresh.step(state, unlinked, u_nom, age)
        assert info_reused.status == info_fresh.status
        np.testing.assert_allclose(info_reused.h, info_fresh.h, **TOLERANCE)
        np.testing.assert_allclose(u_reused, u_fresh, rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize('barrier', sorted(CONE_MODELS))
@SETTINGS
@given(polygons=polygon_lists, seed=st.integers(0, 2 ** 32 - 1))
def test_moved_polygons_seen_from_q_are_the_polygons_seen_from_q_minus_offset(barrier, polygons,
                                                                             seed):
    """The identity translated sets rely on: cones and exits of P + o from q = of P from q - o."""
    rng = np.random.default_rng(seed)
    cone_model = make_cone_model(barrier, rng.uniform(0.0, 0.5))
    batch = PolygonBatch.from_polygons(polygons)
    offsets = rng.uniform(-5.0, 5.0, (len(batch), 2))
    moved = cone_model.prepare(PolygonBatch(batch.vertices + offsets[:, None, :], batch.counts))
    base = cone_model.prepare(batch)
    viewpoints = rng.uniform(-8.0, 8.0, (2, len(batch)))
    shifted = np.ascontiguousarray(viewpoints - offsets.T)
    cones_moved, cones_base = cone_model.cones(moved, viewpoints), cone_model.cones(base, shifted)
    np.testing.assert_array_equal(cones_moved.valid, cones_base.valid)
    for name in ('p', 'k', 's', 'ds_dp'):
        np.testing.assert_allclose(getattr(cones_moved, name), getattr(cones_base, name),
                                   **TOLERANCE, err_msg=name)
    np.testing.assert_allclose(cone_model.exits(moved, viewpoints),
                               cone_model.exits(base, shifted), **TOLERANCE)


def test_translated_set_moves_vertices_and_z_and_keeps_the_rest():
    """Vertices and z ranges move, velocities are replaced, a chain adds up from the base."""
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    base = ObstacleSet.from_obstacles([
        Obstacle(polygon=square, z_min=0.0, z_max=2.0, key='a'),
        Obstacle(polygon=square + 3.0, key='b')])
    once = base.translated([[1.0, 2.0], [0.0, -1.0]])
    np.testing.assert_array_equal(once.footprints.vertices[0, :4], square + [1.0, 2.0])
    np.testing.assert_array_equal(once.z_ranges, base.z_ranges)
    np.testing.assert_array_equal(once.velocities, base.velocities)
    assert once.keys == ('a', 'b') and once.base is base
    twice = once.translated([[1.0, 0.0, 0.5], [0.0, 0.0, 0.0]], np.ones((2, 3)))
    assert twice.base is base
    np.testing.assert_array_equal(twice.offsets, [[2.0, 2.0, 0.5], [0.0, -1.0, 0.0]])
    np.testing.assert_array_equal(twice.footprints.vertices[0, :4], square + [2.0, 2.0])
    np.testing.assert_array_equal(twice.z_ranges[0], [0.5, 2.5])
    np.testing.assert_array_equal(twice.velocities, np.ones((2, 3)))
    assert base.base is None and base.offsets is None
    assert twice.accelerations is None
    speeding = twice.translated(np.zeros((2, 2)), accelerations=[[1.0, 0.0], [0.0, -2.0]])
    np.testing.assert_array_equal(speeding.accelerations, [[1.0, 0.0], [0.0, -2.0]])
    np.testing.assert_array_equal(speeding.translated(np.zeros((2, 2))).accelerations,
                                  speeding.accelerations)  # kept, as velocities are
    assert speeding.is_finite()
    assert not twice.translated(np.zeros((2, 2)), accelerations=[[np.nan, 0.0],
                                                                 [0.0, 0.0]]).is_finite()


def test_accelerations_follow_each_part_of_a_split_footprint():
    """``from_obstacles``: a non-convex obstacle's parts share its acceleration; none: None."""
    ell = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 1.0], [1.0, 1.0], [1.0, 2.0], [0.0, 2.0]])
    square = np.array([[5.0, 0.0], [6.0, 0.0], [6.0, 1.0], [5.0, 1.0]])
    obstacles = [Obstacle(polygon=ell, acceleration=np.array([0.5, -1.0])),
                 Obstacle(polygon=square)]
    split = ObstacleSet.from_obstacles(obstacles)
    assert len(split) == 3
    np.testing.assert_array_equal(split.accelerations,
                                  [[0.5, -1.0], [0.5, -1.0], [0.0, 0.0]])
    assert ObstacleSet.from_obstacles([Obstacle(polygon=square)]).accelerations is None


@pytest.mark.parametrize('offsets, velocities, message', [
    (np.zeros((1, 2)), None, 'offsets must have shape'),
    (np.zeros((2, 4)), None, 'offsets must have shape'),
    (np.zeros((2, 2)), np.zeros((2, 2)), 'velocities must have shape'),
    (np.zeros((2, 2)), np.zeros((2, 3)), 'accelerations must have shape'),
])
def test_translated_refuses_wrong_shapes(offsets, velocities, message):
    """Offsets (N, 2 or 3), velocities (N, 3), accelerations (N, 2), the shape named."""
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    base = ObstacleSet.from_obstacles([Obstacle(polygon=square), Obstacle(polygon=square + 2)])
    with pytest.raises(ValueError, match=message):
        base.translated(offsets, velocities, np.zeros((2, 3)))


def test_non_finite_offsets_brake_and_the_base_is_reused_after():
    """NaN offsets give invalid_input; the next finite translation still matches fresh."""
    square = np.array([[2.0, -0.5], [3.0, -0.5], [3.0, 0.5], [2.0, 0.5]])
    base = ObstacleSet.from_obstacles([Obstacle(polygon=square)])
    model = make_model('unicycle')
    filt = SafetyFilter(model, FilterConfig())
    state, u_nom = np.array([0.0, 0.0, 0.0, 1.0, 0.0]), np.array([1.0, 0.0])
    _, info = filt.step(state, base.translated([[np.nan, 0.0]]), u_nom)
    assert info.status.value == 'invalid_input'
    moved = base.translated([[-0.5, 0.1]])
    u, info = filt.step(state, moved, u_nom)
    u_fresh, info_fresh = SafetyFilter(model, FilterConfig()).step(state, _unlinked(moved),
                                                                   u_nom)
    assert info.status == info_fresh.status
    np.testing.assert_allclose(u, u_fresh, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(info.h, info_fresh.h, rtol=1e-12, atol=1e-12)
