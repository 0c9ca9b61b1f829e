"""Laser scan to obstacles: ``scan_to_obstacles`` latency on 1081-beam scans of a few scenes.

Usage: python bench/bench_scan.py [--repeats 2000] [--out bench/results/scan.json]

A scan like a Hokuyo UTM-30LX's (1081 beams over 270 degrees, 0.25 degree steps, ranges
0.05-30 m, Gaussian range noise of 0.01 m) is ray-cast here from a sensor 0.2 m ahead of the
base in each scene: an empty 8 m x 6 m room, a 2 m wide corridor longer than the range, a
10 m x 10 m room with 20 random circles and boxes, and a scan with no return at all (every
range NaN).  Each scan is converted ``--repeats`` times (settings: the defaults with a
0.3 m footprint); the table gives the median, p99 and max of one call in milliseconds and
the obstacles it returns.  Target: median <= 1 ms per scan.

Records (``bench`` = ``scan``): ``scene``, ``beams``, ``valid_beams``, ``obstacles``,
``repeats``, ``p50_ms``, ``p99_ms``, ``max_ms``, ``load_avg_1min``.
"""
import argparse
import math
import os
import sys
import time

import numpy as np
from bench_io import require_installed_checkout, write_records

from polyc2bf_ros.core.obstacles.scan_conversion import scan_to_obstacles, ScanSettings

BEAMS = 1081
ANGLE_MIN = math.radians(-135.0)
ANGLE_INCREMENT = math.radians(0.25)
RANGE_MIN, RANGE_MAX = 0.05, 30.0
RANGE_NOISE = 0.01
SENSOR_POSE = (0.2, 0.0, 0.0)
SETTINGS = ScanSettings(footprint_radius=0.3)
TARGET_MS = 1.0


def _box(centre, half_x, half_y, yaw=0.0):
    """Return the four wall segments of a rectangle."""
    corners = np.array([[-half_x, -half_y], [half_x, -half_y], [half_x, half_y],
                        [-half_x, half_y]])
    rotation = np.array([[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]])
    corners = corners @ rotation.T + centre
    return [(corners[k], corners[(k + 1) % 4]) for k in range(4)]


def cast(origin, headings, segments=(), circles=()):
    """Return the range from ``origin`` along each heading to the first segment or circle hit."""
    dx, dy = np.cos(headings), np.sin(headings)
    ranges = np.full(len(headings), np.inf)
    with np.errstate(divide='ignore', invalid='ignore'):
        for a, b in segments:
            ex, ey = b[0] - a[0], b[1] - a[1]
            wx, wy = a[0] - origin[0], a[1] - origin[1]
            denominator = dx * ey - dy * ex
            r = (wx * ey - wy * ex) / denominator
            s = (wx * dy - wy * dx) / denominator
            ranges = np.where((r > 0) & (s >= 0) & (s <= 1), np.minimum(ranges, r), ranges)
        for (cx, cy), radius in circles:
            along = (cx - origin[0]) * dx + (cy - origin[1]) * dy
            miss_sq = (cx - origin[0]) ** 2 + (cy - origin[1]) ** 2 - along ** 2
            r = along - np.sqrt(radius ** 2 - miss_sq)
            ranges = np.where((miss_sq <= radius ** 2) & (r > 0), np.minimum(ranges, r), ranges)
    return ranges


def _clutter(rng, count=20):
    """Return segments and circles of a 10 m room with ``count`` circles and boxes in it."""
    segments, circles = _box(np.zeros(2), 5.0, 5.0), []
    while len(circles) + (len(segments) - 4) // 4 < count:
        centre = rng.uniform(-4.3, 4.3, 2)
        if np.linalg.norm(centre) < 1.2:
            continue  # keep the robot's surroundings free
        if rng.random() < 0.5:
            circles.append((centre, rng.uniform(0.1, 0.4)))
        else:
            segments += _box(centre, *rng.uniform(0.1, 0.4, 2), rng.uniform(0.0, math.pi))
    return segments, circles


def scenes(rng):
    """Return {scene: (robot pose, segments, circles)}; None segments: no return at all."""
    return {
        'room': ((1.0, -0.5, 0.3), _box(np.zeros(2), 4.0, 3.0), ()),
        'corridor': ((0.0, 0.0, 0.05), [((-60.0, -1.0), (60.0, -1.0)),
                                        ((-60.0, 1.0), (60.0, 1.0))], ()),
        'clutter': ((0.0, 0.0, 0.7), *_clutter(rng)),
        'all_nan': ((0.0, 0.0, 0.0), None, ()),
    }


def scan_of(robot_pose, segments, circles, rng):
    """Return the 1081 noisy ranges the sensor on a robot at ``robot_pose`` measures."""
    if segments is None:
        return np.full(BEAMS, np.nan)
    x, y, yaw = robot_pose
    origin = (x + math.cos(yaw) * SENSOR_POSE[0], y + math.sin(yaw) * SENSOR_POSE[0])
    headings = yaw + SENSOR_POSE[2] + ANGLE_MIN + ANGLE_INCREMENT * np.arange(BEAMS)
    ranges = cast(origin, headings, segments, circles)
    return ranges + rng.normal(0.0, RANGE_NOISE, BEAMS)


def time_scene(name, robot_pose, ranges, repeats):
    """Return one record: latency percentiles of ``scan_to_obstacles`` and its output size."""
    args = (ranges, ANGLE_MIN, ANGLE_INCREMENT, RANGE_MIN, RANGE_MAX, SENSOR_POSE, robot_pose,
            SETTINGS)
    obstacles = scan_to_obstacles(*args)  # warm: the bearing table is cached per layout
    samples = np.empty(repeats)
    for i in range(repeats):
        start = time.perf_counter()
        scan_to_obstacles(*args)
        samples[i] = time.perf_counter() - start
    ms = samples * 1e3
    valid = np.isfinite(ranges) & (ranges >= RANGE_MIN) & (ranges <= RANGE_MAX)
    return {'bench': 'scan', 'scene': name, 'beams': BEAMS, 'valid_beams': int(valid.sum()),
            'obstacles': len(obstacles), 'repeats': repeats,
            'p50_ms': round(float(np.percentile(ms, 50)), 3),
            'p99_ms': round(float(np.percentile(ms, 99)), 3),
            'max_ms': round(float(ms.max()), 3), 'load_avg_1min': round(os.getloadavg()[0], 2)}


def main(argv=None):
    """Time every scene, print the table and write the JSON records."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--repeats', type=int, default=2000)
    parser.add_argument('--out', default='bench/results/scan.json')
    args = parser.parse_args(argv)
    require_installed_checkout()
    rng = np.random.default_rng(7)
    records = []
    print(f'{"scene":<10} {"valid":>6} {"obstacles":>9} {"p50 ms":>8} {"p99 ms":>8} '
          f'{"max ms":>8}')
    for name, (robot_pose, segments, circles) in scenes(rng).items():
        record = time_scene(name, robot_pose, scan_of(robot_pose, segments, circles, rng),
                            args.repeats)
        records.append(record)
        print(f'{name:<10} {record["valid_beams"]:>6} {record["obstacles"]:>9} '
              f'{record["p50_ms"]:>8.3f} {record["p99_ms"]:>8.3f} {record["max_ms"]:>8.3f}',
              flush=True)
    worst = max(record['p50_ms'] for record in records)
    print(f'target median <= {TARGET_MS} ms per scan: {"met" if worst <= TARGET_MS else "NOT met"}'
          f' (worst scene median {worst:.3f} ms, load {os.getloadavg()[0]:.2f})')
    write_records(records, args.out)
    return 0


if __name__ == '__main__':
    sys.exit(main())
