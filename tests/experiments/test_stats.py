"""The interval of a difference of success rates, against a published worked example and its limits."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from experiments import stats


def test_newcombes_worked_example():
    """Newcombe (1998), Statistics in Medicine 17:873, Table II, example (a): 56/70 against 48/80, hybrid
    score interval 0.0524 to 0.3339."""
    d = stats.rate_diff((56, 70), (48, 80))
    assert d["diff"] == pytest.approx(0.2)
    assert (d["lo"], d["hi"]) == (pytest.approx(0.0524, abs=1e-4), pytest.approx(0.3339, abs=1e-4))


@given(st.integers(1, 200).flatmap(lambda n: st.tuples(st.integers(0, n), st.just(n))), st.data())
def test_the_interval_holds_the_difference_and_stays_in_range(a, data):
    n = data.draw(st.integers(1, 200))
    b = (data.draw(st.integers(0, n)), n)
    d = stats.rate_diff(a, b)
    assert -1.0 - 1e-12 <= d["lo"] <= d["diff"] <= d["hi"] <= 1.0 + 1e-12
