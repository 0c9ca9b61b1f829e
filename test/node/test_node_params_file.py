"""Every shipped YAML loads with ``--params-file`` and the node reports the right model."""
import contextlib

import pytest
from diagnostic_msgs.msg import DiagnosticArray

from node_harness import diagnostic_values, Harness, REPO, running_filter

CONFIGS = {
    'quadruped': ('unicycle', '100'),
    'diff_drive': ('unicycle', '100'),
    'holonomic_base': ('point_mass_2d', '100'),
    'drone_velocity': ('point_mass_3d', '100'),
    'crazyflie_thrust': ('quadrotor', '500'),
    'nav2_safety_filter': ('unicycle', '100'),
    'jackal': ('unicycle', '100'),
}


def test_every_config_is_tested():
    """The table above covers every YAML in config/."""
    assert sorted(p.stem for p in (REPO / 'config').glob('*.yaml')) == sorted(CONFIGS)


@pytest.mark.slow
def test_shipped_configs_load_in_namespaces():
    """All four filters run at once, each in its own namespace; diagnostics show model and rate."""
    with contextlib.ExitStack() as stack:
        procs = {name: stack.enter_context(running_filter(
            '--params-file', str(REPO / 'config' / f'{name}.yaml'), '-r', f'__ns:=/{name}'))
            for name in CONFIGS}
        h = stack.enter_context(Harness())
        diagnostics = h.collect(DiagnosticArray, '/diagnostics')
        seen = {}

        def all_reported():
            for _, msg in diagnostics:
                for name in CONFIGS:
                    status, values = diagnostic_values(msg, f'/{name}/safety_filter')
                    if status is not None:
                        seen[name] = (status, values)
            return len(seen) == len(CONFIGS)

        assert h.spin_until(all_reported, 20.0), (
            sorted(seen), {n: p.log_path.read_text() for n, p in procs.items()})
        for name, (model, rate) in CONFIGS.items():
            status, values = seen[name]
            assert (status.hardware_id, values['model'], values['rate_target_hz']) == (
                model, model, rate), name
