"""The in-process lockstep runner: deterministic, the node's obstacles, the paper's long wall."""
import numpy as np
import pytest

from polyc2bf_ros.core.obstacles.scan_conversion import ScanSettings
from polyc2bf_ros.filter_parameters import load_parameters
from sim_bridge.closed_loop import _Robot, obstacle_free, run_in_process
from sim_bridge.evaluation.records import summarise
from sim_bridge.launcher import params_file, scan_parameters
from sim_bridge.lidar import LidarSettings
from sim_bridge.obstacle_views import ObstacleView, ScanView
from sim_bridge.scenario import load_scenario, scenario_from_dict
from sim_bridge.world import SimWorld

# The paper's QP cost |u - u_nom|^2 (quadruped.yaml weighs alpha by offset_l^2): braking
# straight, it stands before a box ahead, the boundary equilibrium a deadlock report is for.
PAPER_COST = {'model_params.steering_weight': 1.0}

# A diff-drive base heading for a goal behind a wall across its way (face at x = 2.5).
WALL_AHEAD = {'name': 'wall_ahead', 'duration': 8.0,
              'robots': [{'name': 'base', 'type': 'diff_drive', 'start': [0.0, 0.0, 0.0],
                          'goal': [5.0, 0.0]}],
              'obstacles': [{'polygon': [[2.5, -3.0], [2.8, -3.0], [2.8, 3.0], [2.5, 3.0]],
                             'z': [0.0, 1.0]}]}


def test_runs_are_deterministic():
    """Two runs of the same scenario and filter record identical traces."""
    first, second = (run_in_process('long_wall', 'polyc2bf_inflated', duration=2.0)
                     for _ in range(2))
    a, b = first.robots['a1'], second.robots['a1']
    assert a.states.shape == (241, 5) and a.commands.shape == (240, 2)
    for field in ('states', 'nominal', 'commands', 'u_nom', 'u'):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    assert a.statuses == b.statuses and a.states[-1, 3] > 0.5


def test_obstacles_are_what_the_node_builds_from_the_bridge():
    """Other robots: the node's 12-gon around their centre; moving boxes: their velocity."""
    with SimWorld(load_scenario('multi_robot_swap')) as world:
        obstacles = ObstacleView(world).obstacles('a1_0')
        assert obstacles.keys == ('a1_1', 'a1_2', 'a1_3')
        counts = obstacles.footprints.counts
        assert counts.tolist() == [12, 12, 12]
        centre = obstacles.footprints.vertices[0, :12].mean(axis=0)
        np.testing.assert_allclose(centre, [4.0, -0.6], atol=1e-9)
        radii = np.linalg.norm(obstacles.footprints.vertices[0, :12] - centre, axis=1)
        np.testing.assert_allclose(radii, 0.4 / np.cos(np.pi / 12))
    with SimWorld(load_scenario('moving_obstacles')) as world:
        view = ObstacleView(world)
        before = view.obstacles('a1')
        np.testing.assert_allclose(before.velocities[:, 1], [0.6, -0.5, 0.5])
        assert view.obstacles('a1') is before  # same physics step: the same set
        world.step()
        after = view.obstacles('a1')
        np.testing.assert_allclose(after.footprints.vertices - before.footprints.vertices,
                                   np.broadcast_to((before.velocities[:, None, :2] * world.dt),
                                                   before.footprints.vertices.shape))


def test_obstacle_free_reference_has_no_obstacles():
    """The nominal reference drops listed and random obstacles."""
    reference = obstacle_free(load_scenario('cluttered'))
    assert reference.all_obstacles() == () and reference.robots


@pytest.fixture(scope='module')
def long_wall():
    """Run the paper's long wall, whole scenario, per filter: {filter: ClosedLoopRun}."""
    return {name: run_in_process('long_wall', name)
            for name in ('polyc2bf_inflated', 'c3bf', 'none')}


def test_polyc2bf_inflated_passes_the_long_wall(long_wall):
    """PolyC2BF keeps a positive clearance and reaches the goal behind the wall."""
    metrics = long_wall['polyc2bf_inflated'].metrics['a1']
    assert not metrics['collision'] and metrics['goal_reached']
    assert metrics['min_clearance_m'] > 0.05


def test_c3bf_fails_the_long_wall(long_wall):
    """C3BF starts inside the wall's virtual circle (escape at once) and never gets round."""
    run = long_wall['c3bf']
    trace = run.robots['a1']
    assert trace.statuses[0] == 'escape'
    assert trace.statuses.count('escape') > 0.5 * len(trace.statuses)
    assert not run.metrics['a1']['goal_reached']
    reference = {'a1': long_wall['none'].metrics['a1']['time_to_goal_s']}
    record = summarise(run, reference)
    assert not record['success'] and record['outcome'] == 'no_cone_at_start'
    assert not record['goal_reached']
    assert record['fallback_at_start'] and record['fallback_rate'] > 0.5


def test_no_filter_drives_into_the_wall(long_wall):
    """Without a filter the nominal controller goes straight through: a collision."""
    run = long_wall['none']
    assert run.metrics['a1']['collision'] and set(run.robots['a1'].statuses) == {'none'}
    assert np.isnan(run.robots['a1'].latency_s).all()
    record = summarise(run, {'a1': 10.0})
    assert record['outcome'] == 'collision' and record['mean_intervention'] is None


def test_the_deadlock_report_flags_the_popup_box_and_not_the_long_wall(long_wall):
    """Stopped for good before the pop-up box: reported at the end, labelled deadlock.

    Slowed and steered along the long wall, then through to the goal: never reported.
    """
    run = run_in_process('popup_obstacle', 'polyc2bf_inflated',
                         parameters={'deadlock_resolution': 'none', **PAPER_COST})
    record = summarise(run, {'a1': 10.0})
    assert record['outcome'] == 'deadlock'
    assert record['deadlocked_at_end'] and record['deadlock_detections'] == 1
    trace = run.robots['a1']
    first = int(np.argmax(trace.deadlocked))
    held = load_parameters([params_file('quadruped')], (), '')['deadlock_time']
    assert trace.times[first] > 3.0 + held  # the box appears at 3 s; held that long at least
    assert trace.deadlocked[first:].all()
    passed = summarise(long_wall['polyc2bf_inflated'], {'a1': 10.0})
    assert passed['success'] and passed['deadlock_detections'] == 0


@pytest.mark.parametrize('resolution', ['circulate', 'route'])
def test_each_resolution_resolves_the_popup_box_without_collision(resolution):
    """Default barrier, the paper's cost: reported, steered round the box, at the goal.

    The report comes deadlock_time after the robot stood; the filter's rows are the same.
    """
    run = run_in_process('popup_obstacle', 'polyc2bf_horizon', duration=30.0,
                         parameters={'deadlock_resolution': resolution, **PAPER_COST})
    record = summarise(run, {'a1': 10.0})
    assert record['success'] and not record['collision']
    assert record['min_clearance_m'] is None or record['min_clearance_m'] > 0.05
    assert record['deadlock_detections'] >= 1 and not record['deadlocked_at_end']


def test_the_shipped_steering_weight_turns_round_the_popup_box_without_a_deadlock():
    """quadruped.yaml's cost (steering_weight = offset_l^2): no boundary equilibrium.

    The box appears 1.75 m ahead, straight across the way: the QP turns as it brakes, so
    the robot never stands, is never reported, and reaches the goal without contact,
    sooner than the paper's cost with a route after the report.
    """
    runs = {name: run_in_process('popup_obstacle', 'polyc2bf_horizon', duration=30.0,
                                 parameters=parameters)
            for name, parameters in (('shipped', None), ('paper', PAPER_COST))}
    shipped, paper = (summarise(runs[name], {'a1': 10.0}) for name in ('shipped', 'paper'))
    assert shipped['success'] and not shipped['collision']
    assert shipped['min_clearance_m'] is None or shipped['min_clearance_m'] > 0.05
    assert shipped['deadlock_detections'] == 0
    assert not runs['shipped'].robots['a1'].deadlocked.any()
    assert paper['deadlock_detections'] >= 1
    times = {name: run.metrics['a1']['time_to_goal_s'] for name, run in runs.items()}
    assert times['shipped'] < times['paper'], times


# A U open towards the quadruped, its goal straight on beyond the closed end.
U_POCKET = {'name': 'u_pocket', 'duration': 40.0,
            'robots': [{'name': 'a1', 'type': 'quadruped', 'start': [0.0, 0.0, 0.0],
                        'goal': [8.0, 0.0]}],
            'obstacles': [{'polygon': polygon, 'z': [0.0, 1.0]} for polygon in (
                [[4.0, -1.5], [4.3, -1.5], [4.3, 1.5], [4.0, 1.5]],
                [[1.5, 1.5], [4.3, 1.5], [4.3, 1.8], [1.5, 1.8]],
                [[1.5, -1.8], [4.3, -1.8], [4.3, -1.5], [1.5, -1.5]])]}


@pytest.mark.parametrize('resolution, succeeds', [('route', True), ('circulate', False)])
def test_a_route_backs_out_of_a_u_pocket_that_circulation_cannot_leave(resolution, succeeds):
    """Go-to-goal into a U: the route leaves by the open end and reaches the goal.

    Circulation follows the back wall into a corner and stays deadlocked.  Neither collides.
    """
    run = run_in_process(scenario_from_dict(U_POCKET), 'polyc2bf_horizon',
                         parameters={'deadlock_resolution': resolution})
    record = summarise(run, {'a1': 8.0})
    assert not record['collision'] and record['deadlock_detections'] >= 1
    assert record['success'] is succeeds
    assert record['deadlocked_at_end'] is not succeeds


def test_scan_mode_filter_holds_only_what_the_node_makes_of_the_lidar_scan():
    """Keys ``scan:scan/<i>``; rectangles behind the wall's lit face; held until the next scan."""
    scenario = scenario_from_dict(WALL_AHEAD)
    lidar = LidarSettings()
    with SimWorld(scenario) as world:
        robot = _Robot(scenario.robots[0], 'polyc2bf_inflated', 'goal', 1.0 / 120.0, 10, world,
                       scan_parameters(lidar))
        view = ScanView(world, {'base': robot}, lidar)
        state = world.robot_state('base')
        snapshot = view.snapshot('base', state, state[2], 0.0)
        obstacles = snapshot.obstacles
        assert obstacles.keys and all(key.startswith('scan:scan/') for key in obstacles.keys)
        vertices = np.concatenate([obstacles.footprints.vertices[i, :count]
                                   for i, count in enumerate(obstacles.footprints.counts)])
        assert vertices[:, 0].min() > 2.5 - 2e-3
        assert vertices[:, 0].max() < 2.5 + ScanSettings().depth + 0.01
        assert vertices[:, 1].min() < -2.9 and vertices[:, 1].max() > 2.9
        assert not np.any(obstacles.velocities)
        world.step()
        view.sense()  # step 1: no scan due (every 24 steps at 10 Hz)
        assert view.snapshot('base', state, state[2], 1.0 / 240.0) is snapshot


def test_a_scan_taken_between_two_periods_is_placed_where_the_base_was():
    """A base driving at 1 m/s at the wall sees its face where it stands, scan after scan.

    The lidar scans at 48 Hz on a 240 Hz physics step, so every other scan falls between two
    120 Hz control periods.  Placed at the next period's pose, the face jumped 4 mm towards
    the base on those scans (1 m/s over the 1/240 s in between); placed at the pose
    interpolated between the periods around it, it stays within noise-free rounding.
    """
    scenario = scenario_from_dict(WALL_AHEAD)
    lidar = LidarSettings(rate=48.0)
    period = 1.0 / 120.0
    with SimWorld(scenario) as world:
        substeps = round(period / world.dt)
        robot = _Robot(scenario.robots[0], 'polyc2bf_inflated', 'goal', period, 60, world,
                       scan_parameters(lidar))
        view = ScanView(world, {'base': robot}, lidar)
        faces, snapshot = [], None
        for k in range(60):
            state = world.robot_state('base')
            latest = view.snapshot('base', state, state[2], k * period)
            if latest is not snapshot and k > 30:  # up to speed, each new scan's face
                footprints = latest.obstacles.footprints
                faces.append(min(footprints.vertices[i, :count, 0].min()
                                 for i, count in enumerate(footprints.counts)))
            snapshot = latest
            world.set_command('base', np.array([1.0, 0.0]), robot.kind)
            for _ in range(substeps):
                world.step()
                view.sense()
        assert world.robot_state('base')[3] > 0.9
    assert len(faces) >= 10
    assert max(faces) - min(faces) < 1e-3, faces


def test_scan_mode_closed_loop_stops_before_the_wall_without_collision():
    """Obstacles only from the lidar: the base drives up to the wall and stops short of it.

    The horizon-aware barrier lets it close in (to a few cm), where only the scan's
    rectangles stand between the disc and the wall.
    """
    run = run_in_process(scenario_from_dict(WALL_AHEAD), 'polyc2bf_horizon',
                         obstacle_source='scan')
    assert run.obstacle_source == 'scan' and run.lidar == LidarSettings()
    metrics, trace = run.metrics['base'], run.robots['base']
    assert not metrics['collision'] and not metrics['goal_reached']
    assert 0.0 < metrics['min_clearance_m'] < 0.1
    assert trace.states[:, 0].max() > 2.2  # up to the wall (face 2.5, disc radius 0.2)
    assert np.isfinite(trace.min_h).all()  # the filter had obstacles from the first step


def test_scan_mode_with_noise_is_deterministic():
    """Seeded range noise: two runs record the same states, unlike the noise-free run."""
    noisy = LidarSettings(noise_std=0.02)
    first, second, clean = (
        run_in_process(scenario_from_dict(WALL_AHEAD), 'polyc2bf_horizon', duration=4.0,
                       obstacle_source='scan', lidar=lidar).robots['base'].states
        for lidar in (noisy, noisy, LidarSettings()))
    np.testing.assert_array_equal(first, second)
    assert not np.array_equal(first, clean)
