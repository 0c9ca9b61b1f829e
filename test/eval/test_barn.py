"""BARN suite: the world file loader, the protocol's metric and referee, and ``evaluate``."""
import contextlib
import io
import json
from types import SimpleNamespace

import numpy as np
import pytest
from PIL import Image

from sim_bridge import barn
from sim_bridge.evaluation.barn_suite import BARN_KEYS, run_world
from sim_bridge.evaluation.cli import main

START, GOAL = [-2.25, 3.0, 1.57], [-2.25, 13.0]
# A row of touching cylinders across the straight line from start to goal, and a path
# around its right end.
ROW = [[-3.6 + 0.15 * i, 6.0] for i in range(17)]
DETOUR = [[-2.25, 3.0], [-0.75, 5.0], [-0.75, 7.0], [-2.25, 9.0], [-2.25, 13.0]]


def _world(number=1, **changes):
    """Return world ``number`` in the BARN format: the blocking row and the detour."""
    length = float(np.sum(np.linalg.norm(np.diff(DETOUR, axis=0), axis=1)))
    data = {'world': number, 'cylinder_radius': 0.075, 'start': START, 'goal': GOAL,
            'reference_path_length_m': length, 'reference_path': DETOUR, 'centers': ROW}
    data.update(changes)
    return data


def _write(tmp_path, worlds, name='worlds.json'):
    path = tmp_path / name
    path.write_text(json.dumps({'source': 'made by the test', 'worlds': worlds}))
    return path


def test_the_shipped_file_loads_with_its_licence_and_citation():
    """200 worlds, BARN's start and goal; the MIT notice and the citation sit beside it."""
    worlds = barn.load_worlds(barn.WORLDS_FILE)
    assert len(worlds) == 200 and len({w.world for w in worlds}) == 200
    for world in worlds:
        np.testing.assert_allclose(world.start, [-2.25, 3.0, 1.57])
        np.testing.assert_allclose(world.goal, [-2.25, 13.0])
        assert world.centers.shape[1] == 2 and world.reference_path.shape[1] == 2
    assert 'MIT License' in (barn.WORLDS_FILE.parent / 'LICENSE').read_text()
    citation = (barn.WORLDS_FILE.parent / 'README.md').read_text()
    assert 'Benchmarking Metric Ground Navigation' in citation


@pytest.mark.parametrize('changes, message', [
    ({'centers': [[-3.0, 6.0], [1.0, 2.0, 3.0]]},
     'world 7 (worlds[1]): centers[1]: expected 2 numbers [x, y], got 3'),
    ({'cylinder_radius': -0.1}, 'world 7 (worlds[1]): cylinder_radius: must be > 0'),
    ({'reference_path': [[0.0, 0.0]]},
     'world 7 (worlds[1]): reference_path: expected >= 2 points [x, y], got 1'),
    ({'start': 'south'}, 'world 7 (worlds[1]): start: expected a list of 3 numbers'),
    ({'goal': [-2.25, float('nan')]}, 'world 7 (worlds[1]): goal[1]: expected a finite number'),
    ({'reference_path_length_m': None}, 'world 7 (worlds[1]): reference_path_length_m: '
     'expected a number'),
    ({'world': 1}, 'worlds[1].world: world 1 appears twice'),
    ({'world': 'seven'}, "worlds[1]: world: expected a whole number >= 0, got 'seven'"),
])
def test_a_malformed_world_is_refused_naming_world_and_field(tmp_path, changes, message):
    """Each broken field of the second world is named with the world's id and place."""
    path = _write(tmp_path, [_world(1), _world(7, **changes)])
    with pytest.raises(barn.BarnError) as error:
        barn.load_worlds(path)
    assert str(error.value).startswith(f'{path}: ') and message in str(error.value)


def test_a_missing_field_and_a_bad_document_are_refused(tmp_path):
    """A missing field is named; so are a file that is not JSON and one without worlds."""
    world = _world(3)
    del world['centers']
    with pytest.raises(barn.BarnError, match=r'world 3 \(worlds\[0\]\): centers: missing'):
        barn.load_worlds(_write(tmp_path, [world]))
    (tmp_path / 'broken.json').write_text('{"worlds": [')
    with pytest.raises(barn.BarnError, match='not valid JSON'):
        barn.load_worlds(tmp_path / 'broken.json')
    with pytest.raises(barn.BarnError, match='worlds: expected a non-empty list'):
        barn.load_worlds(_write(tmp_path, []))


def test_a_start_against_a_cylinder_is_refused_when_the_world_is_built(tmp_path):
    """The world's Scenario is checked like a scenario file: the message names the world."""
    (world,) = barn.load_worlds(_write(tmp_path, [_world(4, centers=[[-2.25, 3.1]])]))
    with pytest.raises(barn.BarnError, match=r"world 4: robots\[0\].start: .* from obstacle "
                       r"'cylinder_0', less than the robot radius 0.2"):
        world.scenario()


def test_other_keys_are_accepted(tmp_path):
    """A converted file may carry more than the format reads."""
    (world,) = barn.load_worlds(_write(tmp_path, [_world(5, difficulty=0.3)]))
    assert world.world == 5 and world.name == 'barn_005'
    assert world.optimal_time == pytest.approx(world.reference_path_length_m / 2.0)


@pytest.mark.parametrize('success, time, optimal, expected', [
    (True, 10.0, 4.0, 0.4),          # OT / T inside [2 OT, 8 OT]
    (True, 5.0, 4.0, 0.5),           # faster than 2 OT: clipped to 2 OT, the maximum
    (True, 8.0, 4.0, 0.5),           # exactly 2 OT
    (True, 40.0, 4.0, 0.125),        # slower than 8 OT: clipped to 8 OT
    (True, 32.0, 4.0, 0.125),        # exactly 8 OT
    (False, 10.0, 4.0, 0.0),         # a failure scores 0
])
def test_barn_metric_by_hand(success, time, optimal, expected):
    """The metric is success * OT / clip(T, 2 OT, 8 OT)."""
    assert barn.barn_metric(success, time, optimal) == pytest.approx(expected)


def _referee_inputs(position, collision=False):
    """Return stand-ins for the world and metrics the referee reads: the base at ``position``."""
    world = SimpleNamespace(robot_state=lambda name: np.array([*position, 0.0, 0.0, 0.0]),
                            robot_spec=lambda name: SimpleNamespace(goal=np.array(GOAL)))
    metrics = SimpleNamespace(robots={barn.ROBOT_NAME: SimpleNamespace(collision=collision)})
    return world, metrics


def test_referee_ends_runs_on_collision_goal_and_a_stop():
    """Collision first; within 1 m of the goal; 10 s within 0.1 m of one point; else go on."""
    referee = barn.BarnReferee()
    assert referee(0.1, *_referee_inputs([-2.25, 12.1], collision=True)) == 'collision'
    assert referee(0.1, *_referee_inputs([-2.25, 12.1])) == 'success'
    referee = barn.BarnReferee()
    assert referee(1.0, *_referee_inputs([-2.25, 5.0])) is None
    assert referee(10.9, *_referee_inputs([-2.2, 5.05])) is None
    assert referee(11.0, *_referee_inputs([-2.2, 5.05])) == 'deadlock'
    referee = barn.BarnReferee()
    for step in range(200):  # creeping 0.02 m/s: it moves, so it is no deadlock
        assert referee(0.1 * step, *_referee_inputs([-2.25, 5.0 + 0.002 * step])) is None


@pytest.fixture(scope='module')
def blocked(tmp_path_factory):
    """Run ``evaluate --suite barn`` without a filter, both nominals, on the blocked world."""
    tmp_path = tmp_path_factory.mktemp('barn')
    worlds = _write(tmp_path, [_world(1), _world(2, centers=ROW[:-2])])
    out = tmp_path / 'out'
    stderr, stdout = io.StringIO(), io.StringIO()
    with contextlib.redirect_stderr(stderr), contextlib.redirect_stdout(stdout):
        status = main(['--suite', 'barn', '--worlds', str(worlds), '--filters', 'none',
                       '--nominal', 'path', 'goal', '--jobs', '1', '--out', str(out)])
    assert status == 0, stderr.getvalue()
    return out, worlds, stderr.getvalue(), stdout.getvalue()


def test_path_nominal_follows_the_detour_and_goal_nominal_hits_the_row(blocked):
    """Without a filter: pure pursuit along the path succeeds, go-to-goal collides."""
    out, _, _, _ = blocked
    records = json.loads((out / 'results.json').read_text())
    assert [(r['world'], r['nominal']) for r in records] == [
        (1, 'path'), (1, 'goal'), (2, 'path'), (2, 'goal')]
    for record in records:
        assert set(BARN_KEYS) <= set(record) and record['suite'] == 'barn'
        assert record['filter'] == 'none' and record['mean_intervention'] is None
        outcomes = [record[key] for key in ('success', 'collision', 'timeout', 'deadlock')]
        assert sum(outcomes) == 1
        if record['nominal'] == 'path':
            assert record['success'] and record['min_clearance_m'] > 0.0
            assert record['final_distance_m'] <= 1.0 and record['final_gap_m'] > 0.0
            assert record['barn_metric'] == pytest.approx(
                record['optimal_time_s'] / max(record['time_s'], 2 * record['optimal_time_s']),
                abs=1e-4)
        else:
            assert record['collision'] and record['barn_metric'] == 0.0
            assert record['min_clearance_m'] < 0.0 and record['time_s'] < 5.0
            assert record['final_gap_m'] == pytest.approx(record['min_clearance_m'], abs=2e-3)
            assert record['final_position'][1] < 6.0


def test_results_md_plots_and_progress(blocked):
    """The table has a row per filter x nominal and DWA's; the PNGs are images; one bar."""
    out, worlds, stderr, stdout = blocked
    text = (out / 'results.md').read_text()
    assert '| none | path | markers | 2 | 1.000 | 0.000 | 0.000 | 0.000 |' in text
    assert '| none | goal | markers | 2 | 0.000 | 1.000 | 0.000 | 0.000 | 0.000 |' in text
    assert '| DWA (move_base, BARN) | – | – | 50 x 10 runs | 0.880 | 0.048 |' in text
    assert str(worlds) in text and '| none | path |' in stdout
    for name in ('outcomes.png', 'trajectories.png', 'metric_histogram.png'):
        with Image.open(out / name) as image:
            assert image.format == 'PNG' and min(image.size) > 300
    assert stderr.count('100.0 %') == 1 and 'world 2' in stderr


def test_parallel_runs_give_the_same_records(blocked, tmp_path):
    """Two processes, the limit and the default filter: the same numbers as one process."""
    out, worlds, _, _ = blocked
    with contextlib.redirect_stderr(io.StringIO()), contextlib.redirect_stdout(io.StringIO()):
        assert main(['--suite', 'barn', '--worlds', str(worlds), '--filters', 'none',
                     '--nominal', 'path', '--jobs', '2', '--limit', '2', '--no-plots',
                     '--out', str(tmp_path)]) == 0
    serial = [r for r in json.loads((out / 'results.json').read_text())
              if r['nominal'] == 'path']
    parallel = json.loads((tmp_path / 'results.json').read_text())
    drop = ('wall_time_s', 'latency_p50_us', 'latency_p99_us')
    assert [{k: v for k, v in r.items() if k not in drop} for r in parallel] == \
        [{k: v for k, v in r.items() if k not in drop} for r in serial]
    assert not (tmp_path / 'outcomes.png').exists()


def test_bad_barn_arguments_exit_2(tmp_path, capsys):
    """Options of the other suite, a bad job count and a malformed file are refused."""
    broken = _write(tmp_path, [_world(9, centers=[[0.0]])])
    for argv in (['--suite', 'barn', '--seeds', '1'], ['--suite', 'barn', '--jobs', '0'],
                 ['--suite', 'barn', '--worlds', str(broken)], ['--limit', '3']):
        with pytest.raises(SystemExit) as exit_info:
            main(argv)
        assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert '--seeds belong(s) to --suite scenarios' in err and '--jobs must be >= 1' in err
    assert 'world 9 (worlds[0]): centers[0]: expected 2 numbers [x, y], got 1' in err
    assert '--limit belong(s) to --suite barn' in err


def test_scan_mode_goal_nominal_keeps_clear_of_the_row_it_sees_by_lidar(tmp_path):
    """The default filter fed by the lidar alone: go-to-goal no longer hits the row."""
    worlds, out = _write(tmp_path, [_world()]), tmp_path / 'out'
    with contextlib.redirect_stderr(io.StringIO()), contextlib.redirect_stdout(io.StringIO()):
        assert main(['--suite', 'barn', '--worlds', str(worlds), '--nominal', 'goal',
                     '--jobs', '1', '--obstacle-source', 'scan', '--no-plots',
                     '--out', str(out)]) == 0
    record, = json.loads((out / 'results.json').read_text())
    assert record['obstacle_source'] == 'scan' and record['lidar']['beams'] == 360
    assert not record['collision'] and record['min_clearance_m'] > 0.0
    assert record['mean_intervention'] > 0.0
    text = (out / 'results.md').read_text()
    assert '| goal | scan | 1 |' in text and 'Obstacles: scan (lidar beams 360' in text


def test_a_standing_row_of_posts_gets_no_velocity_from_the_scan_tracker():
    """A shipped world whose rows of posts match themselves shifted by a post.

    Before the tracker tested rest (``core/obstacles/scan_tracker.py``, step 3) a standing row here
    got 2.4 m/s, and go-to-goal from the scan drove into it.  Evasion is off, for it steers
    clear of a phantom that moves.
    """
    world, = [w for w in barn.load_worlds(barn.WORLDS_FILE) if w.world == 275]
    (record, _), = run_world(world, [('polyc2bf_horizon', 'goal')], obstacle_source='scan',
                             parameters={'filter.evasion_horizon': 0.0})
    assert record['success'] and not record['collision'], record
    assert record['min_clearance_m'] > 0.0
