"""The in-process lockstep runner: deterministic, the node's obstacles, the paper's long wall."""
import numpy as np
import pytest

from sim_bridge.closed_loop import _ObstacleView, obstacle_free, run_in_process
from sim_bridge.evaluate import summarise
from sim_bridge.scenario import load_scenario
from sim_bridge.world import SimWorld


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
        obstacles = _ObstacleView(world).obstacles('a1_0')
        assert obstacles.keys == ('a1_1', 'a1_2', 'a1_3')
        counts = obstacles.footprints.counts
        assert counts.tolist() == [12, 12, 12]
        centre = obstacles.footprints.vertices[0, :12].mean(axis=0)
        np.testing.assert_allclose(centre, [4.0, -0.6], atol=1e-9)
        radii = np.linalg.norm(obstacles.footprints.vertices[0, :12] - centre, axis=1)
        np.testing.assert_allclose(radii, 0.4 / np.cos(np.pi / 12))
    with SimWorld(load_scenario('moving_obstacles')) as world:
        view = _ObstacleView(world)
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
                         parameters={'deadlock_resolution': 'none'})
    record = summarise(run, {'a1': 10.0})
    assert record['outcome'] == 'deadlock'
    assert record['deadlocked_at_end'] and record['deadlock_detections'] == 1
    trace = run.robots['a1']
    first = int(np.argmax(trace.deadlocked))
    assert trace.times[first] > 3.0 + 3.0  # the box appears at 3 s; held 3 s at least
    assert trace.deadlocked[first:].all()
    passed = summarise(long_wall['polyc2bf_inflated'], {'a1': 10.0})
    assert passed['success'] and passed['deadlock_detections'] == 0


def test_circulation_resolves_the_popup_box_without_collision():
    """deadlock_resolution circulate, default barrier: reported, steered round the box, at goal.

    The report comes deadlock_time after the robot stood; the filter's rows are the same.
    """
    run = run_in_process('popup_obstacle', 'polyc2bf_horizon', duration=30.0,
                         parameters={'deadlock_resolution': 'circulate'})
    record = summarise(run, {'a1': 10.0})
    assert record['success'] and not record['collision']
    assert record['min_clearance_m'] is None or record['min_clearance_m'] > 0.05
    assert record['deadlock_detections'] >= 1 and not record['deadlocked_at_end']
