"""Footprints in Nav2's format: read, refused with one clear reason, guarded by their cover."""
import math

import numpy as np
import pytest
from hypothesis import given, strategies as st

from polyc2bf_ros.core.barrier.footprint_cone import FootprintCone
from polyc2bf_ros.core.geometry.footprint import (
    covering_radius,
    FootprintError,
    format_footprint,
    parse_footprint,
)
from polyc2bf_ros.core.geometry.polygons import signed_area
from polyc2bf_ros.core.models import make_model
from polyc2bf_ros.core.safety_filter import FilterConfig, SafetyFilter
from strategies import convex_polygons, JACKAL


def test_a_nav2_footprint_string_is_read_as_a_counter_clockwise_polygon():
    """Nav2's string in either winding, spaces or not, with a closing point or not."""
    points = parse_footprint(JACKAL)  # clockwise as written
    assert signed_area(points) == pytest.approx(0.508 * 0.430)
    assert covering_radius(points) == pytest.approx(math.hypot(0.254, 0.215))
    closed = parse_footprint('[[0.254,0.215],[0.254,-0.215],[-0.254,-0.215],[-0.254,0.215],'
                             '[0.254,0.215]]')
    assert len(closed) == 4 and signed_area(closed) == pytest.approx(signed_area(points))
    notch = parse_footprint('[[0.5, 0.3], [-0.5, 0.3], [-0.5, -0.3], [0.0, -0.1], '
                            '[0.5, -0.3]]')  # not convex: accepted
    assert len(notch) == 5
    assert parse_footprint('[]') is None and parse_footprint('') is None


@pytest.mark.parametrize('text, reason', [
    ('[[0.3, 0.2], [-0.3, 0.2]]', 'at least 3 distinct points'),
    ('[[0.3, 0.2], [-0.3, -0.2], [-0.3, 0.2], [0.3, -0.2]]', 'self-intersecting'),
    ('[[0.3, 0.2], [-0.3, .nan], [-0.3, -0.2]]', 'point 1 is .* finite number'),
    ('[[0.3, 0.2], [-0.3, nan], [-0.3, -0.2]]', 'point 1 is .* finite number'),
    ('[[0.3, 0.2], [-0.3, 0.2], [-0.3, -0.2', 'does not parse'),
    ('0.3', 'not a list of \\[x, y\\] pairs'),
    ('[[0.3, 0.2, 0.1], [-0.3, 0.2], [-0.3, -0.2]]', 'not a list of \\[x, y\\] pairs'),
    ('[[0, 0], [1, 0], [2, 0]]', 'collinear'),
])
def test_a_bad_footprint_is_refused_with_one_line_saying_why(text, reason):
    """Each kind of bad footprint gets its own reason, on one line, and names the footprint."""
    with pytest.raises(FootprintError, match=reason) as caught:
        parse_footprint(text)
    assert '\n' not in str(caught.value) and 'footprint' in str(caught.value)
    with pytest.raises(ValueError, match=reason):
        FilterConfig(footprint=text).validate()


@given(convex_polygons(centre_range=0.3, min_size=0.1, max_size=1.0),
       st.integers(0, 3))
def test_a_polygon_survives_its_own_string_and_its_cover_holds_every_vertex(polygon, start):
    """Format -> parse gives the same polygon (any starting vertex); the cover holds it."""
    points = np.roll(polygon, start, axis=0)
    again = parse_footprint(format_footprint(points))
    assert again.shape == points.shape
    assert np.allclose(np.roll(again, -int(np.argmin(np.hypot(*(again - points[0]).T))),
                               axis=0), points)
    radius = covering_radius(again)
    assert np.all(np.hypot(again[:, 0], again[:, 1]) <= radius + 1e-12)
    assert np.any(np.isclose(np.hypot(again[:, 0], again[:, 1]), radius))


def test_a_footprint_replaces_robot_radius_by_its_cover_or_turning_with_the_unicycle():
    """The covering disc by default; the polygon itself with the footprint barrier.

    Either way robot_radius no longer counts.
    """
    config = FilterConfig(robot_radius=0.1, footprint=JACKAL).validate()
    assert config.body_radius == pytest.approx(math.hypot(0.254, 0.215))
    assert FilterConfig(robot_radius=0.1).validate().body_radius == 0.1
    turning = SafetyFilter(make_model('unicycle'), FilterConfig(
        robot_radius=0.1, footprint=JACKAL, barrier=FootprintCone.name))
    assert isinstance(turning.cone_model, FootprintCone)
    assert turning.guard_radius == pytest.approx(config.body_radius)
    holonomic = make_model('point_mass_2d')
    covered = SafetyFilter(holonomic, config)
    assert not isinstance(covered.cone_model, FootprintCone)
    assert covered.guard_radius == pytest.approx(config.body_radius + holonomic.guard_offset)
