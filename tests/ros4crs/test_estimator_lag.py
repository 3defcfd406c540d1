"""The estimator node's arrival-delay window (what its adaptive lag covers)."""

import math

from ros4crs.estimator_node import WindowMax


def test_window_max_keeps_the_largest_value_of_the_last_seconds():
    window = WindowMax(5.0)
    assert window.value(100.0) == -math.inf
    window.add(100.2, 0.03)
    window.add(100.7, 0.01)
    window.add(102.5, 0.02)
    assert window.value(102.9) == 0.03
    assert window.value(104.9) == 0.03  # second 100 is one of the last five
    assert window.value(105.0) == 0.02  # ... and now it is not
    for second in range(107, 130):  # long runs keep a bounded number of buckets
        window.add(second + 0.5, 0.001)
    assert window.value(129.9) == 0.001 and len(window._buckets) <= 6
