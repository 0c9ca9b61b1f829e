"""Closed loops on shipped BARN worlds: the default filter, both nominals, in PyBullet.

Worlds 13, 43 and 260 are the ones where the default left the safe set (some h < 0 with
the QP ``ok`` or on slack) before the braking check also tested the barrier along the way
to rest (``filter.braking_check_barrier``, doc/design.md 3.10); world 1 is the first.
"""
import pytest

from sim_bridge.barn import load_worlds, WORLDS_FILE
from sim_bridge.evaluation.barn_suite import run_world
from sim_bridge.launcher import default_barrier

WORLDS = (1, 13, 43, 260)


@pytest.fixture(scope='module')
def worlds():
    """Return the shipped worlds by number."""
    return {world.world: world for world in load_worlds(WORLDS_FILE)}


@pytest.mark.parametrize('number', WORLDS)
def test_the_default_reaches_the_goal_inside_the_safe_set(worlds, number):
    """Path and go-to-goal nominal: goal reached, no collision, h >= 0 at every step."""
    barrier = default_barrier('diff_drive')
    results = run_world(worlds[number], [(barrier, 'path'), (barrier, 'goal')])
    for record, _ in results:
        label = (number, record['nominal'], record['outcome'], record['deepest_h'])
        assert record['success'] and not record['collision'], label
        assert record['penetration_m'] == 0.0, label
        assert record['negative_h_rate'] == 0.0 and record['deepest_h'] >= 0.0, label


def test_without_the_barrier_test_world_43_leaves_the_safe_set(worlds):
    """The same run with clearance alone in the braking check: h < 0 on the way (no contact)."""
    barrier = default_barrier('diff_drive')
    (record, _), = run_world(worlds[43], [(barrier, 'goal')],
                             parameters={'filter.braking_check_barrier': False})
    assert not record['collision']
    assert record['deepest_h'] < 0.0 and record['negative_h_rate'] > 0.0
