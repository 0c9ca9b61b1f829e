"""``DeadlockDetector``: held in place by the filter for T within R, on given times."""
import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from polyc2bf_ros.core.liveness.deadlock import DeadlockDetector, holds, MIN_INTERVENTION
from polyc2bf_ros.core.safety_filter import FilterInfo, FilterStatus
from strategies import examples


def run(detector, steps, dt=0.01):
    """Feed ``[(position, holding)]`` at ``dt`` apart from t = 0; return the verdicts."""
    return [detector.update(k * dt, p, h) for k, (p, h) in enumerate(steps)]


def test_deadlocked_exactly_after_the_time_held_in_place():
    """Held at one point: False until T has passed since the first held step, then True."""
    verdicts = run(DeadlockDetector(1.0, 0.1), [((0.0, 0.0), True)] * 150)
    assert verdicts.index(True) == 100 and all(verdicts[100:])


def test_creeping_slower_than_radius_over_time_is_a_deadlock_faster_is_not():
    """R / T = 0.1 m/s: 0.05 m/s counts as standing, 0.2 m/s re-anchors for ever."""
    for speed, expected in ((0.05, True), (0.2, False)):
        steps = [((speed * 0.01 * k, 0.0), True) for k in range(300)]
        assert any(run(DeadlockDetector(1.0, 0.1), steps)) is expected


def test_a_step_that_does_not_hold_starts_the_count_again():
    """One free step in the middle: the deadlock comes T after it, counted once."""
    detector = DeadlockDetector(1.0, 0.1)
    steps = [((0.0, 0.0), True)] * 80 + [((0.0, 0.0), False)] + [((0.0, 0.0), True)] * 120
    verdicts = run(detector, steps)
    assert verdicts.index(True) == 81 + 100 and detector.onsets == 1


def test_each_new_deadlock_is_counted():
    """Deadlock, freed, deadlock again: two onsets."""
    detector = DeadlockDetector(0.5, 0.1)
    run(detector, ([((0.0, 0.0), True)] * 60 + [((0.0, 0.0), False)]) * 2)
    assert detector.onsets == 2


def test_holding_means_the_filter_acted_and_changed_the_command():
    """Acted and changed the command: holds; unconstrained, or changed too little: not.

    Too little: by at most MIN_INTERVENTION in every component.
    """
    nominal, held_back, kept = (0.8, 0.0), (0.1, 0.0), (0.8 - 0.5 * MIN_INTERVENTION, 0.0)
    assert holds(FilterInfo(FilterStatus.OK, active=np.array([3])), nominal, held_back)
    assert not holds(FilterInfo(FilterStatus.OK, active=np.array([3])), nominal, kept)
    assert not holds(FilterInfo(FilterStatus.OK), nominal, held_back)
    for status in (FilterStatus.SLACK, FilterStatus.BRAKE, FilterStatus.ESCAPE):
        assert holds(FilterInfo(status), nominal, held_back)


@pytest.mark.parametrize('time_s, radius_m', [(0.0, 0.1), (-1.0, 0.1), (math.inf, 0.1),
                                              (1.0, -0.1), (1.0, math.nan)])
def test_bad_thresholds_are_refused(time_s, radius_m):
    """T must be positive and finite, R non-negative and finite; T_s, R_s >= 0, finite."""
    with pytest.raises(ValueError):
        DeadlockDetector(time_s, radius_m)
    with pytest.raises(ValueError):
        DeadlockDetector(1.0, 0.1, stuck_time_s=time_s if time_s < 0 or math.isinf(time_s)
                         else -1.0, stuck_radius_m=1.0)


@settings(max_examples=examples(200), deadline=None)
@given(st.lists(st.tuples(st.floats(-0.3, 0.3), st.floats(-0.3, 0.3), st.booleans(),
                          st.floats(0.001, 0.2)), min_size=1, max_size=120),
       st.floats(0.05, 1.0), st.floats(0.0, 0.3))
def test_a_verdict_always_rests_on_a_held_window(steps, time_s, radius_m):
    """Whenever it says deadlocked, every step of the last T s held, within 2R of each other.

    (Within R of one anchor, so within 2R pairwise.)  And a robot held at one point for
    longer than T plus one step is always reported.
    """
    detector = DeadlockDetector(time_s, radius_m)
    now, history = 0.0, []
    for x, y, holding, dt in steps:
        now += dt
        history.append((now, np.array([x, y]), holding))
        if detector.update(now, (x, y), holding):
            window = [(p, h) for t, p, h in history if t >= now - time_s]
            assert all(h for _, h in window)
            assert all(np.linalg.norm(p - q) <= 2.0 * radius_m + 1e-12
                       for p, _ in window for q, _ in window)
    held = DeadlockDetector(time_s, radius_m)
    verdicts = [held.update(k * 0.01, (0.1, 0.2), True)
                for k in range(int(time_s / 0.01) + 2)]
    assert verdicts[-1]


def _circle(count, radius, nominal=(1.0, 0.0), dt=0.01, speed=0.5):
    """Return steps of a body circling at ``speed`` on a circle of ``radius``, never held."""
    return [(k * dt, (radius * math.cos(speed * k * dt / radius),
                      radius * math.sin(speed * k * dt / radius)), nominal)
            for k in range(count)]


def _track(detector, steps):
    """Feed ``[(time, body, nominal)]`` to ``track`` then ``update`` (not held)."""
    verdicts = []
    for now, body, nominal in steps:
        detector.track(now, body, nominal)
        verdicts.append(detector.update(now, None, False))
    return verdicts


def test_circling_within_the_stuck_radius_is_reported_after_the_stuck_time():
    """Never held, but round and round within R_s: a deadlock from T_s on, not before."""
    detector = DeadlockDetector(1.0, 0.1, stuck_time_s=5.0, stuck_radius_m=1.0)
    verdicts = _track(detector, _circle(800, 0.4))
    assert verdicts.index(True) == 500 and all(verdicts[500:])
    assert detector.stuck_onsets == 1 and detector.onsets == 0


def test_driving_away_or_being_told_to_stop_is_not_stuck():
    """A circle wider than R_s re-anchors; a nominal stop restarts the count."""
    wide = DeadlockDetector(1.0, 0.1, stuck_time_s=5.0, stuck_radius_m=1.0)
    assert not any(_track(wide, _circle(2000, 3.0)))
    told = DeadlockDetector(1.0, 0.1, stuck_time_s=5.0, stuck_radius_m=1.0)
    steps = _circle(800, 0.4)
    steps[400] = (steps[400][0], steps[400][1], (0.0, 0.01))  # one stop request
    assert not any(_track(told, steps))  # without it: reported from step 500 on


def test_the_stuck_rule_is_off_at_zero_time():
    """stuck_time_s = 0 (the default): circling in place is not reported."""
    detector = DeadlockDetector(1.0, 0.1)
    assert not any(_track(detector, _circle(2000, 0.2)))


def _held_bursts(detector, bursts, dt=0.01, gap=2.0, nominal=(1.0, 0.0)):
    """Hold the robot ``bursts`` times for 1.5 s, each after ``gap`` s free; return verdicts.

    Each burst is held at a new place 1 m on, so the other two rules only see it held.
    """
    verdicts, now = [], 0.0
    for burst in range(bursts):
        for held, duration in ((False, gap), (True, 1.5)):
            for _ in range(int(round(duration / dt))):
                body = (float(burst), 0.0)
                detector.track(now, body, nominal)
                verdicts.append((now, held, detector.update(now, body, held)))
                now += dt
    return verdicts


def test_deadlocks_over_and_over_are_reported_while_they_go_on():
    """Three holds of 1 s within the window: a deadlock from the third on, between holds too."""
    detector = DeadlockDetector(1.0, 0.1, repeat_count=3, repeat_window_s=20.0)
    verdicts = _held_bursts(detector, 5)
    assert detector.onsets == 5 and detector.repeat_onsets == 1
    third = 2 * 3.5 + 2.0 + 1.0     # the third hold reaches 1 s
    free = [deadlocked for now, held, deadlocked in verdicts if not held and now > third]
    assert free and all(free)       # still reported while it drives between the holds
    assert not any(deadlocked for now, held, deadlocked in verdicts
                   if not held and now < third)


def test_repeated_reports_end_when_the_window_empties_or_the_nominal_stops():
    """Reports older than the window no longer count; a nominal stop is not a deadlock."""
    detector = DeadlockDetector(1.0, 0.1, repeat_count=3, repeat_window_s=20.0)
    _held_bursts(detector, 3)
    now = 3 * 3.5
    detector.track(now, (9.0, 0.0), (1.0, 0.0))
    assert detector.update(now, None, False)
    detector.track(now, (9.0, 0.0), (0.0, 0.0))
    assert not detector.update(now, None, False)
    later = now + 21.0
    detector.track(later, (9.0, 0.0), (1.0, 0.0))
    assert not detector.update(later, None, False)


def test_the_repeated_rule_is_off_at_a_count_of_zero():
    """repeat_count 0: five holds give five held reports and nothing between them."""
    detector = DeadlockDetector(1.0, 0.1, repeat_count=0)
    verdicts = _held_bursts(detector, 5)
    assert detector.onsets == 5 and detector.repeat_onsets == 0
    assert not any(deadlocked for _, held, deadlocked in verdicts if not held)
    with pytest.raises(ValueError):
        DeadlockDetector(1.0, 0.1, repeat_count=2.5)
