"""``filter_state``: the action precedence and the closest-obstacle distance, without ROS."""
import math

import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus

from polyc2bf_ros.core.decision import Decision
from polyc2bf_ros.core.obstacles.obstacle_set import Obstacle, ObstacleSet
from polyc2bf_ros.core.safety_filter import FilterInfo, FilterStatus
from polyc2bf_ros.filter_state import classify, closest_obstacle, state_status


def _filtered(status, safe, active=(), deadlocked=False):
    info = FilterInfo(status=status, active=np.array(active, dtype=int))
    return Decision('filter', np.array(safe, dtype=float), info, deadlocked=deadlocked)


def test_actions_follow_the_documented_precedence():
    """Precedence: disabled > deadlock > stop > fallback > pass / limit."""
    nominal = (0.5, 0.1)
    assert classify(False, Decision('pass'), nominal, True) == ('disabled', 'disabled', 0)
    assert classify(False, Decision('stop', reason='stale_stop'), nominal, True)[0] == 'disabled'
    assert classify(True, Decision('stop', reason='stale_stop'), nominal, True) == (
        'stop', 'stale_stop', 0)
    held = _filtered(FilterStatus.BRAKE, (0.0, 0.0), (0,), deadlocked=True)
    assert classify(True, held, nominal, True)[0] == 'deadlock'
    assert classify(True, _filtered(FilterStatus.BACKUP, (0.1, 0.0)), nominal, True)[0] == 'stop'
    assert classify(True, _filtered(FilterStatus.SLACK, (0.1, 0.0)), nominal, True)[0] == \
        'fallback'
    assert classify(True, _filtered(FilterStatus.ESCAPE, (-0.1, 0.0)), nominal, True)[0] == \
        'fallback'
    assert classify(True, _filtered(FilterStatus.OK, (0.5, 0.1 + 1e-9)), nominal, True) == (
        'pass', 'ok', 0)
    assert classify(True, _filtered(FilterStatus.OK, (0.2, 0.1), (0, 2)), nominal, True) == (
        'limit', 'ok', 2)
    assert classify(True, _filtered(FilterStatus.OK, (0.0, 0.0), (0,)), nominal, True)[0] == \
        'stop'
    # A wrench of zeros is no stop for the quadrotor (its stop is the hover wrench).
    assert classify(True, _filtered(FilterStatus.OK, (0.0,) * 4), (1.0,) * 4, False)[0] == \
        'limit'


def test_closest_obstacle_is_the_signed_footprint_distance():
    """Nearest part's face; negative inside; NaN without obstacles or position."""
    square = np.array([[2.0, -1.0], [3.0, -1.0], [3.0, 1.0], [2.0, 1.0]])
    far = square + (10.0, 0.0)
    obstacles = ObstacleSet.from_obstacles([Obstacle(polygon=far), Obstacle(polygon=square)])
    assert math.isclose(closest_obstacle((0.5, 0.0), obstacles), 1.5)
    assert closest_obstacle((2.5, 0.0, 1.0), obstacles) < 0.0
    assert math.isnan(closest_obstacle((0.0, 0.0), ObstacleSet.empty()))
    assert math.isnan(closest_obstacle(None, obstacles))


def test_status_message_carries_the_documented_keys():
    """Name, message = action, level by action, the five keys."""
    status = state_status('/sf: state', 'unicycle', 'limit', 'ok', 2, 1.23456, False)
    values = {kv.key: kv.value for kv in status.values}
    assert status.name == '/sf: state' and status.message == 'limit'
    assert status.level == DiagnosticStatus.OK
    assert values == {'action': 'limit', 'closest_obstacle_m': '1.2346',
                      'active_constraints': '2', 'status': 'ok', 'deadlocked': 'false'}
    status = state_status('/sf: state', 'unicycle', 'stop', 'stale_stop', 0, math.nan, False)
    assert status.level == DiagnosticStatus.WARN
    assert {kv.key: kv.value for kv in status.values}['closest_obstacle_m'] == 'nan'
