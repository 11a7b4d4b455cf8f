"""rbgp_cli.wording: counts in messages read as English."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from rbgp_cli.wording import plural


def test_one_is_singular_and_zero_is_plural():
    assert plural(1, "demonstration") == "1 demonstration"
    assert plural(0, "fold") == "0 folds"


@given(st.integers(min_value=2, max_value=10**6))
def test_more_than_one_is_plural(n):
    assert plural(n, "pair") == f"{n} pairs"
