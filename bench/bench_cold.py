"""Cold-cache benchmark: what the node's step costs right after an idle gap, in process.

At 1 kHz the node blocks for most of each millisecond between steps.  On this
2-vCPU VM that idle time evicts what the step uses from the CPU caches, so a
step right after the gap runs 2-3x slower than the same step back to back;
this is most of the gap between the node benchmark's p50 and its DDS floor
(``bench_node.py``, doc/safety_filter.md "Benchmark").  Measured here, each
right after a ``--gap`` sleep (cold) and once more at once (hot), subjects
taking turns so that all see the same phase of the VM:

- ``probe_lines``: a compiled walk over 512 cache lines (32 KB, one read each);
- ``probe_compute``: a compiled loop of 2000 floating-point steps, no memory;
- ``node_path``: ``SafetyFilterNode`` in this process (unicycle, 50 obstacles as
  in ``bench_node.py``, ``trigger: command``): ``_on_odom`` then ``_on_command``
  with serialized messages, the answer captured instead of published;
- ``node_shell``: the same with ``CommandFilter.filter`` replaced by its last
  answer (everything but the filter);
- ``filter_step``: ``SafetyFilter.step`` alone at the node's state, obstacles
  and nominal input;
- ``filter_kernels``: only the compiled kernels that step runs (reference
  kinematics, cones and barrier terms of the plane, rows + QP front end + active
  parts), called back to back on the step's own buffers: what a step would
  cost cold with no Python at all between the kernels.

If the probes differ only after the gap for memory, not for compute, the
slowdown is the caches, not the clock.  Results: a table on stdout and
``bench/results/cold.json``.

    .venv/bin/python bench/bench_cold.py [--gap 0.001] [--samples 2000]
"""
import argparse
import os
import sys
import time
from pathlib import Path

import numba
import numpy as np
import rclpy
from bench_io import require_installed_checkout, write_records
from bench_node import obstacle_markers
from geometry_msgs.msg import TwistStamped
from nav_msgs.msg import Odometry
from rclpy.parameter import Parameter
from rclpy.serialization import serialize_message

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / 'bench' / 'results' / 'cold.json'
LINE_DOUBLES = 8  # 64-byte cache lines


@numba.njit(cache=False)
def _walk(values, stride, count):
    total = 0.0
    for i in range(count):
        total += values[i * stride]
    return total


@numba.njit(cache=False)
def _compute(count):
    total = 0.0
    for i in range(count):
        total += (i * 0.5) % 3.0
    return total


def node_subjects():
    """Return ``{name: callable}`` for the node path and its shell, and a clean-up function."""
    from polyc2bf_ros.safety_filter_node import SafetyFilterNode
    rclpy.init()
    node = SafetyFilterNode(parameter_overrides=[
        Parameter('trigger', value='command'), Parameter('stamped', value=True),
        Parameter('rate', value=1000.0), Parameter('obstacles_timeout', value=0.0)])
    answers = []
    node._publish = answers.append  # the serialized answer, instead of DDS
    node._on_obstacles(serialize_message(obstacle_markers(50)))
    odom = Odometry()
    odom.header.frame_id = 'odom'
    odom.pose.pose.orientation.w = 1.0
    odom.twist.twist.linear.x = 0.5
    command = TwistStamped()
    command.twist.linear.x = 1.0
    odom_bytes, command_bytes = serialize_message(odom), serialize_message(command)
    command_filter = node._filter
    real_filter = command_filter.filter

    def path(filter_function):
        def run():
            command_filter.filter = filter_function
            node._on_odom(odom_bytes)
            node._on_command(command_bytes)
            answers.clear()
        return run

    node._on_odom(odom_bytes)  # the odometry frame: the worker builds the set in it
    node._intake.process()
    path(real_filter)()
    obstacles = node._take_obstacles().obstacles
    state = node._decision.state
    last = real_filter(state, 0.0, (1.0, 0.0), obstacles, 0.0)
    subjects = {'node_path': path(real_filter), 'node_shell': path(lambda *_: last),
                **filter_subjects(command_filter, state, obstacles)}

    def close():
        node.destroy_node()
        rclpy.try_shutdown()
    return subjects, node, close


def filter_subjects(command_filter, state, obstacles):
    """``{name: callable}``: the node's filter step, and its compiled kernels alone.

    The kernel calls mirror ``SafetyFilter.step``'s common path for a single-view
    (2-D) model (private names of ``core.safety_filter``: a bench may reach in).
    """
    from polyc2bf_ros.core.kernels.filter_rows import _rows_and_answer
    from polyc2bf_ros.core.safety_filter import PLANE_ROWS
    safety_filter, model = command_filter.safety_filter, command_filter.model
    state = np.asarray(state, dtype=np.float64)
    u_nom = np.ascontiguousarray(
        command_filter.interface.nominal_input(state, (1.0, 0.0)), dtype=np.float64)
    prepared = safety_filter._prepare(obstacles)
    (view,) = prepared.views
    reference = model.reference(state, safety_filter._reference)
    block, usable = safety_filter._plane(view, prepared, reference, 0.0)
    h, x = np.empty(prepared.count), np.empty(model.input_dim)
    active = np.empty(prepared.count, dtype=np.intp)

    def kernels():
        model.reference(state, safety_filter._reference)
        safety_filter.cone_model.fill_plane(
            view.prepared, view.projections, prepared.velocities, prepared.offsets, 0.0,
            reference, safety_filter._epsilon, block, usable, False)
        _rows_and_answer.unchecked(
            block[PLANE_ROWS:], usable, *safety_filter._row_settings, prepared.rows_a,
            prepared.rows_b, prepared.index, h, u_nom, safety_filter._weights,
            safety_filter.solver.shortcut, x, active)

    step_u, _ = safety_filter.step(state, obstacles, u_nom)
    kernels()
    if not np.array_equal(step_u, x):
        raise RuntimeError(f'the kernels alone answer {x}, the step {step_u}: '
                           'filter_kernels no longer mirrors SafetyFilter.step')
    return {'filter_step': lambda: safety_filter.step(state, obstacles, u_nom),
            'filter_kernels': kernels}


def measure(subjects, gap, samples):
    """Per subject, microseconds per call after ``gap`` s of sleep (cold) and right after that.

    Each sample sleeps, times one call (cold) and at once a second (hot: the same
    work back to back); subjects take turns, so both see the same phase of the VM.
    """
    times = {(name, cold): [] for name in subjects for cold in (False, True)}
    for _ in range(samples // 10):  # warm-up
        for run in subjects.values():
            run()
    for _ in range(samples):
        for name, run in subjects.items():
            time.sleep(gap)
            for cold in (True, False):
                start = time.perf_counter()
                run()
                times[name, cold].append(1e6 * (time.perf_counter() - start))
    return times


def main(argv=None):
    """Run the probes and the node path; print the table and write the JSON."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--gap', type=float, default=1e-3, help='idle time before a cold call')
    parser.add_argument('--samples', type=int, default=2000, help='per subject and state')
    parser.add_argument('--out', type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    require_installed_checkout()
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    os.environ.setdefault('ROS_DOMAIN_ID', str(95 + os.getpid() % 7))
    values = np.ones(512 * LINE_DOUBLES * 64)
    probes = {'probe_lines': lambda: _walk(values, LINE_DOUBLES, 512),
              'probe_compute': lambda: _compute(2000)}
    node_calls, node, close = node_subjects()
    try:
        times = measure({**probes, **node_calls}, args.gap, args.samples)
        status = node._last_info.status.value
    finally:
        close()
    load = os.getloadavg()[0]
    records = []
    print(f'{"subject":>14} {"hot p50 us":>11} {"cold p50 us":>12} {"cold p99 us":>12} '
          f'{"cold / hot":>10}')
    for name in [*probes, *node_calls]:
        hot, cold = np.array(times[name, False]), np.array(times[name, True])
        record = {'bench': 'cold', 'subject': name, 'gap_s': args.gap, 'samples': args.samples,
                  'hot_p50_us': round(float(np.median(hot)), 2),
                  'cold_p50_us': round(float(np.median(cold)), 2),
                  'cold_p99_us': round(float(np.percentile(cold, 99)), 2),
                  'filter_status': status if name.startswith('node') else None,
                  'cpus': os.cpu_count(), 'load_avg_1min': round(load, 2)}
        records.append(record)
        print(f'{name:>14} {record["hot_p50_us"]:11.1f} {record["cold_p50_us"]:12.1f} '
              f'{record["cold_p99_us"]:12.1f} '
              f'{record["cold_p50_us"] / record["hot_p50_us"]:10.2f}')
    print(f'load average at end: {load:.2f}')
    write_records(records, args.out)
    return 0


if __name__ == '__main__':
    sys.exit(main())
