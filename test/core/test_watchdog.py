"""Watchdog: per-input staleness on caller-supplied monotonic times."""
import math

import pytest
from hypothesis import given, settings, strategies as st

from polyc2bf_ros.core.watchdog import Watchdog
from strategies import examples


def test_never_received_is_stale_with_infinite_age():
    """An input that never arrived is stale and infinitely old."""
    dog = Watchdog({'odom': 0.1, 'cmd': 0.5})
    assert dog.stale(100.0) == ('odom', 'cmd')
    assert dog.age('odom', 100.0) == math.inf


def test_fresh_until_timeout_then_stale():
    """Stale exactly when the age reaches the timeout."""
    dog = Watchdog({'odom': 0.25})
    dog.feed('odom', 10.0)
    assert not dog.is_stale('odom', 10.2499)
    assert dog.is_stale('odom', 10.25)
    assert dog.age('odom', 10.125) == 0.125


def test_inputs_are_independent_and_recover_when_fed_again():
    """Each input expires on its own timeout and recovers when fed."""
    dog = Watchdog({'odom': 0.1, 'cmd': 0.5, 'obstacles': 1.0})
    for name in dog.names:
        dog.feed(name, 0.0)
    assert dog.stale(0.2) == ('odom',)
    assert dog.stale(0.7) == ('odom', 'cmd')
    dog.feed('odom', 0.7)
    assert dog.stale(0.7) == ('cmd',)


def test_zero_timeout_never_expires_once_received():
    """Timeout 0: stale until the first message, then never again."""
    dog = Watchdog({'obstacles': 0.0})
    assert dog.is_stale('obstacles', 0.0)
    dog.feed('obstacles', 0.0)
    assert not dog.is_stale('obstacles', 1e9)


def test_set_timeout_applies_at_once():
    """A new timeout applies to the next check; ``timeout`` reads it back."""
    dog = Watchdog({'cmd': 0.5})
    dog.feed('cmd', 1.0)
    assert not dog.is_stale('cmd', 1.2)
    dog.set_timeout('cmd', 0.1)
    assert dog.timeout('cmd') == 0.1
    assert dog.is_stale('cmd', 1.2)


@pytest.mark.parametrize('bad', [-0.1, math.nan, math.inf])
def test_bad_timeouts_are_refused(bad):
    """Negative, NaN and infinite timeouts raise with the input name."""
    with pytest.raises(ValueError, match='cmd'):
        Watchdog({'cmd': bad})


@settings(max_examples=examples(200), deadline=None)
@given(timeouts=st.lists(st.sampled_from([0.0, 0.1, 0.5]), min_size=1, max_size=4),
       fed=st.lists(st.one_of(st.none(), st.floats(0.0, 2.0)), min_size=4, max_size=4),
       now=st.floats(0.0, 3.0))
def test_any_stale_says_whether_stale_names_any(timeouts, fed, now):
    """``any_stale`` is ``bool(stale(now))`` for any timeouts and arrival times."""
    dog = Watchdog({f'input{i}': timeout for i, timeout in enumerate(timeouts)})
    for name, last in zip(dog.names, fed):
        if last is not None:
            dog.feed(name, last)
    assert dog.any_stale(now) == bool(dog.stale(now))
