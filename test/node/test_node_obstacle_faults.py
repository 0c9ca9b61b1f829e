"""Obstacle faults over real DDS: rejected input blocks, huge input stays bounded, start-up.

Each test runs ``safety_filter`` as its own process and drives it from a harness node.
"""
import subprocess
import sys

import numpy as np
import pytest

from node_harness import (
    Harness,
    latest_status,
    markers,
    node_log,
    odometry,
    REPO,
    running_filter,
    twist,
    wall,
)

RATE = 50.0
AHEAD = [(4.0, -1.0), (4.0, 1.0)]
BESIDE = [(0.0, 3.0), (5.0, 3.0)]  # parallel to the path: no cone in the way


def _drive(h, io, obstacles, seconds, predicate):
    """Publish odometry + nominal 0.8 m/s each period and ``obstacles`` at 5 Hz until true."""
    ticks = [0]

    def feed():
        io.odom.publish(odometry(v=0.5, stamp=h.now()))
        io.cmd.publish(twist(0.8))
        if ticks[0] % 10 == 0:
            io.obstacles.publish(obstacles)
        ticks[0] += 1

    return h.spin_until(predicate, seconds, feed, 1.0 / RATE)


@pytest.mark.slow
@pytest.mark.parametrize('block', [True, False])
def test_a_wall_in_the_wrong_frame_stops_the_robot_unless_block_if_invalid_is_off(block):
    """Wall in ``map``, odometry in ``odom``: rejected; blocking stops once it is stale.

    With every obstacle rejected the obstacle input is reported stale; with
    ``block_if_invalid`` off the robot drives on at the nominal speed, as before.
    """
    params = {'model': 'unicycle', 'rate': RATE, 'obstacles_timeout': 0.5,
              'block_if_invalid': block}
    with running_filter(params=params) as proc, Harness() as h:
        io = h.filter_io(proc)
        wrong = markers(wall(AHEAD, frame='map'))

        def reported():
            values = latest_status(io.diagnostics)[1]
            return values.get('obstacles_rejected') == '1' and len(io.out) > 20

        assert _drive(h, io, wrong, 15.0, reported), node_log(proc)
        count = len(io.out)
        assert _drive(h, io, wrong, 10.0, lambda: len(io.out) > count + 25)
        recent = [m.linear.x for _, m in io.out[-10:]]
        _, values = latest_status(io.diagnostics)
        if block:
            assert recent == [0.0] * 10, recent
            assert _drive(h, io, wrong, 5.0, lambda: 'obstacles' in latest_status(
                io.diagnostics)[1].get('stale_inputs', ''))
            status, values = latest_status(io.diagnostics)
            assert 'rejected' in status.message and int(values['steps_stale_stop']) > 0
        else:
            assert min(recent) > 0.5, recent
            assert values['stale_inputs'] == 'none'


@pytest.mark.slow
def test_block_if_invalid_with_a_latched_map_stops_at_once():
    """``obstacles_timeout`` 0 (never stale): a rejected marker stops the robot right away."""
    params = {'model': 'unicycle', 'rate': RATE, 'obstacles_timeout': 0.0}
    with running_filter(params=params) as proc, Harness() as h:
        io = h.filter_io(proc)
        good = markers(wall(BESIDE, marker_id=1))
        assert _drive(h, io, good, 15.0, lambda: len(io.out) > 10 and io.out[-1][1].linear.x > 0.5)
        mixed = markers(wall(BESIDE, marker_id=1), wall(AHEAD, marker_id=2, frame='map'))
        assert _drive(h, io, mixed, 10.0, lambda: int(latest_status(io.diagnostics)[1].get(
            'steps_blocked_stop', 0)) > 0), node_log(proc)
        count = len(io.out)
        assert _drive(h, io, mixed, 5.0, lambda: len(io.out) > count + 10)
        assert all(m.linear.x == 0.0 for _, m in io.out[-10:])


@pytest.mark.slow
def test_a_10000_point_polygon_is_simplified_and_the_node_keeps_answering():
    """One 10,000-point non-convex star: answers keep coming, one simplified obstacle in use."""
    angles = np.linspace(0.0, 2.0 * np.pi, 10_000, endpoint=False)
    radii = np.where(np.arange(10_000) % 2 == 0, 1.0, 0.7)
    star = markers(wall(list(zip(6.0 + radii * np.cos(angles), radii * np.sin(angles)))))
    with running_filter(params={'model': 'unicycle', 'rate': RATE}) as proc, Harness() as h:
        io = h.filter_io(proc)

        def simplified():
            values = latest_status(io.diagnostics)[1]
            # In use once odometry has given the frame (a loaded machine may report first).
            return (values.get('obstacles_simplified') == '1'
                    and values.get('obstacles_in_use') == '1' and len(io.out) > 50)

        assert _drive(h, io, star, 30.0, simplified), (latest_status(io.diagnostics),
                                                        node_log(proc))
        _, values = latest_status(io.diagnostics)
        assert values['obstacles_in_use'] == '1' and values['obstacles_rejected'] == '0'
        status, _ = latest_status(io.diagnostics)
        assert 'simplified' in status.message
        assert proc.poll() is None


FILTER = 'polyc2bf_ros.safety_filter_node'
BAD_STARTS = [
    (FILTER, 'rate:=0.0', 'rate out of range'),
    (FILTER, 'filter.robot_radius:=.nan', 'filter.robot_radius out of range'),
    (FILTER, 'rate:=fast', "expecting type 'DOUBLE'"),
    (FILTER, 'model:=bogus', "'model' must be one of"),
    (FILTER, 'trigger:=sometimes', "'trigger' must be 'timer' or 'command'"),
    (FILTER, 'stall_timeout:=0.011', 'stall_timeout'),
    (FILTER, 'max_vertices:=2', 'max_vertices out of range'),
    (FILTER, 'odom_timeout:=0.005', 'must exceed the control period'),
    (FILTER, 'use_markers:=false', 'no obstacle source'),
    ('sim_bridge.bridge_node', 'duration:=abc', "expecting type 'DOUBLE'"),
    ('sim_bridge.nominal_controller_node', 'robot_type:=tank', "'robot_type' must be one of"),
]


@pytest.mark.parametrize('module, argument, reason', BAD_STARTS)
def test_an_invalid_start_up_parameter_is_one_fatal_line_and_exit_1(module, argument, reason):
    """No traceback: one ``[FATAL]`` line naming the reason, exit status 1 (every node)."""
    result = subprocess.run(
        [sys.executable, '-m', module, '--ros-args', '-p', argument],
        cwd=REPO, capture_output=True, text=True, timeout=120)
    output = result.stdout + result.stderr
    assert result.returncode == 1, output
    assert 'Traceback' not in output, output
    fatal = [line for line in output.splitlines() if '[FATAL]' in line]
    assert len(fatal) == 1 and reason in fatal[0], output
