"""Diagnostics statistics: the latency ring keeps the last samples, the rate meter counts."""
import math

import numpy as np
from hypothesis import given, strategies as st

from polyc2bf_ros.core.stats import LatencyRing, RateMeter


@given(capacity=st.integers(1, 20),
       samples=st.lists(st.floats(0.0, 1.0, allow_nan=False), max_size=60))
def test_latency_ring_summarises_the_last_capacity_samples(capacity, samples):
    """The sample count and percentiles are those of the last ``capacity`` samples added."""
    ring = LatencyRing(capacity)
    for sample in samples:
        ring.add(sample)
    kept = samples[-capacity:]
    assert len(ring) == len(kept)
    if kept:
        np.testing.assert_allclose(ring.percentiles((0.0, 50.0, 100.0)),
                                   np.percentile(kept, (0.0, 50.0, 100.0)))
    else:
        assert all(math.isnan(value) for value in ring.percentiles())


def test_latency_ring_clear_starts_a_new_window():
    """After ``clear`` only the samples added since count."""
    ring = LatencyRing(4)
    for sample in (5.0, 6.0, 7.0, 8.0, 9.0):
        ring.add(sample)
    ring.clear()
    assert len(ring) == 0
    ring.add(1.0)
    ring.add(3.0)
    assert len(ring) == 2
    assert ring.percentiles((0.0, 100.0)) == (1.0, 3.0)


def test_rate_meter_counts_events_per_window():
    """Events per second since the previous call; each call starts a new window."""
    meter = RateMeter(10.0)
    for _ in range(50):
        meter.tick()
    assert meter.rate(10.5) == 100.0
    meter.tick()
    assert meter.rate(11.5) == 1.0
    assert math.isnan(meter.rate(11.5))
