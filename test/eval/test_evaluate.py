"""``evaluate`` on a tiny subset: outputs, keys, table, findings, plots, progress."""
import contextlib
import io
import json

import pytest
from PIL import Image

from sim_bridge.evaluation.cli import main
from sim_bridge.evaluation.records import KEYS
from sim_bridge.evaluation.scenario_suite import plan_runs


def test_plan_runs_seeds_only_random_scenarios():
    """A random scenario runs per seed, a fixed one once per filter."""
    plan = plan_runs(['cluttered', 'long_wall'], ['c3bf', 'none'])
    assert sorted({(s.name, s.seed) for s, _ in plan}) == [
        ('cluttered', 7), ('cluttered', 8), ('cluttered', 9), ('long_wall', 0)]
    assert len(plan) == 8
    chosen = plan_runs(['cluttered'], ['none'], seeds=[3, 5], duration=2.0)
    assert [(s.seed, s.duration) for s, _ in chosen] == [(3, 2.0), (5, 2.0)]


@pytest.fixture(scope='module')
def tiny(tmp_path_factory):
    """Run ``evaluate`` on long_wall (6 s) with C3BF and PolyC2BF; return (out dir, stderr)."""
    out = tmp_path_factory.mktemp('eval')
    stderr = io.StringIO()
    with contextlib.redirect_stderr(stderr), contextlib.redirect_stdout(io.StringIO()):
        status = main(['--scenarios', 'long_wall', '--filters', 'c3bf', 'polyc2bf_inflated',
                       '--duration', '6', '--out', str(out)])
    assert status == 0
    return out, stderr.getvalue()


def test_results_json_has_the_design_keys(tiny):
    """One record per run with the result-record keys of doc/design.md; values from the run."""
    out, _ = tiny
    records = json.loads((out / 'results.json').read_text())
    assert [r['filter'] for r in records] == ['c3bf', 'polyc2bf_inflated']
    for record in records:
        assert set(KEYS) <= set(record) and record['scenario'] == 'long_wall'
        assert record['latency_p50_us'] > 0 and record['latency_p99_us'] >= \
            record['latency_p50_us']
        assert record['steps'] == 6 * 120
    c3bf, poly = records
    assert not c3bf['success'] and c3bf['fallback_at_start'] and c3bf['fallback_rate'] > 0.5
    assert not poly['collision'] and not poly['fallback_at_start']
    assert poly['robots']['a1']['reference_time_to_goal_s'] > 5.0


def test_results_md_table_and_findings(tiny):
    """The Markdown has the table rows and findings drawn from the records."""
    out, _ = tiny
    text = (out / 'results.md').read_text()
    assert '| scenario | filter | obstacles | success | collision |' in text
    assert '| long_wall | c3bf | markers | 0/1 | 0/1 | 0/1 | 1/1 | 1/1 |' in text  # timeout, 6 s
    assert '| long_wall | polyc2bf_inflated | markers |' in text
    assert 'Obstacles: markers.' in text
    assert 'polyc2bf_inflated: zero collisions in 1 runs over 1 scenarios.' in text
    assert 'c3bf on long_wall: fails in 1/1 runs' in text


def test_plots_and_progress(tiny):
    """Both PNGs are valid images; the progress bar reported an ETA and finished at 100 %."""
    out, stderr = tiny
    for name in ('trajectories.png', 'metrics.png'):
        with Image.open(out / name) as image:
            assert image.format == 'PNG' and min(image.size) > 300
    assert 'ETA' in stderr and '100.0 %' in stderr
    assert 'long_wall (obstacle-free reference)' in stderr


def test_bad_arguments_exit_2(capsys):
    """Unknown scenarios and non-positive durations are refused with a message."""
    for argv in (['--scenarios', 'atlantis'], ['--duration', '0']):
        with pytest.raises(SystemExit) as exit_info:
            main(argv)
        assert exit_info.value.code == 2
    assert 'unknown scenario(s) atlantis' in capsys.readouterr().err


def test_scan_mode_records_and_lidar_settings(tmp_path):
    """--obstacle-source scan: every record says so and carries the --lidar settings."""
    with contextlib.redirect_stderr(io.StringIO()), contextlib.redirect_stdout(io.StringIO()):
        assert main(['--scenarios', 'long_wall', '--filters', 'polyc2bf_inflated',
                     '--duration', '2', '--obstacle-source', 'scan', '--lidar', 'beams=180',
                     '--lidar', 'mount=[0.1, 0, 0]', '--no-plots', '--out', str(tmp_path)]) == 0
    record, = json.loads((tmp_path / 'results.json').read_text())
    assert record['obstacle_source'] == 'scan' and record['steps'] == 2 * 120
    assert record['lidar']['beams'] == 180 and record['lidar']['mount'] == [0.1, 0, 0]
    text = (tmp_path / 'results.md').read_text()
    assert '| long_wall | polyc2bf_inflated | scan |' in text
    assert 'Obstacles: scan (lidar beams 180' in text


@pytest.mark.parametrize('arguments, message', [
    (['--lidar', 'beams=180'], '--lidar needs --obstacle-source scan'),
    (['--obstacle-source', 'scan', '--lidar', 'colour=red'], 'FIELD one of beams'),
    (['--obstacle-source', 'scan', '--lidar', 'beams=0'], 'LidarSettings.beams must be'),
    (['--obstacle-source', 'lidar'], "invalid choice: 'lidar'"),
])
def test_bad_lidar_arguments_exit_2(capsys, arguments, message):
    """Lidar options are checked before anything runs."""
    with pytest.raises(SystemExit) as exited:
        main(['--scenarios', 'long_wall', *arguments])
    assert exited.value.code == 2 and message in capsys.readouterr().err
