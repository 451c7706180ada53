"""twin.samples: a long series kept as a bounded, evenly spaced subsample."""

import numpy as np
import pytest

from twin.samples import Samples


@pytest.mark.parametrize("capacity", [2, 7, 8, 1000])
def test_past_its_capacity_a_series_keeps_every_stride_th_value_from_the_first(capacity):
    series = np.arange(10 * capacity + 3, dtype=float)
    kept = Samples(capacity)
    for x in series:
        kept.append(x)
    assert len(kept) <= capacity
    assert kept.offered == len(series)
    assert kept.stride > 1
    np.testing.assert_array_equal(kept, series[::kept.stride])


def test_under_its_capacity_it_is_the_whole_series():
    kept = Samples(100)
    for x in range(100):
        kept.append(float(x))
    assert kept == [float(x) for x in range(100)] and kept.stride == 1


def test_a_long_run_keeps_its_percentiles():
    rng = np.random.default_rng(0)
    series = rng.exponential(1.0, 200_000)
    kept = Samples(5_000)
    for x in series:
        kept.append(x)
    assert len(kept) <= 5_000
    for q in (50, 99):
        assert abs(np.percentile(kept, q) / np.percentile(series, q) - 1) < 0.1
