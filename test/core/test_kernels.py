"""Compiled hot-path kernels agree with plain numpy formulations of the same math.

The references below are the vectorised numpy versions the kernels replaced
(cones, barrier terms, QP rows, body-point kinematics) or direct transcriptions
of the module docstrings; inputs are random (hypothesis), including shared and
per-obstacle viewpoints, moving obstacles and both planes of 3-D models.
"""
import math

import numpy as np
import pytest
from hypothesis import given, HealthCheck, settings, strategies as st

from oracles import barrier_terms, ReferenceSolver
from polyc2bf_ros.core.barrier.cones import CircleCone, InflatedCone, PaperCone
from polyc2bf_ros.core.geometry.polygons import PolygonBatch, signed_distance_batch
from polyc2bf_ros.core.geometry.views import choose_planes, prepare_views
from polyc2bf_ros.core.kernels import qp as qpk
from polyc2bf_ros.core.kernels.filter_rows import _active_parts, _assemble_rows
from polyc2bf_ros.core.kernels.quadrotor import rotation_matrix
from polyc2bf_ros.core.models import crazyflie as cf, make_model, ReferenceKinematics
from polyc2bf_ros.core.obstacles.obstacle_set import Obstacle, ObstacleSet
from polyc2bf_ros.core.qp import solver as qp
from polyc2bf_ros.core.safety_filter import FilterConfig, SafetyFilter
from strategies import convex_polygons, examples, random_state

SETTINGS = settings(max_examples=examples(150), deadline=None,
                    suppress_health_check=[HealthCheck.too_slow])
CLOSE = {'rtol': 1e-12, 'atol': 1e-12}
polygon_lists = st.lists(convex_polygons(centre_range=5.0), min_size=1, max_size=6)


def reference_polygon_cones(batch, viewpoints, extension):
    """Return (p, k, s, ds_dp, valid) by the padded-batch numpy formulation (cones module)."""
    vertices = np.stack([batch.x, batch.y])  # (2, V, N)
    edge_x, edge_y, _ = batch.edge_table
    rel = vertices - viewpoints.reshape(2, 1, -1)
    facing = edge_x * rel[1] > edge_y * rel[0]
    incoming = facing[np.roll(np.arange(facing.shape[0]), 1)]
    ends = np.stack([(incoming > facing).argmax(axis=0), (facing > incoming).argmax(axis=0)])
    ab = rel[:, ends, np.arange(len(batch))]
    p = 0.5 * (ab[:, 0] + ab[:, 1])
    if extension:
        along = ab[:, 1] - ab[:, 0]
        along *= extension / np.maximum(np.linalg.norm(along, axis=0), 1e-12)
        ab[:, 0] -= along
        ab[:, 1] += along
    norms = np.maximum(np.sqrt(ab[0] ** 2 + ab[1] ** 2), 1e-12)
    cosines = (p[0] * ab[0] + p[1] * ab[1]) / norms
    first = cosines[0] < cosines[1]
    s = np.where(first, cosines[0], cosines[1])
    k_norm = np.where(first, norms[0], norms[1])
    k = np.where(first, ab[:, 0], ab[:, 1])
    k_hat = k / k_norm
    valid = facing.any(axis=0)
    if extension:
        offsets = -np.broadcast_to(viewpoints.reshape(2, -1), (2, len(batch))).T
        valid &= signed_distance_batch(np.zeros(2), batch.translated(offsets)) > extension
    return p, k, s, k_hat + (p - s * k_hat) / k_norm, valid


def reference_circle_cones(circles, viewpoints):
    """Return (p, k, s, ds_dp, valid) of C3BF cones by the numpy formulation."""
    p = circles.centres - viewpoints.reshape(2, -1)
    distance_sq = (p ** 2).sum(axis=0)
    clearance_sq = distance_sq - circles.radii ** 2
    s = np.sqrt(np.maximum(clearance_sq, 1e-12))
    cos_phi = s / np.sqrt(distance_sq)
    sin_phi = circles.radii / np.sqrt(distance_sq)
    k = cos_phi * np.stack([cos_phi * p[0] - sin_phi * p[1], sin_phi * p[0] + cos_phi * p[1]])
    return p, k, s, p / s, clearance_sq > 0.0


def _viewpoints(draw_shared, rng, count):
    """Return a shared (2,) viewpoint or per-obstacle (2, N) ones."""
    return rng.uniform(-6, 6, 2) if draw_shared else rng.uniform(-6, 6, (2, count))


@pytest.mark.parametrize('cone_model', [PaperCone(0.0), PaperCone(0.3), InflatedCone(0.3),
                                        InflatedCone(0.0)])
@SETTINGS
@given(polygons=polygon_lists, seed=st.integers(0, 2 ** 32 - 1), shared=st.booleans())
def test_polygon_cone_kernel_matches_numpy(cone_model, polygons, seed, shared):
    """Silhouette vertices, p, k, s, ds/dp and validity equal the padded-batch version."""
    prepared = cone_model.prepare(PolygonBatch.from_polygons(polygons))
    viewpoints = _viewpoints(shared, np.random.default_rng(seed), len(polygons))
    cones = cone_model.cones(prepared, viewpoints)
    p, k, s, ds_dp, valid = reference_polygon_cones(prepared.batch, viewpoints,
                                                    cone_model.extension)
    np.testing.assert_array_equal(cones.valid, valid)
    for got, want in ((cones.p, p), (cones.k, k), (cones.s, s), (cones.ds_dp, ds_dp)):
        np.testing.assert_allclose(got, want, **CLOSE)


@SETTINGS
@given(polygons=polygon_lists, seed=st.integers(0, 2 ** 32 - 1), shared=st.booleans())
def test_circle_cone_kernel_matches_numpy(polygons, seed, shared):
    """C3BF cones equal the numpy formulation where they exist."""
    cone_model = CircleCone(0.2)
    prepared = cone_model.prepare(PolygonBatch.from_polygons(polygons))
    viewpoints = _viewpoints(shared, np.random.default_rng(seed), len(polygons))
    cones = cone_model.cones(prepared, viewpoints)
    p, k, s, ds_dp, valid = reference_circle_cones(prepared, viewpoints)
    np.testing.assert_array_equal(cones.valid, valid)
    for got, want in ((cones.p, p), (cones.k, k), (cones.s, s), (cones.ds_dp, ds_dp)):
        np.testing.assert_allclose(got[..., valid], want[..., valid], **CLOSE)


def reference_barrier(cones, projections, velocities, ref, eps):
    """Return (h, Lf h, Lg h) by the vectorised formulas of the barrier module."""
    v = np.einsum('nid,nd->in', projections, velocities - ref.velocity)
    a = -np.einsum('nid,d->in', projections, ref.drift)
    b = -np.einsum('nid,dj->nij', projections, ref.input_matrix)
    speed = np.sqrt((v ** 2).sum(axis=0) + eps ** 2)
    h = (cones.p * v).sum(axis=0) + speed * cones.s
    dh_dp = v + speed * cones.ds_dp
    dh_dv = cones.p + cones.s / speed * v
    lf_h = (dh_dp * v).sum(axis=0) + (dh_dv * a).sum(axis=0)
    return h, lf_h, np.einsum('in,nij->jn', dh_dv, b)


@pytest.mark.parametrize('dim, inputs', [(2, 2), (3, 3), (3, 4)])
@SETTINGS
@given(polygons=polygon_lists, seed=st.integers(0, 2 ** 32 - 1))
def test_barrier_kernel_matches_numpy(dim, inputs, polygons, seed):
    """h, Lf h, Lg h for random cones, projections and reference kinematics."""
    rng = np.random.default_rng(seed)
    count = len(polygons)
    cone_model = InflatedCone(0.2)
    cones = cone_model.cones(cone_model.prepare(PolygonBatch.from_polygons(polygons)),
                             rng.uniform(-6, 6, (2, count)))
    projections = rng.normal(size=(count, 2, dim))
    velocities = rng.normal(size=(count, dim))
    ref = ReferenceKinematics(*(rng.normal(size=dim) for _ in range(3)),
                              input_matrix=rng.normal(size=(dim, inputs)))
    terms = barrier_terms(cones, projections, velocities, ref, 0.05)
    h, lf_h, lg_h = reference_barrier(cones, projections, velocities, ref, 0.05)
    np.testing.assert_allclose(terms.h, h, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(terms.lf_h, lf_h, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(terms.lg_h, lg_h, rtol=1e-10, atol=1e-10)


@pytest.mark.parametrize('cone_model', [PaperCone(0.3), InflatedCone(0.3), CircleCone(0.3)])
@pytest.mark.parametrize('dim, inputs', [(2, 2), (3, 4)])
@SETTINGS
@given(polygons=polygon_lists, seed=st.integers(0, 2 ** 32 - 1))
def test_fused_plane_matches_viewpoints_cones_and_barrier(cone_model, dim, inputs, polygons,
                                                          seed):
    """``ConeModel.plane`` (one pass) equals viewpoints, then ``cones``, then ``barrier_terms``."""
    rng = np.random.default_rng(seed)
    count = len(polygons)
    obstacles = ObstacleSet.from_obstacles([
        Obstacle(polygon=p, velocity=rng.uniform(-1, 1, 3), z_min=0.0, z_max=2.0)
        for p in polygons])
    velocities = np.ascontiguousarray(obstacles.velocities[:, :dim])
    offsets = rng.uniform(-1, 1, (count, dim))
    ref = ReferenceKinematics(*(rng.normal(size=dim) for _ in range(3)),
                              input_matrix=rng.normal(size=(dim, inputs)))
    age = rng.uniform(0.0, 0.5)
    for view in prepare_views(obstacles, cone_model, dim, 0.3):
        block, valid = cone_model.plane(view.prepared, view, velocities, offsets, age, ref, 0.05)
        viewpoints = view.viewpoints(ref.position, velocities, offsets, age)
        cones = cone_model.cones(view.prepared, viewpoints)
        terms = barrier_terms(cones, view.projections, velocities, ref, 0.05)
        np.testing.assert_array_equal(valid, cones.valid)
        want = np.vstack((viewpoints, cones.p, cones.k, cones.s, cones.ds_dp, terms.h,
                          terms.lf_h, terms.lg_h))
        np.testing.assert_allclose(block, want, **CLOSE)


def reference_rows(h, lf_h, lg_h, usable, margin, gamma, lower, upper, prune):
    """Return (A, b, index, h with NaN) by the numpy formulation of the filter's rows."""
    b = margin - lf_h - gamma * h
    needed = usable.copy()
    if prune:
        worst = np.minimum(lg_h * lower[:, None], lg_h * upper[:, None]).sum(axis=0)
        needed &= worst < b
    index = np.flatnonzero(needed)
    scale = 1.0 / np.maximum(np.linalg.norm(lg_h[:, index], axis=0), 1e-12)
    return ((lg_h[:, index] * scale).T, b[index] * scale, index,
            np.where(usable, h, np.nan))


@SETTINGS
@given(seed=st.integers(0, 2 ** 32 - 1), count=st.integers(0, 30), inputs=st.integers(2, 4),
       prune=st.booleans())
def test_row_assembly_matches_numpy(seed, count, inputs, prune):
    """Pruned, unit-norm rows, their obstacle indices and h (NaN where unusable)."""
    rng = np.random.default_rng(seed)
    h, lf_h = rng.normal(size=count), rng.normal(size=count)
    lg_h = rng.normal(size=(inputs, count)) * rng.uniform(0.0, 3.0, count)
    lg_h[:, rng.random(count) < 0.1] = 0.0  # zero rows: kept, unless pruned
    usable = rng.random(count) < 0.9
    upper = rng.uniform(0.1, 2.0, inputs)
    lower = -rng.uniform(0.1, 2.0, inputs)
    rows_a, rows_b = np.empty((count, inputs)), np.empty(count)
    index, h_out = np.empty(count, dtype=np.intp), np.empty(count)
    kept, inside, min_h = _assemble_rows(np.vstack((h, lf_h, lg_h)), usable, 0.01, 1.5, lower,
                                         upper, prune, rows_a, rows_b, index, h_out)
    A, b, want_index, want_h = reference_rows(h, lf_h, lg_h, usable, 0.01, 1.5, lower, upper,
                                              prune)
    assert kept == want_index.size and inside == (~usable).sum()
    np.testing.assert_array_equal(index[:kept], want_index)
    np.testing.assert_allclose(rows_a[:kept], A, **CLOSE)
    np.testing.assert_allclose(rows_b[:kept], b, rtol=1e-12)
    np.testing.assert_array_equal(h_out, want_h)
    assert min_h == (np.nanmin(want_h) if usable.any() else math.inf)


def test_pruning_keeps_rows_with_unbounded_inputs():
    """An input without bounds can make any row active: such a row is never pruned."""
    lg_h = np.array([[0.0, 1.0], [1.0, 0.0]])  # row 0 uses input 1 only, row 1 input 0 only
    rows_a, rows_b, index, h = np.empty((2, 2)), np.empty(2), np.empty(2, dtype=np.intp), \
        np.empty(2)
    lower, upper = np.array([-np.inf, -1.0]), np.array([np.inf, 1.0])
    terms = np.vstack((np.full(2, 5.0), np.zeros(2), lg_h))
    kept, _, _ = _assemble_rows(terms, np.ones(2, dtype=bool), 0.0, 1.0, lower, upper, True,
                             rows_a, rows_b, index, h)
    # Row 0: worst = -1 >= b = -5: pruned.  Row 1: worst = -inf < -5: kept.
    assert kept == 1 and index[0] == 1


@settings(max_examples=examples(100), deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), m=st.integers(0, 12), n=st.integers(1, 5))
def test_row_residuals_match_numpy(seed, m, n):
    """A x - b and its minimum; NaN anywhere makes the minimum NaN."""
    rng = np.random.default_rng(seed)
    A, x, b = rng.normal(size=(m, n)), rng.normal(size=n), rng.normal(size=m)
    out = np.empty(m)
    smallest = qpk.row_residuals(A, x, b, out)
    np.testing.assert_allclose(out, A @ x - b, **CLOSE)
    assert smallest == (out.min() if m else np.inf)
    if m:
        b[rng.integers(m)] = np.nan
        assert np.isnan(qpk.row_residuals(A, x, b, out))


@settings(max_examples=examples(100), deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), m=st.integers(0, 12), n=st.integers(1, 5))
def test_active_parts_match_numpy(seed, m, n):
    """The obstacle indices of the rows with A x - b <= tolerance, in row order."""
    rng = np.random.default_rng(seed)
    A, x = rng.normal(size=(m, n)), rng.normal(size=n)
    b = A @ x - rng.choice([0.0, 1e-9, 1.0], size=m)  # some rows exactly or nearly active
    index = rng.permutation(3 * m)[:m].astype(np.intp)
    out = np.empty(m, dtype=np.intp)
    count = _active_parts(A, x, b, index, 1e-7, out)
    np.testing.assert_array_equal(out[:count], index[(A @ x - b) <= 1e-7])


def reference_body_point(model, x):
    """Return (r, r_dot, drift, B) of the quadrotor's body point by numpy (module docstring)."""
    roll, pitch, yaw = x[6:9]
    rot = (np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]])
           @ np.array([[np.cos(pitch), 0, np.sin(pitch)], [0, 1, 0],
                       [-np.sin(pitch), 0, np.cos(pitch)]])
           @ np.array([[1, 0, 0], [0, np.cos(roll), -np.sin(roll)],
                       [0, np.sin(roll), np.cos(roll)]]))
    w, b = x[9:12], np.array([0.0, 0.0, model.offset_l])
    b_skew = np.array([[0.0, -b[2], b[1]], [b[2], 0.0, -b[0]], [-b[1], b[0], 0.0]])
    torque_map = np.linalg.inv(model.inertia) @ cf.MIXER[1:]
    gyro = np.cross(w, model.inertia @ w)
    drift = np.array([0.0, 0.0, -cf.GRAVITY]) + rot @ (
        np.cross(w, np.cross(w, b)) + b_skew @ np.linalg.solve(model.inertia, gyro))
    B = np.outer(rot[:, 2], np.ones(4)) / model.mass - rot @ b_skew @ torque_map
    return x[0:3] + rot @ b, x[3:6] + rot @ np.cross(w, b), drift, B


@settings(max_examples=examples(100), deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1))
def test_quadrotor_body_point_kernel_matches_numpy(seed):
    """Body-point kinematics of the compiled kernel equal the numpy formulas."""
    model = make_model('quadrotor')
    x = random_state('quadrotor', np.random.default_rng(seed))
    ref = model.reference(x)
    for got, want in zip((ref.position, ref.velocity, ref.drift, ref.input_matrix),
                         reference_body_point(model, x)):
        np.testing.assert_allclose(got, want, rtol=1e-10, atol=1e-9)
    np.testing.assert_allclose(rotation_matrix(*x[6:9]) @ rotation_matrix(*x[6:9]).T,
                               np.eye(3), atol=1e-12)


@pytest.mark.parametrize('model_name', ['unicycle', 'point_mass_2d', 'point_mass_3d',
                                        'quadrotor'])
def test_reference_into_a_reused_buffer_matches_a_fresh_one(model_name):
    """``reference(x, out)`` (the filter's per-step buffer) gives what ``reference(x)`` does."""
    model = make_model(model_name)
    out = ReferenceKinematics.empty(model.position_dim, model.input_dim)
    rng = np.random.default_rng(7)
    for _ in range(3):  # refilled, not stale
        x = random_state(model_name, rng)
        fresh, reused = model.reference(x), model.reference(x, out)
        for name in ('position', 'velocity', 'drift', 'input_matrix'):
            np.testing.assert_array_equal(getattr(reused, name), getattr(fresh, name))


@settings(max_examples=examples(100), deadline=None)
@given(polygons=polygon_lists, seed=st.integers(0, 2 ** 32 - 1))
def test_plane_choice_follows_the_rule(polygons, seed):
    """3-D views: viewpoints P_n (r - age c_dot - o_n) and the plane chosen per obstacle.

    Vertical is chosen iff its cone is usable, it is a candidate (the robot within the
    footprint's long extent grown by the margin, or no horizontal cone), and its ||k||
    is smaller; an obstacle is usable when either plane's cone is.
    """
    rng = np.random.default_rng(seed)
    count = len(polygons)
    obstacles = ObstacleSet.from_obstacles([
        Obstacle(polygon=p, velocity=rng.uniform(-1, 1, 3), z_min=rng.uniform(-1, 0.5),
                 z_max=rng.uniform(0.6, 2.0)) for p in polygons])
    cone_model = InflatedCone(0.2)
    horizontal, vertical = prepare_views(obstacles, cone_model, 3, 0.2)
    position, age = rng.uniform(-3, 3, 3), rng.uniform(-1, 1)
    velocities = np.ascontiguousarray(obstacles.velocities)
    offsets = rng.uniform(-1, 1, (count, 3)) * rng.integers(0, 2)  # moved, or not
    seen_from = position - age * velocities - offsets
    cones = []
    for view in (horizontal, vertical):
        viewpoints = view.viewpoints(position, velocities, offsets, age)
        np.testing.assert_allclose(
            viewpoints, np.einsum('nid,nd->in', view.projections, seen_from), **CLOSE)
        cones.append(cone_model.cones(view.prepared, viewpoints))
    take, usable = choose_planes(cones[0].valid, cones[0].k, cones[1].valid, cones[1].k,
                                 vertical, position, velocities, offsets, age)
    along = (vertical.long_axes * seen_from[:, :2]).sum(axis=1)
    in_band = (vertical.band[:, 0] <= along) & (along <= vertical.band[:, 1])
    candidate = cones[1].valid & vertical.enabled & (in_band | ~cones[0].valid)
    rank_h = np.where(cones[0].valid, cones[0].k_norm, np.inf)
    rank_v = np.where(candidate, cones[1].k_norm, np.inf)
    np.testing.assert_array_equal(take, rank_v < rank_h)
    np.testing.assert_array_equal(usable, cones[0].valid | candidate)
    assert take.shape == usable.shape == (count,)


def test_far_prism_below_the_robot_is_seen_in_the_horizontal_plane():
    """A low wall 10 m away along its long axis does not block descending.

    Its vertical-plane shadow is endless along the long axis, so from here it looks 0.1 m
    below the inflated robot, with a smaller ||k|| than in the horizontal plane; it is
    seen in the horizontal plane, 10 m away.  Beside the wall the vertical plane is used.
    """
    wall = ObstacleSet.from_obstacles([Obstacle(
        polygon=np.array([[-0.2, 4.0], [0.2, 4.0], [0.2, 12.0], [-0.2, 12.0]]),
        z_min=0.0, z_max=0.6)])
    model = make_model('point_mass_3d')
    filt = SafetyFilter(model, FilterConfig(robot_radius=0.3))
    state = np.array([0.0, -6.0, 1.0, 0.0, 0.0, 0.0])
    k_norms = [filt.cone_model.cones(view.prepared, view.viewpoints(
        state[:3], np.zeros((1, 3)), np.zeros((1, 3)), 0.0)).k_norm[0]
        for view in filt._prepare(wall).views]
    assert k_norms[1] < 1.0 < 10.0 < k_norms[0]
    assert filt.evaluate(state, wall).plane[0] == 0
    state[:3] = [0.6, 8.0, 0.95]
    assert filt.evaluate(state, wall).plane[0] == 1


def test_hovering_among_many_low_prisms_is_feasible():
    """At rest among 200 random prisms (the core benchmark's scene) the first step is ok.

    Before the vertical plane was limited to the footprint's long extent, every step of
    this scene needed the slack fallback.
    """
    rng = np.random.default_rng(3)
    angles = np.linspace(0, 2 * np.pi, 8, endpoint=False)
    obstacles = []
    for _ in range(200):
        distance, bearing, radius = rng.uniform(2, 20), rng.uniform(-np.pi, np.pi), \
            rng.uniform(0.2, 0.6)
        centre = distance * np.array([np.cos(bearing), np.sin(bearing)])
        obstacles.append(Obstacle(
            polygon=centre + radius * np.column_stack([np.cos(angles), np.sin(angles)]),
            z_min=0.0, z_max=rng.uniform(0.5, 3.0)))
    model = make_model('quadrotor')
    filt = SafetyFilter(model, FilterConfig(robot_radius=0.3))
    state = np.zeros(12)
    state[2] = 1.0
    _, info = filt.step(state, ObstacleSet.from_obstacles(obstacles),
                        np.full(4, cf.HOVER_ROTOR_THRUST))
    assert info.status.value == 'ok'
    assert info.num_obstacles == 200


@settings(max_examples=examples(300), deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), n=st.integers(2, 4), m=st.integers(1, 6),
       outside=st.booleans())
def test_single_active_shortcut_is_the_optimum_when_it_answers(seed, n, m, outside):
    """Box-only or one-row candidates: when the shortcut accepts one, it is the optimum.

    Problems are feasible at a random point; x_ref is pushed across one row (or out of
    the box), so the shortcut answers often, and is checked against exhaustive search.
    """
    rng = np.random.default_rng(seed)
    weights = rng.uniform(0.2, 5.0, n)
    feasible = rng.uniform(-1, 1, n)
    A = rng.normal(size=(m, n))
    b = A @ feasible - rng.uniform(0.0, 1.0, m)
    lower, upper = feasible - rng.uniform(0.5, 2, n), feasible + rng.uniform(0.5, 2, n)
    x_ref = feasible + rng.normal(size=n) * (2.0 if outside else 0.7)
    x = np.empty(n)
    if qpk._single_active(x_ref, weights, A, b, lower, upper, x):
        expected = ReferenceSolver().solve(x_ref, weights, A, b, lower, upper)
        assert expected.status is qp.QPStatus.OPTIMAL
        np.testing.assert_allclose(x, expected.x, rtol=0.0, atol=1e-9)


def test_single_active_shortcut_tries_every_pair_of_violated_rows():
    """x_ref far outside the box: the farthest-violation rule picks the wrong pair.

    Rows x <= 0.5 y and x <= -0.5 y meet at the optimum (0, 0); 10 x <= 10 is the row
    violated farthest at x_ref = (50, 0) but inactive there.  Only the enumeration of
    the pairs violated at clip(x_ref) finds the optimum without the backend.
    """
    A = np.array([[-1.0, 0.5], [-1.0, -0.5], [-10.0, 0.0]])
    b = np.array([0.0, 0.0, -10.0])
    lower, upper, weights = np.array([-2.0, -4.0]), np.array([2.0, 4.0]), np.ones(2)
    x_ref, x = np.array([50.0, 0.0]), np.empty(2)
    assert not qpk._two_row_candidate(x_ref, weights, A, b, lower, upper, x)
    assert qpk._single_active(x_ref, weights, A, b, lower, upper, x)
    expected = ReferenceSolver().solve(x_ref, weights, A, b, lower, upper)
    np.testing.assert_allclose(x, expected.x, rtol=0.0, atol=1e-12)
    np.testing.assert_allclose(x, [0.0, 0.0], atol=1e-12)


def test_single_active_shortcut_answers_one_or_two_rows_and_refuses_three():
    """One or two violated rows: their projection.  Three rows active: no answer."""
    lower, upper, weights = np.full(3, -5.0), np.full(3, 5.0), np.ones(3)
    x = np.empty(3)
    rows = -np.eye(3), -np.ones(3)  # x <= 1
    assert qpk._single_active(np.array([2.0, 0.5, 0.0]), weights, *rows, lower, upper, x)
    np.testing.assert_allclose(x, [1.0, 0.5, 0.0])
    assert qpk._single_active(np.array([2.0, 3.0, 0.0]), weights, *rows, lower, upper, x)
    np.testing.assert_allclose(x, [1.0, 1.0, 0.0])
    assert not qpk._single_active(np.array([2.0, 2.0, 2.0]), weights, *rows, lower, upper, x)
    assert not qpk._single_active(np.array([np.nan, 0.0, 0.0]), weights, *rows, lower, upper,
                                  x)
