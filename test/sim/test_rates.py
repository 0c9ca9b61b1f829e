"""Control periods are whole numbers of physics steps: other rates are refused, not rounded."""
import dataclasses
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from polyc2bf_ros.filter_parameters import load_parameters
from sim_bridge.closed_loop import run_in_process
from sim_bridge.launcher import closed_loop_plan, control_rate
from sim_bridge.scenario import (
    DEFAULT_CONTROL_RATE,
    DEFAULT_PHYSICS_RATE,
    load_scenario,
    scenario_from_dict,
    scenario_names,
)
from sim_bridge.scenario_specs import control_substeps, ScenarioError

REPO = Path(__file__).resolve().parents[2]


def _document(**rates):
    """Return a valid one-robot scenario document with ``rates`` added."""
    return {'name': 'probe', 'duration': 1.0, **rates,
            'robots': [{'name': 'a1', 'type': 'quadruped', 'start': [0.0, 0.0, 0.0],
                        'goal': [4.0, 0.0]}]}


@pytest.mark.parametrize('physics, control, steps', [
    (240, 120, 2), (240, 240, 1), (240, 80, 3), (240, 60, 4), (1000, 100, 10),
    (1000, 1000 / 7, 7),               # 142.857... Hz: the ratio has float error
    (1000, 100.00000000000001, 10),    # a rate computed as, e.g., a sum of decimals
    ((0.1 + 0.2) * 1000, 100, 3),      # 300.00000000000006 Hz physics
    (500, 1 / 0.01, 5), (1 / 0.001, 1 / 0.004, 4),
])
def test_a_dividing_rate_gives_its_whole_number_of_substeps(physics, control, steps):
    """Accepted to float error; the control rate is physics_rate / steps."""
    assert control_substeps(physics, control) == steps
    scenario = scenario_from_dict(_document(physics_rate=physics, control_rate=control))
    assert scenario.substeps == steps
    assert control_rate(scenario) == pytest.approx(control, rel=1e-12)
    assert control_rate(scenario) == scenario.physics_rate / steps


@pytest.mark.parametrize('physics, control, nearby', [
    (240, 100, ('120 Hz (2 steps)', '80 Hz (3 steps)')),
    (1000, 120, ('125 Hz (8 steps)', '111.111 Hz (9 steps)')),
    (240, 119.9999, ('120 Hz (2 steps)', '80 Hz (3 steps)')),  # beyond float error
    (100, 30, ('33.3333 Hz (3 steps)', '25 Hz (4 steps)')),
    (240, 500, ('240 Hz (1 step)', '120 Hz (2 steps)')),       # faster than physics
])
def test_a_non_dividing_rate_is_refused_naming_both_rates_and_valid_ones(physics, control,
                                                                         nearby):
    """ScenarioError (a ValueError): both rates, and the divisors of physics_rate near."""
    with pytest.raises(ScenarioError) as refused:
        control_substeps(physics, control)
    message = str(refused.value)
    assert isinstance(refused.value, ValueError)
    assert message.startswith(f'control_rate {control:g} Hz ')
    assert f'physics_rate {physics:g} Hz' in message
    for rate in nearby:
        assert rate in message, message


def test_the_default_rates_divide_and_keep_the_old_effective_rate():
    """240 / 120 Hz: the 2 steps per period that 240 / 100 Hz used to be rounded to."""
    scenario = scenario_from_dict(_document())
    assert (scenario.physics_rate, scenario.control_rate) == (DEFAULT_PHYSICS_RATE,
                                                             DEFAULT_CONTROL_RATE) == (240, 120)
    assert scenario.substeps == 2


def test_a_scenario_file_with_a_non_dividing_rate_is_refused_at_the_field(tmp_path):
    """The loader's message names the file and the field, as for any bad field."""
    path = tmp_path / 'bad_rate.yaml'
    path.write_text(yaml.safe_dump(_document(control_rate=100)))
    with pytest.raises(ScenarioError, match=r'bad_rate\.yaml: control_rate: 100 Hz does not '
                                            r'divide physics_rate 240 Hz .*120 Hz \(2 steps\)'):
        load_scenario(path)
    with pytest.raises(ScenarioError, match='control_rate: 120 Hz does not divide physics_rate '
                                            '1000 Hz'):
        scenario_from_dict(_document(physics_rate=1000))


def test_every_entry_point_refuses_a_non_dividing_rate(tmp_path):
    """Loader, in-process closed loop, launcher plan and a replaced rate (the bridge's)."""
    path = tmp_path / 'bad_rate.yaml'
    path.write_text(yaml.safe_dump(_document(physics_rate=240, control_rate=90)))
    for entry in (load_scenario, run_in_process, closed_loop_plan):
        with pytest.raises(ScenarioError, match='90 Hz does not divide physics_rate 240 Hz'):
            entry(str(path))
    scenario = load_scenario('clear_path')
    # The bridge applies its physics_rate / control_rate parameters with dataclasses.replace.
    with pytest.raises(ScenarioError, match='control_rate 100 Hz does not divide physics_rate '
                                            '240 Hz'):
        dataclasses.replace(scenario, control_rate=100.0)
    with pytest.raises(ScenarioError, match='control_rate 120 Hz does not divide physics_rate '
                                            '1000 Hz'):
        dataclasses.replace(scenario, physics_rate=1000.0)
    assert dataclasses.replace(scenario, physics_rate=1200.0).substeps == 10


@pytest.mark.parametrize('name', scenario_names())
def test_shipped_scenarios_and_the_filters_they_start_use_dividing_rates(name):
    """Each shipped scenario's rates divide; every filter of its run gets rate = 1 / period.

    The filter parameter files' own ``rate`` (100 Hz, the Crazyflie's 500 Hz) is the
    node's on hardware: the launcher's ``-p rate:=...`` replaces it in the simulated
    loop, read here with the node's parameter-file loader.
    """
    scenario = load_scenario(name)
    steps = control_substeps(scenario.physics_rate, scenario.control_rate)
    assert steps == scenario.substeps >= 1
    assert scenario.physics_rate / steps == pytest.approx(scenario.control_rate, rel=1e-12)
    filters = [spec for spec in closed_loop_plan(name) if spec.module.endswith('filter_node')]
    assert len(filters) == len(scenario.robots)
    for spec in filters:
        args = spec.ros_args()
        overrides = [args[i + 1] for i, arg in enumerate(args) if arg == '-p']
        values = load_parameters([spec.params_file], overrides, spec.namespace)
        assert control_substeps(scenario.physics_rate, values['rate']) == steps


@pytest.mark.parametrize('parameters, message, valid', [
    (['control_rate:=100.0'], 'control_rate 100 Hz does not divide physics_rate 240 Hz',
     'valid control rates'),
    (['physics_rate:=1000.0'], 'control_rate 120 Hz does not divide physics_rate 1000 Hz',
     'valid control rates'),
    (['lidar.enabled:=true', 'lidar.rate:=7.0'],
     'lidar rate 7 Hz does not divide physics_rate 240 Hz', 'valid lidar rates'),
])
def test_the_bridge_refuses_a_non_dividing_rate_parameter_with_one_fatal_line(parameters,
                                                                               message, valid):
    """No traceback: one ``[FATAL]`` line with both rates and valid ones, exit status 1."""
    command = [sys.executable, '-m', 'sim_bridge.bridge_node', '--ros-args',
               '-p', 'scenario:=clear_path']
    for parameter in parameters:
        command += ['-p', parameter]
    result = subprocess.run(command, cwd=REPO, capture_output=True, text=True, timeout=120)
    output = result.stdout + result.stderr
    assert result.returncode == 1, output
    assert 'Traceback' not in output, output
    fatal = [line for line in output.splitlines() if '[FATAL]' in line]
    assert len(fatal) == 1 and message in fatal[0] and valid in fatal[0], output
