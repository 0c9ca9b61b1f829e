"""Hypothesis strategies shared by the core tests (not collected: no test_ prefix)."""
import numpy as np
from hypothesis import settings, strategies as st

from polyc2bf_ros.core.geometry.polygons import convex_hull
from polyc2bf_ros.core.models import make_model


def examples(count):
    """Return ``count`` scaled by the loaded hypothesis profile (test/conftest.py).

    ``count`` under ``fixed``, ``EXPLORE_FACTOR * count`` under ``explore``: an explicit
    ``max_examples`` overrides the profile, so a test's own budget must scale with it.
    """
    scale = settings.default.max_examples / settings.get_profile('fixed').max_examples
    return max(1, round(count * scale))


finite = st.floats(allow_nan=False, allow_infinity=False)

JACKAL = '[[0.254, 0.215], [-0.254, 0.215], [-0.254, -0.215], [0.254, -0.215]]'
"""The Clearpath Jackal's 0.508 x 0.430 m body about its centre, Nav2's footprint string."""


@st.composite
def convex_polygons(draw, centre_range=6.0, min_size=0.2, max_size=2.0):
    """Draw a convex polygon with 3..10 vertices, centred within +-centre_range."""
    seed = draw(st.integers(0, 2 ** 32 - 1))
    rng = np.random.default_rng(seed)
    count = draw(st.integers(3, 10))
    size = draw(st.floats(min_size, max_size))
    aspect = draw(st.floats(0.15, 1.0))
    angles = np.sort(rng.uniform(0.0, 2 * np.pi, count))
    radii = rng.uniform(0.6, 1.0, count)
    points = np.column_stack([size * radii * np.cos(angles),
                              aspect * size * radii * np.sin(angles)])
    turn = rng.uniform(0, 2 * np.pi)
    rot = np.array([[np.cos(turn), -np.sin(turn)], [np.sin(turn), np.cos(turn)]])
    centre = np.array([draw(st.floats(-centre_range, centre_range)),
                       draw(st.floats(-centre_range, centre_range))])
    hull = convex_hull(points @ rot.T + centre)
    return hull


def random_state(model_name, rng):
    """Return a random state for the named model, away from documented singularities."""
    if model_name == 'unicycle':
        return np.array([*rng.uniform(-1, 1, 2), rng.uniform(-np.pi, np.pi),
                         rng.uniform(-1.5, 1.5), rng.uniform(-2, 2)])
    if model_name == 'point_mass_2d':
        return np.concatenate([rng.uniform(-1, 1, 2), rng.uniform(-1.5, 1.5, 2)])
    if model_name == 'point_mass_3d':
        return np.concatenate([rng.uniform(-1, 1, 3), rng.uniform(-1.5, 1.5, 3)])
    return np.concatenate([rng.uniform(-1, 1, 3), rng.uniform(-1.5, 1.5, 3),
                           rng.uniform(-0.7, 0.7, 2), rng.uniform(-np.pi, np.pi, 1),
                           rng.uniform(-3, 3, 3)])


def long_path(rng, near):
    """Return a path of up to 400 rows [x, y, vx, vy], 0-30 mm apart, from within 1 m of ``near``.

    A unicycle's braking path from a random state at a random period down to 1 ms (the
    filter's own rows), or a random walk: started near a polygon's vertex, it passes
    near, along and through it, so that groups of rows straddle the part's box.
    """
    start = np.asarray(near) + rng.uniform(-1.0, 1.0, 2)
    if rng.random() < 0.5:
        state = np.array([*start, rng.uniform(-np.pi, np.pi), rng.uniform(-2.0, 2.0),
                          rng.uniform(-2.0, 2.0)])
        period = float(rng.choice([0.001, 0.002, 0.005, 0.01]))
        return make_model('unicycle').braking_path(state, period)[:400]
    rows = int(rng.integers(1, 400))
    steps = rng.normal(0.0, rng.uniform(0.0, 0.03), (rows, 4))
    return np.ascontiguousarray(np.r_[start, rng.uniform(-2.0, 2.0, 2)]
                                + np.cumsum(steps, axis=0))
