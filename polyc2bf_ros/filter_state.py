"""``~/state``: what the filter did on its last step, as one ``diagnostic_msgs/DiagnosticStatus``.

``action`` of a step, first match wins (doc/safety_filter.md, "State")::

    disabled   ~/enable false (pass-through; also while a stale command makes it a stop)
    deadlock   the deadlock detector reports the robot held in place (``~/deadlock`` true)
    stop       the output is a stop: a watchdog stop (stale input), invalid input, rejected
               obstacles blocking, the filter's ``brake`` / ``backup`` / ``invalid_input``,
               or a filtered velocity command within ``STOP_TOLERANCE`` of zero
    fallback   the filter's ``slack`` or ``escape``
    pass       the filter ran and every component is within ``PASS_TOLERANCE`` of the nominal
    limit      the filter changed the command and still moves the robot

The classification is a few float comparisons per step (``classify``); the message, with
the distance to the closest obstacle (``closest_obstacle``), is built only when published.
"""
import math

import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus, KeyValue

from polyc2bf_ros.core.geometry.polygons import signed_distance_batch
from polyc2bf_ros.core.safety_filter import FilterStatus

ACTIONS = ('pass', 'limit', 'stop', 'fallback', 'deadlock', 'disabled')
PASS_TOLERANCE = 1e-6  # largest component change still called 'pass' (command units)
STOP_TOLERANCE = 1e-6  # a filtered velocity command this close to zero is a 'stop'
_STOPS = frozenset({FilterStatus.BRAKE, FilterStatus.BACKUP, FilterStatus.INVALID_INPUT})
_FALLBACKS = frozenset({FilterStatus.SLACK, FilterStatus.ESCAPE})
_LEVELS = {'pass': DiagnosticStatus.OK, 'limit': DiagnosticStatus.OK}


def classify(enabled, decision, nominal, velocity):
    """Return ``(action, status, active constraints)`` of one ``core.decision.Decision``.

    ``nominal``: the nominal command vector the step had; ``velocity``: the model takes
    velocity commands (a zero command is its stop).  Plain Python on a few numbers.
    """
    if decision.action == 'pass':
        return 'disabled', 'disabled', 0
    if decision.action == 'stop':
        return ('disabled' if not enabled else 'stop'), decision.reason, 0
    info = decision.info
    status, active = info.status, len(info.active)
    if decision.deadlocked:
        action = 'deadlock'
    elif status in _STOPS:
        action = 'stop'
    elif status in _FALLBACKS:
        action = 'fallback'
    elif nominal is not None and all(abs(float(a) - float(b)) <= PASS_TOLERANCE
                                     for a, b in zip(nominal, decision.command)):
        action = 'pass'
    elif velocity and all(abs(float(c)) <= STOP_TOLERANCE for c in decision.command):
        action = 'stop'
    else:
        action = 'limit'
    return action, status.value, active


def closest_obstacle(position, obstacles):
    """Return the signed distance [m] from ``position`` to the nearest obstacle part.

    Distance in the plane to the part's footprint as last received (odometry frame, not
    extrapolated, not inflated by ``robot_radius``; negative inside; z ignored); NaN
    without a position or obstacles.
    """
    if position is None or len(obstacles) == 0:
        return math.nan
    point = np.asarray(position, dtype=np.float64)[:2]
    if not np.all(np.isfinite(point)):
        return math.nan
    return float(np.min(signed_distance_batch(point, obstacles.footprints)))


def state_status(name, hardware_id, action, status, active, closest, deadlocked):
    """Return the ``DiagnosticStatus`` of ``~/state`` (level OK for pass / limit, else WARN)."""
    values = {
        'action': action,
        'closest_obstacle_m': 'nan' if math.isnan(closest) else f'{closest:.4f}',
        'active_constraints': str(active),
        'status': status,
        'deadlocked': str(bool(deadlocked)).lower(),
    }
    return DiagnosticStatus(
        level=_LEVELS.get(action, DiagnosticStatus.WARN), name=name, message=action,
        hardware_id=hardware_id, values=[KeyValue(key=k, value=v) for k, v in values.items()])
