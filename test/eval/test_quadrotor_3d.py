"""The Crazyflie in PyBullet among 3-D obstacles: the body, not a point, and the floor, clear.

Lockstep, in process (``run_in_process``), the shipped quadrotor config (``ground_z`` 0,
``robot_radius`` around the centre of mass).  The simulator measures the body's collision
cylinder, and counts touching the floor as a collision (``SimWorld.min_clearance``).
"""
import dataclasses

import numpy as np
import pytest

from sim_bridge.closed_loop import run_in_process
from sim_bridge.evaluation.records import summarise
from sim_bridge.scenario import load_scenario


@pytest.mark.parametrize('rate', [None, 100.0])
@pytest.mark.parametrize('name', ['quadrotor_slab', 'quadrotor_floor_wall',
                                  'quadrotor_window'])
def test_no_collision_and_no_floor_contact(name, rate):
    """Slab across the way, wall on the floor, window: never touched, floor included.

    At the scenarios' rate (500 Hz) and at 100 Hz (physics at 1 kHz, so that it divides).
    """
    scenario = load_scenario(name)
    if rate is not None:
        scenario = dataclasses.replace(scenario, physics_rate=1000.0, control_rate=rate)
    run = run_in_process(scenario, 'polyc2bf_horizon')
    record = summarise(run, {'cf': 10.0})
    assert not record['collision']
    assert record['min_clearance_m'] is None or record['min_clearance_m'] > 0.0
    heights = run.robots['cf'].states[:, 2]
    assert heights.min() > 0.065  # the body's radius above the floor, at any tilt



@pytest.mark.parametrize('name', ['quadrotor_wall', 'quadrotor_floor_box'])
def test_hovering_at_an_obstacle_stays_in_the_safe_set(name):
    """Held at a wall for most of the run, h never goes below 0 at the config's 500 Hz.

    The sample-and-hold margin (``margin_gain`` 25 in ``crazyflie_thrust.yaml``) covers
    the attitude dynamics' hold error; with the generic 1.0, h reached -0.04 here.
    """
    run = run_in_process(name, 'polyc2bf_horizon')
    min_h = run.robots['cf'].min_h
    finite = min_h[np.isfinite(min_h)]
    assert finite.size > 0.9 * min_h.size
    assert finite.min() >= 0.0
    assert 'recovering' not in run.robots['cf'].statuses
