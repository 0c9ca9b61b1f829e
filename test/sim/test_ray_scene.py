"""The lidars' ray scene: every obstacle visible to rays, the world's physics untouched."""
import math

import numpy as np
import pybullet as pb
import pytest

from polyc2bf_ros.core.geometry.polygons import signed_distance
from sim_bridge.barn import load_worlds, WORLDS_FILE
from sim_bridge.lidar import LidarSettings, RobotLidars
from sim_bridge.metrics import RunMetrics
from sim_bridge.scenario import scenario_from_dict
from sim_bridge.scenario_specs import ScenarioError
from sim_bridge.world import SimWorld

DIRECTIONS = 8     # rays per obstacle, from all round
STANDOFF = 0.05    # m: rays start this far outside the obstacle's circumcircle
L_SHAPE = [[4.0, -1.0], [5.0, -1.0], [5.0, 0.0], [4.4, 0.0], [4.4, 1.0], [4.0, 1.0]]
BOX = [[-3.0, 2.0], [-2.0, 2.0], [-2.0, 3.0], [-3.0, 3.0]]


def _probe(world, polygon, height=0.5):
    """Return the hit points (M, 2) of rays aimed at ``polygon``'s vertex mean from all round.

    Each ray runs from STANDOFF outside the circumcircle about the vertex mean to the mean,
    in the ray scene at ``height``; rays without a hit are left out.
    """
    client, _ = world.ray_scene()
    centre = np.mean(polygon, axis=0)
    reach = np.max(np.linalg.norm(np.asarray(polygon) - centre, axis=1)) + STANDOFF
    angles = np.linspace(0.0, 2.0 * math.pi, DIRECTIONS, endpoint=False)
    starts = centre + reach * np.column_stack([np.cos(angles), np.sin(angles)])
    results = pb.rayTestBatch([(*s, height) for s in starts.tolist()],
                              [(*centre, height)] * DIRECTIONS, physicsClientId=client)
    return np.array([r[3][:2] for r in results if r[0] >= 0]).reshape(-1, 2)


def _bodies(world):
    """Return how many bodies the world's own client holds (ground, robots, obstacles made)."""
    return pb.getNumBodies(physicsClientId=world._client)


def test_every_cylinder_of_a_barn_world_is_hit_though_none_was_queried():
    """A fresh BARN world (no closest-point query made any obstacle body): every cylinder.

    Every one of its cylinders is hit, and the hit lies on the cylinder's surface (rays
    measure short by at most 2 mm).
    """
    barn = load_worlds(WORLDS_FILE)[0]
    with SimWorld(barn.scenario()) as world:
        made = _bodies(world)
        assert made == 2  # the ground plane and the robot: no obstacle body yet
        for centre in barn.centers:
            polygon = centre + barn.cylinder_radius * np.array([[1, 0], [0, 1], [-1, 0],
                                                                [0, -1]])
            hits = _probe(world, polygon)
            assert len(hits) >= DIRECTIONS // 2, centre
            gaps = np.linalg.norm(hits - centre, axis=1) - barn.cylinder_radius
            assert np.min(np.abs(gaps)) < 2e-3, (centre, gaps)
        assert _bodies(world) == made


def test_convex_non_convex_moving_and_popup_prisms_are_hit_where_they_are():
    """Box and L-shaped prism at once, a moving box where it has moved, a pop-up once up."""
    scenario = scenario_from_dict({
        'name': 'probe', 'duration': 5.0,
        'robots': [{'name': 'base', 'type': 'diff_drive', 'start': [0.0, 0.0, 0.0],
                    'goal': [1.0, 0.0]}],
        'obstacles': [{'polygon': BOX}, {'polygon': L_SHAPE},
                      {'polygon': [[0.0, -3.0], [0.4, -3.0], [0.4, -2.6], [0.0, -2.6]],
                       'velocity': [1.0, 0.0]},
                      {'polygon': [[-3.0, -3.0], [-2.6, -3.0], [-2.6, -2.6], [-3.0, -2.6]],
                       'appear_at': 0.5}]})
    obstacles = scenario.all_obstacles()
    with SimWorld(scenario) as world:
        for obstacle in obstacles[:2]:
            hits = _probe(world, obstacle.polygon)
            assert len(hits) >= 2
            assert max(abs(signed_distance(p, obstacle.polygon)) for p in hits) < 2e-3
        popup = obstacles[3].polygon
        assert len(_probe(world, popup)) == 0
        for _ in range(round(1.0 / world.dt)):
            world.step()
        hits = _probe(world, popup)
        assert len(hits) >= 2 and max(abs(signed_distance(p, popup)) for p in hits) < 2e-3
        moved = obstacles[2].polygon + obstacles[2].velocity * world.time
        hits = _probe(world, moved)
        assert len(hits) >= 2 and max(abs(signed_distance(p, moved)) for p in hits) < 2e-3


def test_other_robots_are_seen_and_the_own_body_never():
    """Two diff-drive discs 2 m apart: each lidar sees the other's disc, never its own."""
    scenario = scenario_from_dict({
        'name': 'probe', 'duration': 5.0,
        'robots': [{'name': 'left', 'type': 'diff_drive', 'start': [0.0, 0.0, 0.0],
                    'goal': [1.0, 0.0]},
                   {'name': 'right', 'type': 'diff_drive', 'start': [2.0, 0.0, 0.0],
                    'goal': [3.0, 0.0]}]})
    with SimWorld(scenario) as world:
        scans = dict(RobotLidars(world, LidarSettings()).scans())
        ahead, behind = scans['left'].ranges[180], scans['right'].ranges[0]
        assert ahead == pytest.approx(2.0 - 0.2, abs=2e-3)   # +x: the right disc's face
        assert behind == pytest.approx(2.0 - 0.2, abs=2e-3)  # -x: the left disc's face
        assert np.isfinite(scans['left'].ranges).sum() < 40  # nothing but the other disc


def test_scans_are_due_every_physics_rate_over_rate_steps_and_other_rates_are_refused():
    """240 Hz physics, 10 Hz lidar: steps 0, 24, 48 ...; 7 Hz is refused like a control rate."""
    scenario = scenario_from_dict({
        'name': 'probe', 'duration': 5.0,
        'robots': [{'name': 'base', 'type': 'diff_drive', 'start': [0.0, 0.0, 0.0],
                    'goal': [1.0, 0.0]}]})
    with SimWorld(scenario) as world:
        lidars = RobotLidars(world, LidarSettings(rate=10.0))
        due = []
        for _ in range(50):
            if lidars.scans():
                due.append(world.steps)
            world.step()
        assert lidars.steps == 24 and due == [0, 24, 48]
        with pytest.raises(ScenarioError, match='lidar rate 7 Hz does not divide physics_rate '
                                                '240 Hz.*valid lidar rates nearby'):
            RobotLidars(world, LidarSettings(rate=7.0))
        with pytest.raises(ValueError, match="no robot 'ghost'"):
            RobotLidars(world, LidarSettings(), ['ghost'])


@pytest.mark.parametrize('robot', [
    {'name': 'a1', 'type': 'quadruped', 'start': [0.0, 0.3, 0.0], 'goal': [5.0, 0.3]},
    {'name': 'cf', 'type': 'crazyflie', 'start': [0.0, 0.3, 0.5, 0.0], 'goal': [5.0, 0.3, 0.5]},
])
def test_the_ray_scene_changes_no_state_clearance_or_collision(robot):
    """The same commands with and without scanning every step: identical states and metrics.

    The quadruped drives into a wall (a collision), the Crazyflie falls on the floor.
    """
    document = {'name': 'probe', 'duration': 3.0, 'robots': [robot],
                'obstacles': [{'polygon': [[1.5, -1.0], [1.8, -1.0], [1.8, 1.0], [1.5, 1.0]]},
                              {'cylinder': [1.0, 0.9], 'radius': 0.2}]}
    command = ((1.5, 0.2), 'velocity') if robot['type'] == 'quadruped' else ((0.2, 0, 0, 0),
                                                                              'wrench')
    runs = []
    for scanning in (False, True):
        with SimWorld(scenario_from_dict(document)) as world:
            lidars = RobotLidars(world, LidarSettings(rate=240.0)) if scanning else None
            metrics = RunMetrics(world)
            states, clearances = [], []
            for _ in range(round(2.0 / world.dt)):
                world.set_command(robot['name'], *command)
                world.step()
                if lidars is not None:
                    assert lidars.scans()
                metrics.update()
                states.append(world.robot_state(robot['name']))
                clearances.append(world.clearances(robot['name']))
            runs.append((np.array(states), np.array(clearances), metrics.to_json()))
    (states, clearances, metrics), (states_scan, clearances_scan, metrics_scan) = runs
    np.testing.assert_array_equal(states, states_scan)
    np.testing.assert_array_equal(clearances, clearances_scan)
    assert metrics == metrics_scan and metrics[robot['name']]['collision']
