"""What the laser's tracker says of the dynamic suite's cylinders, against the truth.

Usage: python bench/bench_scan_tracks.py [--worlds ID ...] [--seconds 20]
    [--position 10 0] [--range 4] [--config config/diff_drive.yaml] [-p NAME:=VALUE ...]
    [--generator-seed 2022] [--out bench/results/scan_tracks.json]

The robot of each world of ``sim_bridge.dynamic_worlds`` (default: the first five of each
difficulty) stands at ``--position`` (the course's middle) while its cylinders circle for
``--seconds``; its lidar (``LidarSettings()``, as ``evaluate --suite dynamic
--obstacle-source scan``) scans the world and each scan goes through the node's obstacle
pipeline with the parameters of ``--config`` (``ScanView``, the same path as the suite's
scan runs): conversion, tracking, the velocities and their bounds.  No filter acts: what
is measured is perception alone, not the robot's behaviour.

On every scan, every cylinder whose centre lies within ``--range`` of the robot is a
sample.  It is *seen* when the centroid of a published obstacle lies within its radius +
``SEEN_MARGIN`` of its centre; then its velocity is the mean of those obstacles'
velocities and its bound the largest of their ``velocity_error``; the true velocity is
the central difference of the cylinder's centre (``ContactReferee.centres``) over 2 ms.
It is *crowded* when another cylinder's centre lies within two radii + ``CROWDED_GAP``
(less than that gap between their surfaces: the laser cannot tell them apart in one
cluster, and the generator lets cylinders pass through each other).  The table gives,
per difficulty and alone / crowded: samples, the share seen, the share published moving,
the velocity error (|published - true|) p50 / p90 and its share within 0.1 m/s, and the
shares with an unknown speed (untrusted, the bound at least ``scan_unknown_speed``) and
with only the hidden-object bound (``scan_hidden_speed``).

Records (``bench`` = ``scan_tracks``): ``difficulty``, ``crowded``, ``samples``, ``seen``,
``published``, ``error_p50_m_s``, ``error_p90_m_s``, ``within_0_1``, ``unknown_bound``,
``hidden_bound_only``, ``worlds``, ``seconds``, ``range_m``, ``position``, ``config``,
``params`` (the ``-p`` overrides), ``generator_seed``.
"""
import argparse
import dataclasses
import sys
import types

import numpy as np
from bench_io import require_installed_checkout, write_records

from polyc2bf_ros.filter_parameters import build_filter, load_parameters
from sim_bridge.dynamic_worlds import (
    ContactReferee,
    CYLINDER_RADIUS,
    DEFAULT_SEED,
    DIFFICULTIES,
    difficulty_of,
    dynamic_world,
    WORLDS_PER_DIFFICULTY,
)
from sim_bridge.launcher import scan_parameters
from sim_bridge.lidar import LidarSettings
from sim_bridge.obstacle_views import ScanView
from sim_bridge.world import SimWorld

SEEN_MARGIN = 0.25  # m beyond the cylinder's radius within which an obstacle's centroid counts
CROWDED_GAP = 0.3  # m between two cylinders' surfaces under which they are crowded
WITHIN = 0.1  # m/s: a published velocity this close to the truth is right
DIFFERENCE = 1e-3  # s: the central difference of the centres that gives the true velocity


def default_worlds(per_difficulty=5):
    """Return the first ``per_difficulty`` world ids of each difficulty."""
    return [index * WORLDS_PER_DIFFICULTY + k for index in range(len(DIFFICULTIES))
            for k in range(per_difficulty)]


def _pipeline_robot(parameters):
    """Return what ``ScanView`` reads of a filtered robot: its filter, intake and geometry."""
    settings = build_filter(parameters)
    return types.SimpleNamespace(filter=settings.command_filter, intake=settings.intake,
                                 geometry=settings.command_filter.safety_filter.geometry)


def _samples(snapshot, referee, time, position, reach):
    """Return [(crowded, seen, published, error, bound)] of one scan's cylinders in reach."""
    centres = referee.centres(time)
    velocities = (referee.centres(time + DIFFERENCE)
                  - referee.centres(time - DIFFERENCE)) / (2.0 * DIFFERENCE)
    obstacles = snapshot.obstacles
    footprints = obstacles.footprints
    counts = footprints.counts
    centroids = (np.array([footprints.vertices[i, :counts[i]].mean(axis=0)
                           for i in range(len(counts))]) if len(counts) else np.zeros((0, 2)))
    errors = (obstacles.velocity_errors if obstacles.velocity_errors is not None
              else np.zeros(len(counts)))
    result = []
    radius = CYLINDER_RADIUS
    for index, centre in enumerate(centres):
        if np.hypot(*(centre - position)) > reach:
            continue
        apart = np.hypot(*(centres - centre).T) - 2.0 * radius
        apart[index] = np.inf
        crowded = bool((apart < CROWDED_GAP).any())
        near = (np.hypot(*(centroids - centre).T) <= radius + SEEN_MARGIN
                if len(centroids) else np.zeros(0, dtype=bool))
        if not near.any():
            result.append((crowded, False, False, np.nan, 0.0))
            continue
        velocity = obstacles.velocities[near, :2].mean(axis=0)
        result.append((crowded, True, bool(velocity.any()),
                       float(np.hypot(*(velocity - velocities[index]))),
                       float(errors[near].max())))
    return result


def measure_world(world_id, seed, seconds, position, reach, parameters):
    """Return the samples of one world (``_samples`` over every scan of ``seconds``)."""
    scenario = dynamic_world(world_id, seed=seed).scenario(duration=seconds)
    robot = scenario.robots[0]
    start = np.array([*position, float(robot.start[-1])])
    scenario = dataclasses.replace(scenario, robots=(dataclasses.replace(robot, start=start),))
    referee = ContactReferee(scenario)
    world = SimWorld(scenario)
    samples = []
    try:
        view = ScanView(world, {robot.name: _pipeline_robot(parameters)}, LidarSettings())
        world.set_command(robot.name, np.zeros(2))  # held: the robot stands throughout
        steps = int(round(seconds / world.dt))
        for _ in range(steps):
            world.step()
            view.sense()
            if world.steps % view.lidars.steps:  # no scan taken at this step
                continue
            state = world.robot_state(robot.name)
            snapshot = view.snapshot(robot.name, state, state[2], world.time)
            samples += _samples(snapshot, referee, world.time, state[:2], reach)
    finally:
        world.close()
    return samples


def summarise(samples, unknown):
    """Return the record fields of a list of samples (module docstring).

    ``unknown``: ``scan_unknown_speed``; a bound at least that is an untrusted track's.
    """
    seen = [s for s in samples if s[1]]
    errors = np.array([s[3] for s in seen])

    def share(flags):
        return round(float(np.mean(flags)), 3) if len(flags) else None

    return {
        'samples': len(samples),
        'seen': share([s[1] for s in samples]),
        'published': share([s[2] for s in seen]),
        'error_p50_m_s': round(float(np.percentile(errors, 50)), 3) if len(errors) else None,
        'error_p90_m_s': round(float(np.percentile(errors, 90)), 3) if len(errors) else None,
        'within_0_1': share(errors <= WITHIN),
        'unknown_bound': share([s[4] >= unknown > 0.0 for s in seen]),
        'hidden_bound_only': share([s[4] > 0.0 and not s[4] >= unknown > 0.0 for s in seen]),
    }


def main(argv=None):
    """Measure, print the table, write the records."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--worlds', type=int, nargs='+', default=None)
    parser.add_argument('--seconds', type=float, default=20.0)
    parser.add_argument('--position', type=float, nargs=2, default=(10.0, 0.0))
    parser.add_argument('--range', type=float, default=4.0)
    parser.add_argument('--config', default='config/diff_drive.yaml')
    parser.add_argument('--generator-seed', type=int, default=DEFAULT_SEED)
    parser.add_argument('--param', '-p', action='append', default=[],
                        help='NAME:=VALUE over the config, as evaluate -p')
    parser.add_argument('--out', default='bench/results/scan_tracks.json')
    args = parser.parse_args(argv)
    require_installed_checkout()
    worlds = args.worlds or default_worlds()
    values = load_parameters([args.config], args.param, '')
    parameters = {**values, **scan_parameters(LidarSettings()), 'scan_tracking': True}
    unknown = float(build_filter(parameters).intake.scan_unknown_speed)
    grouped = {}
    for number, world_id in enumerate(worlds, 1):
        print(f'[{number}/{len(worlds)}] world {world_id}', file=sys.stderr, flush=True)
        difficulty = difficulty_of(world_id)
        for sample in measure_world(world_id, args.generator_seed, args.seconds,
                                    args.position, args.range, parameters):
            grouped.setdefault((difficulty, sample[0]), []).append(sample)
    records = []
    header = (f'{"difficulty":<10} {"crowded":<8} {"samples":>7} {"seen":>6} {"moving":>6} '
              f'{"err p50":>8} {"err p90":>8} {"<=0.1":>6} {"unknown":>8} {"hidden":>7}')
    print(header)
    for difficulty in DIFFICULTIES:
        for crowded in (False, True):
            samples = grouped.get((difficulty, crowded), [])
            record = {'bench': 'scan_tracks', 'difficulty': difficulty, 'crowded': crowded,
                      **summarise(samples, unknown), 'worlds': worlds,
                      'seconds': args.seconds, 'range_m': args.range,
                      'position': list(args.position), 'config': args.config,
                      'params': args.param, 'generator_seed': args.generator_seed}
            records.append(record)
            cells = [record[key] for key in ('seen', 'published', 'error_p50_m_s',
                                             'error_p90_m_s', 'within_0_1', 'unknown_bound',
                                             'hidden_bound_only')]
            print(f'{difficulty:<10} {"yes" if crowded else "no":<8} {record["samples"]:>7} '
                  + ' '.join(f'{"-" if c is None else c:>{w}}'
                             for c, w in zip(cells, (6, 6, 8, 8, 6, 8, 7))))
    write_records(records, args.out)


if __name__ == '__main__':
    main()
