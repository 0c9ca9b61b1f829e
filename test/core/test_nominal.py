"""Nominal controllers: the quadrotor's compiled law equals its numpy formulation."""
import math

import numpy as np
from hypothesis import given, settings, strategies as st

from polyc2bf_ros.core.kernels.quadrotor import rotation_matrix
from polyc2bf_ros.core.models import crazyflie as cf
from sim_bridge.nominal import QuadrotorGoalController
from strategies import examples


def numpy_wrench(controller, state, goal):
    """Return the wrench of ``QuadrotorGoalController``'s documented law, vectorised."""
    error = goal[:3] - state[:3]
    accel = controller.position_gain * error
    norm = np.linalg.norm(accel)
    if norm > controller.max_accel:
        accel = accel * (controller.max_accel / norm)
    accel = accel - controller.velocity_gain * state[3:6] + [0.0, 0.0, cf.GRAVITY]
    rot = rotation_matrix(*state[6:9])
    thrust = controller.mass * accel @ rot[:, 2]
    tilt = rot.T @ np.cross(rot[:, 2], accel / np.linalg.norm(accel))
    yaw_error = -((state[8] + math.pi) % (2 * math.pi) - math.pi)
    torque = cf.INERTIA @ (controller.attitude_gain * np.array([tilt[0], tilt[1], yaw_error])
                           - controller.rate_gain * state[9:12])
    return np.concatenate([[thrust], torque])


@settings(max_examples=examples(200), deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), far=st.booleans())
def test_quadrotor_wrench_matches_the_numpy_law(seed, far):
    """Near (unclipped) and far (clipped position term) goals, any attitude and rates."""
    rng = np.random.default_rng(seed)
    state = np.concatenate([rng.uniform(-2, 2, 3), rng.uniform(-2, 2, 3),
                            rng.uniform(-0.8, 0.8, 2), rng.uniform(-7, 7, 1),
                            rng.uniform(-3, 3, 3)])
    goal = state[:3] + rng.uniform(-1, 1, 3) * (10.0 if far else 0.5)
    controller = QuadrotorGoalController()
    np.testing.assert_allclose(controller.wrench(state, goal),
                               numpy_wrench(controller, state, goal), rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(controller(state, list(goal)),
                               cf.thrusts_from_wrench(numpy_wrench(controller, state, goal)),
                               rtol=1e-12, atol=1e-15)
