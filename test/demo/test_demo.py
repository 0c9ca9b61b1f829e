"""``demo`` end to end: three kinds of processes over localhost DDS, bag, metrics, plot, summary.

One short lockstep ``long_wall`` run (module fixture) serves every test here.
The children inherit the per-worker ROS_DOMAIN_ID of test/conftest.py, which
the launcher honours.
"""
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from PIL import Image
from rosbags.highlevel import AnyReader

from sim_bridge.closed_loop import run_in_process
from sim_bridge.launcher import default_barrier

REPO = Path(__file__).resolve().parents[2]
ENV = {**os.environ, 'PYTHONPATH': os.pathsep.join(
    filter(None, [str(REPO), os.environ.get('PYTHONPATH')]))}
DURATION = 15.0  # s: short of the goal (16.8 s), and > 1 s of wall time even at 6x real time,
# so the filter's 1 Hz (wall) diagnostics land in the bag


def _demo(tmp_path, *args, timeout=300):
    # --out relative to the working directory, as `make demo` runs it (runs/<timestamp>).
    return subprocess.run([sys.executable, '-m', 'sim_bridge.demo', '--out', 'runs',
                           *args], cwd=tmp_path, env=ENV, capture_output=True, text=True,
                          timeout=timeout)


@pytest.fixture(scope='module')
def demo_run(tmp_path_factory):
    """Run ``demo --duration 15`` (the default filter) once; return (process, run directory)."""
    out = tmp_path_factory.mktemp('demo')
    result = _demo(out, '--duration', str(DURATION))
    runs = [p for p in (out / 'runs').iterdir() if p.is_dir()]
    assert result.returncode == 0 and len(runs) == 1, result.stdout + result.stderr
    return result, runs[0]


def _odometry(bag, topic='/a1/odom'):
    """Return {stamp ns: (x, y, v)} of the recorded odometry, read with rosbags."""
    with AnyReader([bag]) as reader:
        connections = [c for c in reader.connections if c.topic == topic]
        poses = {}
        for connection, _, raw in reader.messages(connections=connections):
            msg = reader.deserialize(raw, connection.msgtype)
            stamp = msg.header.stamp.sec * 10 ** 9 + msg.header.stamp.nanosec
            poses[stamp] = (msg.pose.pose.position.x, msg.pose.pose.position.y,
                            msg.twist.twist.linear.x)
    return poses


@pytest.mark.slow
def test_demo_writes_bag_metrics_plot_and_summary(demo_run):
    """Files exist and read back; the summary names goal, clearance, rate, latency, files."""
    result, run_dir = demo_run
    out = result.stdout
    for text in ('demo: long_wall', 'a1: goal NOT reached, no collision', 'commands/s',
                 'step latency p50', 'bag:', 'metrics:', 'plot:', str(run_dir)):
        assert text in out, out
    assert 'sim ' in result.stderr  # progress lines from /clock
    link = run_dir / 'run.mcap'
    assert link.is_symlink() and link.resolve() == (run_dir / 'run' / 'run_0.mcap').resolve()
    assert (run_dir / 'run' / 'metadata.yaml').is_file()
    metrics = json.loads((run_dir / 'metrics.json').read_text())
    assert metrics['completed'] and metrics['sim_time_s'] == DURATION
    assert metrics['lockstep_timeouts'] == {'a1': 0}
    robot = metrics['robots']['a1']
    assert robot['collision'] is False and robot['path_length_m'] > 5.0
    with Image.open(run_dir / 'trajectory.png') as image:
        assert image.format == 'PNG' and image.size[0] > 400 and image.size[1] > 400
    for name in ('bridge', 'a1_nominal', 'a1_filter'):
        assert (run_dir / f'{name}.log').is_file()
    with AnyReader([link]) as reader:  # the single MCAP file opens on its own
        topics = {c.topic for c in reader.connections}
    assert {'/a1/odom', '/a1/cmd_vel_in', '/a1/cmd_vel_out', '/diagnostics'} <= topics


@pytest.mark.slow
def test_in_process_runner_reproduces_the_dds_run(demo_run):
    """The in-process lockstep loop gives the DDS run's trajectory to rounding error.

    Same world, same nominal law, same CommandFilter decision, with the filter node
    answering each stamped command with the same-stamp odometry (match_stamps).
    """
    _, run_dir = demo_run
    poses = _odometry(run_dir / 'run')
    stamps = sorted(poses)
    trace = run_in_process('long_wall', default_barrier('quadruped'),
                           duration=DURATION).robots['a1']
    assert len(stamps) == len(trace.states) == round(DURATION * 120) + 1
    recorded = np.array([poses[s] for s in stamps])
    np.testing.assert_allclose(recorded, trace.states[:, [0, 1, 3]], rtol=0, atol=1e-9)
    assert recorded[-1, 2] > 0.5  # it drove


def test_unknown_scenario_is_a_clear_error(tmp_path):
    """An unknown scenario exits 2 naming it and the shipped ones; nothing is started."""
    result = _demo(tmp_path, '--scenario', 'no_such_world', timeout=60)
    assert result.returncode == 2
    assert "no scenario named 'no_such_world'" in result.stderr and 'long_wall' in result.stderr
    assert not any(tmp_path.iterdir())


@pytest.mark.slow
def test_scan_mode_over_dds_stops_before_a_wall_seen_only_by_lidar(tmp_path):
    """--obstacle-source scan: no marker reaches the filter, the scans and /tf_static do.

    Without obstacles the base would drive into the wall within the run; it stops short.
    """
    scenario = tmp_path / 'wall_ahead.yaml'
    scenario.write_text(yaml.safe_dump({
        'name': 'wall_ahead', 'duration': 6.0,
        'robots': [{'name': 'base', 'type': 'diff_drive', 'start': [0.0, 0.0, 0.0],
                    'goal': [5.0, 0.0]}],
        'obstacles': [{'polygon': [[2.5, -3.0], [2.8, -3.0], [2.8, 3.0], [2.5, 3.0]]}]}))
    result = _demo(tmp_path, '--scenario', str(scenario), '--filter', 'polyc2bf_horizon',
                   '--obstacle-source', 'scan', timeout=600)
    assert result.returncode == 0, result.stdout + result.stderr
    assert 'obstacles from scan' in result.stdout and 'no collision' in result.stdout
    run_dir, = [p for p in (tmp_path / 'runs').iterdir() if p.is_dir()]
    robot = json.loads((run_dir / 'metrics.json').read_text())['robots']['base']
    assert not robot['collision'] and robot['min_clearance_m'] is not None
    x = [x for x, _, _ in _odometry(run_dir / 'run', '/base/odom').values()]
    assert max(x) > 1.5
    with AnyReader([run_dir / 'run']) as reader:
        by_topic = {c.topic: c for c in reader.connections}
        assert by_topic['/base/scan'].msgcount >= 1
        markers = [len(reader.deserialize(raw, c.msgtype).markers) for c, _, raw in
                   reader.messages(connections=[by_topic['/base/obstacles']])]
        assert markers and not any(markers)
        (_, _, raw), = reader.messages(connections=[by_topic['/tf_static']])
        transform, = reader.deserialize(raw, by_topic['/tf_static'].msgtype).transforms
        assert (transform.header.frame_id, transform.child_frame_id) == ('base/base_link',
                                                                        'base/laser')
        scan = next(reader.messages(connections=[by_topic['/base/scan']]))
        message = reader.deserialize(scan[2], by_topic['/base/scan'].msgtype)
        assert message.header.frame_id == 'base/laser' and len(message.ranges) == 360
