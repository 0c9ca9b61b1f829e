"""The node's parameter files read without ROS (offline replay, in-process evaluation)."""
import numpy as np
import pytest

from polyc2bf_ros.core.decision import ControlDecision
from polyc2bf_ros.filter_parameters import (
    build_filter,
    build_settings,
    load_parameters,
    ParameterError,
)


def test_parameter_files_match_node_names_like_rcl(tmp_path):
    """Sections for /**, the namespace and the bare name apply in order; -p overrides last."""
    path = tmp_path / 'params.yaml'
    path.write_text(
        '/**/safety_filter:\n  ros__parameters:\n    rate: 50.0\n    filter: {gamma: 2.0}\n'
        '/a1/safety_filter:\n  ros__parameters:\n    rate: 80.0\n'
        '/b2/safety_filter:\n  ros__parameters:\n    rate: 10.0\n'
        'other_node:\n  ros__parameters:\n    rate: 1.0\n')
    params = load_parameters([path], ['filter.barrier:=c3bf', 'match_stamps:=true'], 'a1')
    assert params == {'rate': 80.0, 'filter.gamma': 2.0, 'filter.barrier': 'c3bf',
                      'match_stamps': True}
    assert load_parameters([path], [], '')['rate'] == 50.0
    setup = build_filter(params)
    assert setup.command_filter.safety_filter.config.control_period == pytest.approx(1 / 80)
    assert setup.parameters['filter.barrier'] == 'c3bf'
    with pytest.raises(ParameterError, match='invalid filter parameters: gamma'):
        build_filter({'filter.gamma': -1.0})
    with pytest.raises(ParameterError, match='not NAME:=VALUE'):
        load_parameters([], ['rate'], 'a1')


def test_unknown_parameters_are_listed_not_applied():
    """A name the node does not declare is reported in ``ignored`` and changes nothing."""
    setup = build_filter({'filter.gamma': 2.0, 'filter.no_such_field': 1.0, 'typo_rate': 5.0})
    assert setup.ignored == ('filter.no_such_field', 'typo_rate')
    assert setup.command_filter.safety_filter.config.gamma == 2.0
    with pytest.raises(ParameterError, match="parameter 'model' must be one of"):
        build_filter({'model': 'tank'})


def test_route_parameters_reach_the_resolution_and_must_fit_the_window():
    """route_ahead, route_window, route_clear_run reach the route; window under 2 x reach fails."""
    setup = build_filter({'deadlock_resolution': 'route', 'route_ahead': 4.0,
                          'route_window': 12.0, 'route_clear_run': 1.5})
    assert setup.route == (4.0, 12.0, 1.5)
    decision = ControlDecision(setup.command_filter, setup.timeouts, setup.block_if_invalid,
                               setup.max_extrapolation, setup.deadlock, setup.resolution,
                               setup.route)
    assert decision.circulation.route_options == {'ahead': 4.0, 'window': 12.0, 'run': 1.5}
    with pytest.raises(ParameterError, match='route_window .* must exceed 2 route_ahead'):
        build_filter({'route_ahead': 6.0})


def test_scan_split_tolerance_must_leave_room_in_the_cluster_tolerance():
    """A piece's points stay within cluster_tolerance of its polygon only if split + 1 cm fits."""
    assert build_filter({'scan_split_tolerance': 0.01}).intake.scan_split_tolerance == 0.01
    with pytest.raises(ParameterError, match='invalid scan parameters .*must not exceed '
                                             'cluster_tolerance'):
        build_filter({'scan_split_tolerance': 0.2})


@pytest.mark.parametrize('values, message', [
    ({'command_latency': -0.01}, 'command_latency must be a finite number >= 0'),
    ({'command_latency': float('nan')}, 'command_latency must be a finite number >= 0'),
    ({'actuator_tau': float('inf')}, 'actuator_tau must be a finite number >= 0'),
    ({'actuator_tau_error': -0.01}, 'actuator_tau_error must be a finite number >= 0'),
    ({'command_latency_error': float('nan')},
     'command_latency_error must be a finite number >= 0'),
    ({'command_latency': 0.5, 'cmd_timeout': 0.5}, r'command_latency \(0.5 s\) must be '
     r'below cmd_timeout \(0.5 s\)'),
])
def test_bad_latency_and_lag_are_refused_in_one_line(values, message):
    """Negative or non-finite actuation, or a latency as long as the command timeout: refused."""
    with pytest.raises(ParameterError, match=message) as error:
        build_filter(values)
    assert '\n' not in str(error.value)
    assert build_filter({'command_latency': 0.03, 'actuator_tau': 0.1}).command_filter


def test_scan_sources_are_checked_offline_as_in_the_node():
    """No obstacle source, or a scan timeout within a period: refused by ``build_filter`` too."""
    with pytest.raises(ParameterError, match='use_markers is false and scan_topics is empty'):
        build_filter({'use_markers': False})
    with pytest.raises(ParameterError, match=r'scan_timeout \(0.005 s\) must exceed'):
        build_filter({'scan_topics': ['scan'], 'scan_timeout': 0.005})
    setup = build_filter({'use_markers': False, 'scan_topics': ['scan', '/scan', 'scan', ''],
                          'scan_timeout': 0.0})
    assert setup.scan_topics == ('scan', '/scan') and setup.scan_timeout == 0.0
    assert setup.ignored == ()


def test_a_change_that_keeps_the_filter_values_is_checked_without_building_a_filter():
    """``reuse``: its filter when only other values change; a filter value builds a new one."""
    setup = build_filter({'model': 'quadrotor', 'scan_topics': ['/robot/scan']})
    model = setup.command_filter.model
    changed = build_settings(dict(setup.parameters, odom_timeout=0.3), model, setup)
    assert changed.command_filter is setup.command_filter and changed.timeouts['odom'] == 0.3
    assert changed.watchdog_timeouts == {'odom': 0.3, 'cmd': 0.5, 'obstacles': 1.0,
                                         'scan_robot_scan': 1.0}
    with pytest.raises(ParameterError, match=r'odom_timeout \(0.005 s\) must exceed'):
        build_settings(dict(setup.parameters, odom_timeout=0.005), model, setup)
    with pytest.raises(ParameterError, match='command_latency applies to velocity models'):
        build_settings(dict(setup.parameters, command_latency=0.1), model, setup)
    rebuilt = build_settings(dict(setup.parameters, **{'filter.gamma': 2.0}), model, setup)
    assert rebuilt.command_filter is not setup.command_filter
    assert rebuilt.command_filter.safety_filter.config.gamma == 2.0


def test_error_bounds_slow_and_delay_the_braking_checks_stops_only():
    """Bounds on the latency and lag error plan slower stops; the brake asked stays full."""
    told = {'command_latency': 0.02, 'actuator_tau': 0.07}
    exact = build_filter(told).command_filter.model
    model = build_filter({**told, 'command_latency_error': 0.01,
                          'actuator_tau_error': 0.03}).command_filter.model
    assert (exact.braking_share, exact.braking_coast) == (1.0, 0.0)
    assert model.braking_share < 1.0 and model.braking_coast == pytest.approx(0.08)
    assert model.brake_time_constant == pytest.approx(0.1)
    state = [0.0, 0.0, 0.0, 1.0, 0.0]
    np.testing.assert_array_equal(model.braking_input(state), exact.braking_input(state))
    assert model.braking_path(state, 0.01)[-1, 0] > exact.braking_path(state, 0.01)[-1, 0] + 0.1


def test_a_nav2_footprint_in_a_parameter_file_is_guarded_by_its_covering_disc(tmp_path):
    """``footprint`` as Nav2 writes it (a quoted string) replaces robot_radius everywhere."""
    path = tmp_path / 'params.yaml'
    path.write_text('safety_filter:\n  ros__parameters:\n    filter:\n      robot_radius: 0.1\n'
                    '      footprint: "[[0.5, 0.3], [-0.5, 0.3], [-0.5, -0.3], [0.5, -0.3]]"\n')
    setup = build_filter(load_parameters([path], [], ''))
    geometry = setup.command_filter.safety_filter.geometry
    assert geometry.robot_radius == pytest.approx(np.hypot(0.5, 0.3))  # the scans' own body too
    with pytest.raises(ParameterError, match='footprint .* self-intersecting') as error:
        build_filter({'filter.footprint': '[[0.5, 0.3], [-0.5, -0.3], [-0.5, 0.3], [0.5, -0.3]]'})
    assert '\n' not in str(error.value)
    with pytest.raises(ParameterError, match='footprint must be a string'):
        build_filter({'filter.footprint': [[0.5, 0.3], [-0.5, 0.3], [-0.5, -0.3]]})
