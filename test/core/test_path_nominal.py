"""The path nominal: ``ReferencePath`` progress and points, ``UnicyclePathController``'s law."""
import math

import numpy as np
import pytest

from sim_bridge.nominal import ReferencePath, UnicyclePathController

U_TURN = [[0.0, 0.0], [5.0, 0.0], [5.0, 0.0], [5.0, 0.3], [0.0, 0.3]]


def _state(x, y, theta, v=0.0, omega=0.0):
    return np.array([x, y, theta, v, omega])


def test_path_arc_lengths_and_points():
    """Repeated waypoints go; points along the arc interpolate and clip at both ends."""
    path = ReferencePath(U_TURN)
    assert len(path.points) == 4 and path.length == pytest.approx(10.3)
    assert path.point_at(2.5) == pytest.approx((2.5, 0.0))
    assert path.point_at(5.15) == pytest.approx((5.0, 0.15))
    assert path.point_at(-1.0) == pytest.approx((0.0, 0.0))
    assert path.point_at(99.0) == pytest.approx((0.0, 0.3))
    assert ReferencePath([[1.0, 2.0]]).point_at(3.0) == pytest.approx((1.0, 2.0))
    with pytest.raises(ValueError, match='finite points'):
        ReferencePath([[0.0, 0.0], [np.nan, 1.0]])


def test_progress_only_grows_and_does_not_jump_to_a_leg_nearby():
    """Near the start, the return leg 0.3 m away is not taken: it is outside the window."""
    path = ReferencePath(U_TURN)
    assert path.advance((0.5, 0.29), window=1.0) == pytest.approx(0.5)
    assert path.advance((0.2, 0.0), window=1.0) == pytest.approx(0.5)  # never backwards
    assert path.advance((2.0, 0.1), window=1.0) == pytest.approx(1.5)  # at most the window
    for x in np.arange(1.5, 5.01, 0.5):
        path.advance((x, 0.05), window=1.0)
    assert path.advance((4.5, 0.3), window=1.0) == pytest.approx(5.8)  # round the turn


def test_straight_ahead_full_speed_and_no_turn():
    """On a straight path, facing along it: v_max, omega 0."""
    controller = UnicyclePathController()
    command = controller.velocity_command(_state(0.0, 0.0, 0.0), ReferencePath([[0, 0], [9, 0]]))
    assert command == pytest.approx([controller.max_speed, 0.0])


def test_speed_follows_the_arc_to_the_carrot():
    """Speed min(v_max, sqrt(a_lat / |kappa|), omega_max / |kappa|), omega = v kappa."""
    controller = UnicyclePathController()
    path = ReferencePath([[0.0, 0.0], [0.1, 0.1], [3.0, 0.1]])
    state = _state(0.0, 0.0, 0.0)
    v, omega = controller.velocity_command(state, path)
    carrot = path.point_at(controller.min_lookahead)
    kappa = 2.0 * carrot[1] / (carrot[0] ** 2 + carrot[1] ** 2)
    expected = min(controller.max_speed, math.sqrt(controller.max_lateral_accel / abs(kappa)),
                   controller.max_turn_rate / abs(kappa))
    assert v == pytest.approx(expected) and omega == pytest.approx(expected * kappa)


def test_turns_in_place_towards_a_path_behind_and_stops_at_its_end():
    """Carrot more than turn_in_place off the heading: v = 0, turn its way; then still."""
    controller = UnicyclePathController()
    path = ReferencePath([[0.0, 0.0], [-3.0, 0.5]])
    v, omega = controller.velocity_command(_state(0.0, 0.0, 0.0), path)
    assert v == 0.0 and omega == pytest.approx(controller.max_turn_rate)
    path.advance((-3.0, 0.5), window=10.0)
    assert controller.velocity_command(_state(-2.95, 0.5, 0.0), path) == pytest.approx([0, 0])
    acceleration = controller(_state(-2.95, 0.5, 0.0, 0.3, 0.0), path)
    assert acceleration == pytest.approx([-0.3 / controller.time_constant, 0.0])
