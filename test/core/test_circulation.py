"""``Circulation``: the side it latches, the tangent command, release and flip."""
import math
from types import SimpleNamespace

import numpy as np
import pytest

from polyc2bf_ros.core.barrier.cones import PLANE_CONES, PLANE_ROWS
from polyc2bf_ros.core.liveness.circulation import Circulation
from polyc2bf_ros.core.safety_filter import Evaluation


def evaluation_with_axes(axes, valid):
    """Return an ``Evaluation`` whose parts' cone axes p are the columns of ``axes`` (2, N)."""
    axes = np.array(axes, dtype=float).reshape(2, -1)
    block = np.zeros((PLANE_ROWS + 4, axes.shape[1]))
    block[PLANE_CONES][0:2] = axes
    valid = np.array(valid)
    return Evaluation(block=block, valid=valid, usable=valid, vertical=None, viewpoints=())


def info_with_axis(axis, h=0.1):
    """Return a FilterInfo stand-in: one valid part, cone axis ``axis``, barrier value ``h``."""
    return SimpleNamespace(h=np.array([h]), evaluation=evaluation_with_axes(axis, [True]))


@pytest.mark.parametrize('yaw, side', [(0.3, 1), (-0.3, -1), (0.0, 1)])
def test_the_side_is_the_one_the_heading_already_lies_on(yaw, side):
    """Obstacle straight ahead along +x: heading a bit left -> left, right -> right."""
    circulation = Circulation()
    circulation.observe(info_with_axis((1.0, 0.0)))
    circulation.engage(0.0, (0.0, 0.0), yaw, (0.8, 0.0))
    assert circulation.side == side and circulation.engagements == 1


def test_the_command_turns_to_the_tangent_then_drives_along_it():
    """Facing the obstacle: turn in place toward the tangent; aligned with it: full speed."""
    circulation = Circulation(turn_gain=2.0, max_turn_rate=1.5)
    circulation.observe(info_with_axis((1.0, 0.0)))
    circulation.engage(0.0, (0.0, 0.0), 0.1, (0.8, 0.0))   # left: tangent along +y
    v, omega = circulation.command(0.0, (0.8, 0.0))
    assert v == pytest.approx(0.0, abs=1e-12) and omega == 1.5
    v, omega = circulation.command(math.pi / 2, (0.8, 0.0))
    assert v == pytest.approx(0.8) and omega == pytest.approx(0.0, abs=1e-12)
    v, omega = circulation.command(math.pi / 2 - 0.2, (-0.9, 0.3))  # speed is |v|
    assert v == pytest.approx(0.9 * math.cos(0.2)) and omega == pytest.approx(0.4)


def test_the_speed_reported_with_the_deadlock_is_kept_when_the_nominal_drops_it():
    """A go-to-goal law asks v = 0 with the goal 90 degrees off: circulation keeps going."""
    circulation = Circulation()
    circulation.observe(info_with_axis((1.0, 0.0)))
    circulation.engage(0.0, (0.0, 0.0), 0.1, (0.7, 0.0))
    v, omega = circulation.command(math.pi / 2, (0.0, -1.5))
    assert v == pytest.approx(0.7) and omega == pytest.approx(0.0, abs=1e-12)
    circulation.engage(1.0, (0.0, 0.0), math.pi / 2, (0.2, 0.0))  # flipped: keeps 0.7
    assert circulation.side == -1
    v, _ = circulation.command(-math.pi / 2, (0.0, 1.5))
    assert v == pytest.approx(0.7)


def test_not_circulating_or_a_nominal_stop_passes_the_nominal_through():
    """Before engaging, and for a zero nominal speed, the nominal is returned as it is."""
    circulation = Circulation()
    nominal = np.array([0.8, 0.2])
    assert circulation.command(0.0, nominal) is nominal
    circulation.observe(info_with_axis((1.0, 0.0)))
    circulation.engage(0.0, (0.0, 0.0), 0.0, (0.8, 0.0))
    stop = np.array([0.0, 0.0])
    assert circulation.command(0.0, stop) is stop


def test_release_once_the_nominal_is_free_or_after_the_time_and_flip_on_a_second_report():
    """Released past release_distance once the filter would pass the probe, or on time."""
    circulation = Circulation(release_distance=1.0, max_time=10.0)
    circulation.observe(info_with_axis((1.0, 0.0)))
    circulation.engage(0.0, (0.0, 0.0), 0.1, (0.8, 0.0))
    circulation.engage(1.0, (0.0, 0.0), 0.1, (0.8, 0.0))
    assert circulation.side == -1 and circulation.engagements == 2
    asked = []

    def passes():
        asked.append(True)
        return True

    circulation.release_if_done(2.0, (0.0, 0.9), passes)
    assert circulation.active and not asked          # not far enough: the filter not asked
    circulation.release_if_done(2.0, (0.0, 1.0), lambda: False)
    assert circulation.active                        # the filter would hold it: keep going
    circulation.release_if_done(2.0, (0.0, 1.0), passes)
    assert not circulation.active and asked
    circulation.engage(3.0, (0.0, 0.0), 0.1, (0.8, 0.0))
    circulation.release_if_done(13.0, (0.0, 0.0), lambda: False)
    assert not circulation.active                    # max_time
    circulation.engage(13.0, (0.0, 0.0), 0.1, (0.8, 0.0), renew=True)
    assert circulation.side == -1                    # still held: the other side (was +1)


def test_the_probe_drives_on_where_the_nominal_turns():
    """A nominal turning in place is probed at half the held speed, its turn kept."""
    circulation = Circulation()
    circulation.observe(info_with_axis((1.0, 0.0)))
    circulation.engage(0.0, (0.0, 0.0), 0.1, (0.8, 0.0))
    assert circulation.probe((0.0, -1.5)) == pytest.approx([0.4, -1.5])
    assert circulation.probe((0.9, 0.2)) == pytest.approx([0.9, 0.2])
    assert circulation.probe((-0.1, 0.0)) == pytest.approx([-0.4, 0.0])


def test_the_axis_comes_from_the_last_step_with_parts_idle_and_every_step_circulating():
    """Idle, engage takes the axis of the last info with parts; circulating, each step's.

    Side +1 about an axis p drives along (p_x, -p_y) turned: p = +x leads along +y (heading
    pi/2: straight on), p = +y along -x (heading pi/2: turn at the limit).
    """
    circulation = Circulation()
    circulation.observe(info_with_axis((0.0, 1.0)))
    circulation.observe(info_with_axis((1.0, 0.0)))
    circulation.observe(SimpleNamespace(h=np.empty(0), evaluation=evaluation_with_axes(
        np.empty((2, 0)), np.empty(0, dtype=bool))))          # no parts: changes nothing
    circulation.engage(0.0, (0.0, 0.0), 0.3, (0.8, 0.0))
    assert circulation.side == 1
    assert circulation.command(0.5 * math.pi, (0.8, 0.0)) == pytest.approx([0.8, 0.0])
    circulation.observe(info_with_axis((0.0, 1.0)))           # circulating: taken at once
    assert circulation.command(0.5 * math.pi, (0.8, 0.0)) == pytest.approx([0.0, 1.5],
                                                                           abs=1e-9)


def test_without_a_valid_cone_nothing_is_engaged():
    """No cone seen (inside, or no obstacles): engaging does nothing."""
    circulation = Circulation()
    circulation.observe(SimpleNamespace(h=np.array([np.nan]),
                                        evaluation=evaluation_with_axes((0.0, 0.0), [False])))
    circulation.engage(0.0, (0.0, 0.0), 0.0, (0.8, 0.0))
    assert not circulation.active


def test_bad_settings_are_refused():
    """Every setting must be positive."""
    with pytest.raises(ValueError):
        Circulation(release_distance=0.0)
