"""Moving obstacles in closed loop: a crossing pedestrian seen only by the laser.

The ``crossing_pedestrian`` scenario (a 0.5 m cylinder crossing the robot's path at
1.4 m/s, timed to meet it) in scan mode: the filter's obstacles come from the simulated
lidar through the node's own scan pipeline and tracker.  With tracking the robot gives way
and is never the one that closes on the pedestrian; with every scan obstacle standing
still (``scan_tracking: false``) the same run ends in a collision, so the test can fail.
"""
import numpy as np
import pytest

from sim_bridge.closed_loop import run_in_process
from sim_bridge.dynamic_worlds import AT_FAULT_SPEED
from sim_bridge.launcher import default_barrier
from sim_bridge.scenario import load_scenario

SCENARIO = load_scenario('crossing_pedestrian')
PEDESTRIAN = SCENARIO.obstacles[0]


def _closing_speeds_at_contact(run):
    """Return the robot's speed towards the pedestrian's centre at every touching period."""
    (trace,) = run.robots.values()
    centre0 = np.mean(PEDESTRIAN.polygon, axis=0)
    radius = PEDESTRIAN.radius + run.robot_radius
    speeds = []
    for k, t in enumerate(trace.times):
        position = trace.states[k + 1][:2]
        centre = centre0 + PEDESTRIAN.velocity * (t + run.period)
        offset = centre - position
        if np.linalg.norm(offset) <= radius:
            step = trace.states[k + 1][:2] - trace.states[k][:2]
            speeds.append(float(step @ offset / np.linalg.norm(offset) / run.period))
    return speeds


@pytest.mark.slow
def test_a_crossing_pedestrian_seen_by_the_laser_is_given_way():
    """Scan mode, tracked: no contact at all, and the goal is reached."""
    run = run_in_process(SCENARIO, default_barrier('quadruped'), obstacle_source='scan')
    (metrics,) = run.metrics.values()
    assert not metrics['collision'], metrics
    assert metrics['goal_reached'], metrics
    assert not [s for s in _closing_speeds_at_contact(run) if s > AT_FAULT_SPEED]


@pytest.mark.slow
def test_untracked_scans_let_the_pedestrian_walk_into_the_robot():
    """The same run with every scan obstacle standing still ends in a collision."""
    run = run_in_process(SCENARIO, default_barrier('quadruped'), obstacle_source='scan',
                         parameters={'scan_tracking': False})
    (metrics,) = run.metrics.values()
    assert metrics['collision'], metrics
