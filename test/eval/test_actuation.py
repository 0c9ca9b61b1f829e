"""The arena's realism mode (``sim_bridge.actuation``): latency, first-order response, noise."""
import contextlib
import io
import json

import numpy as np
import pytest

from sim_bridge.actuation import Actuation, CommandPipe, describe, Odometry
from sim_bridge.barn import load_worlds, WORLDS_FILE
from sim_bridge.closed_loop import run_in_process
from sim_bridge.evaluation.barn_suite import run_world
from sim_bridge.evaluation.cli import main
from sim_bridge.evaluation.records import summarise
from sim_bridge.lidar import LidarSettings

DURATION = 1.5


def _speeds(actuation):
    """Return (times, speeds) of the quadruped of ``clear_path`` unfiltered, from rest."""
    run = run_in_process('clear_path', 'none', duration=DURATION, actuation=actuation)
    trace = run.robots['a1']
    return trace.times, trace.states[:-1, 3], run


def test_a_command_acts_after_the_latency():
    """The pipe holds each command back by the latency; before the first, its initial one."""
    pipe = CommandPipe(0.03, 'rest')
    pipe.send(0.0, 'a')
    pipe.send(0.01, 'b')
    assert pipe.at(0.0) == 'rest' and pipe.at(0.029) == 'rest'
    assert pipe.at(0.03) == 'a' and pipe.at(0.035) == 'a' and pipe.at(0.04) == 'b'
    assert CommandPipe(0.0, None).at(0.0) is None


def test_latency_delays_and_the_actuator_lags_the_plant():
    """From rest, the plant starts to move the latency later, and follows to first order.

    Exact: the speed steps up within the plant's acceleration limit from the first period.
    With tau = 0.2 s it reaches at most 1 - exp(-t / tau) of the commanded speed, and
    with 0.1 s of latency it stands still for the first 0.1 s.
    """
    times, exact, run = _speeds(None)
    assert run.actuation.exact and exact[1] > 0.0
    times, delayed, run = _speeds(Actuation(latency=0.1))
    assert run.actuation.record() == {'latency_s': 0.1, 'actuator_tau_s': 0.0,
                                      'odom_noise_m': 0.0}
    late = times <= 0.1 + 1e-9
    assert np.all(delayed[late] == 0.0) and delayed[~late].max() > 0.0
    shift = round(0.1 / (times[1] - times[0]))  # the same speeds, that many periods later
    np.testing.assert_allclose(delayed[shift:shift + 10], exact[:10], atol=1e-9)
    times, lagging, _ = _speeds(Actuation(actuator_tau=0.2))
    commanded = exact.max()
    assert np.all(lagging <= commanded * (1.0 - np.exp(-times / 0.2)) + 1e-6)
    assert lagging[-1] > 0.9 * commanded * (1.0 - np.exp(-times[-1] / 0.2))


def test_odometry_noise_is_seeded_and_leaves_the_truth_alone():
    """Noise of the given size on x, y (and heading per metre); the same seed, the same."""
    state = np.array([1.0, 2.0, 0.5, 0.3, 0.0])
    readings = [Odometry(0.01, 7, yaw_index=2).read(state) for _ in range(2)]
    np.testing.assert_array_equal(readings[0], readings[1])
    many = np.array([Odometry(0.01, seed, yaw_index=2).read(state) for seed in range(400)])
    assert np.std(many[:, 0] - 1.0) == pytest.approx(0.01, rel=0.2)
    np.testing.assert_array_equal(many[:, 3:], np.tile(state[3:], (400, 1)))
    assert Odometry(0.0, 1).read(state) is state
    assert state.tolist() == [1.0, 2.0, 0.5, 0.3, 0.0]


def test_evaluate_states_the_actuation_and_refuses_bad_values(tmp_path, capsys):
    """The CLI passes the settings to every run, its records and its table header."""
    out = tmp_path / 'out'
    with contextlib.redirect_stderr(io.StringIO()), contextlib.redirect_stdout(io.StringIO()):
        assert main(['--scenarios', 'clear_path', '--filters', 'polyc2bf_inflated',
                     '--duration', '2', '--no-plots', '--out', str(out),
                     '--latency', '0.02', '--actuator-tau', '0.05',
                     '--odom-noise', '0.005']) == 0
    record, = json.loads((out / 'results.json').read_text())
    assert record['actuation'] == {'latency_s': 0.02, 'actuator_tau_s': 0.05,
                                   'odom_noise_m': 0.005}
    assert f"Actuation: {describe(record['actuation'])}." in (out / 'results.md').read_text()
    assert 'command latency 0.02 s' in describe(record['actuation'])
    with pytest.raises(SystemExit) as exit_info:
        main(['--scenarios', 'clear_path', '--actuator-tau', '-1'])
    assert exit_info.value.code == 2
    assert '--actuator-tau must be a finite number >= 0' in capsys.readouterr().err


def test_a_parameter_a_robots_filter_refuses_exits_2_naming_it(capsys):
    """``-p command_latency`` reaches the Crazyflie's filter, which refuses it: exit 2."""
    with pytest.raises(SystemExit) as exit_info, \
            contextlib.redirect_stdout(io.StringIO()):
        main(['--scenarios', 'quadrotor_pillars', '--filters', 'default', '--duration', '0.1',
              '--no-plots', '--out', '/dev/null/none', '-p', 'command_latency:=0.03'])
    assert exit_info.value.code == 2
    assert 'applies to velocity models' in capsys.readouterr().err


def test_a_parameter_no_node_declares_exits_2_naming_it(capsys):
    """A misspelt ``-p`` name would change nothing: refused before any run."""
    with pytest.raises(SystemExit) as exit_info:
        main(['--suite', 'barn', '--limit', '1', '--no-plots', '--out', '/dev/null/none',
              '-p', 'command_latency_eror:=0.01'])
    assert exit_info.value.code == 2
    assert '--param command_latency_eror: the safety_filter node has no such parameter' in (
        capsys.readouterr().err)


@pytest.mark.parametrize('told, margin', [((0.03, 0.1), None), ((0.02, 0.07), 0.02)],
                         ids=['true values', 'told 20 ms and 0.07 s'])
def test_a_late_lagging_base_touches_unless_the_filter_is_told(told, margin):
    """BARN world 16, go-to-goal: a base 30 ms late with tau 0.1 s and 1 cm odometry noise.

    Uncompensated the robot touches a cylinder; told the true latency and lag, or told
    less (20 ms and 0.07 s, with a 2 cm braking margin), it reaches the goal
    without contact.
    """
    world, = [w for w in load_worlds(WORLDS_FILE) if w.world == 16]
    plant = Actuation(latency=0.03, actuator_tau=0.1, odom_noise=0.01)
    (blind, _), = run_world(world, [('polyc2bf_horizon', 'goal')], actuation=plant)
    assert blind['collision'] and blind['min_clearance_m'] < 0.0
    parameters = {'command_latency': told[0], 'actuator_tau': told[1]}
    if margin is not None:
        parameters['filter.braking_margin'] = margin
    (record, _), = run_world(world, [('polyc2bf_horizon', 'goal')], parameters=parameters,
                             actuation=plant)
    assert record['success'] and not record['collision']
    assert record['min_clearance_m'] > 0.0
    assert record['actuation']['latency_s'] == 0.03


def test_from_the_laser_a_base_later_and_slower_than_told_stays_clear_with_the_error_bounds():
    """BARN world 212, go-to-goal, from a 270-degree laser with 1 cm noise.

    The base is 30 ms late with tau 0.1 s and 1 cm odometry noise; the filter is told
    20 ms and 0.07 s with a 2 cm braking margin, and that the base may be 10 ms later and
    0.03 s slower (``braking_plan``): it reaches the goal without contact.  Without the
    bounds it stays clear too: the braking check refuses stops deeper inside an obstacle
    where braking cannot stop clear.  The bounds change the stops it plans, so the runs
    differ.
    """
    world, = [w for w in load_worlds(WORLDS_FILE) if w.world == 212]
    plant = Actuation(latency=0.03, actuator_tau=0.1, odom_noise=0.01)
    lidar = LidarSettings(field_of_view=4.71238898, noise_std=0.01)  # as bench/README.md
    # The laser keeps nothing it saw (scan_memory_time 0): the bounds and the check alone.
    told = {'command_latency': 0.02, 'actuator_tau': 0.07, 'odom_position_std': 0.01,
            'odom_heading_std': 0.01, 'filter.braking_margin': 0.02, 'scan_memory_time': 0.0}
    records = {}
    for name, bounds in (('unbounded', {}), ('bounded', {'command_latency_error': 0.01,
                                                         'actuator_tau_error': 0.03})):
        (records[name], _), = run_world(world, [('polyc2bf_horizon', 'goal')],
                                        parameters={**told, **bounds},
                                        obstacle_source='scan', lidar=lidar,
                                        actuation=plant)
    unbounded, bounded = records['unbounded'], records['bounded']
    assert not unbounded['collision'] and unbounded['min_clearance_m'] > 0.0
    assert bounded['success'] and not bounded['collision']
    assert bounded['min_clearance_m'] > 0.0
    assert bounded['time_s'] != unbounded['time_s']   # the bounds changed the stops planned


def test_lagging_rotors_put_a_crazyflie_into_the_pillars_unless_the_filter_is_told():
    """``quadrotor_pillars`` with rotors lagging by 30 ms: a contact, unless the filter is told.

    Told ``actuator_tau``, it commands thrusts the rotors reach (``core.actuation.rotor_lag``) and
    the run reaches the goal clear of the pillars.
    """
    plant = Actuation(actuator_tau=0.03)
    blind = summarise(run_in_process('quadrotor_pillars', 'polyc2bf_horizon', actuation=plant),
                      {})
    assert blind['collision']
    told = summarise(run_in_process('quadrotor_pillars', 'polyc2bf_horizon', actuation=plant,
                                    parameters={'actuator_tau': 0.03}), {})
    assert not told['collision'] and told['goal_reached']
    assert told['min_clearance_m'] > 0.05
