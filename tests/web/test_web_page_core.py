"""The page's pure cores: which asset names are served (``mrosd.web.page.asset``) and ``RateWindow``."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from mrosd.web.page import ASSET_NAME, CONTENT_TYPES, asset
from mrosd.web.rates import RateWindow


def test_every_shipped_asset_is_served_with_its_content_type() -> None:
    for name, ctype in [("index.html", "text/html"), ("app.js", "text/javascript"), ("style.css", "text/css")]:
        found = asset(name)
        assert found is not None and found[1].startswith(ctype) and found[0]


@given(st.text(max_size=80))
def test_any_other_name_is_refused(name: str) -> None:
    found = asset(name)
    if found is not None:
        assert ASSET_NAME.fullmatch(name) and "/" not in name and ".." not in name
        assert found[1] in CONTENT_TYPES.values()


@pytest.mark.parametrize("name", ["../page.py", "..", "/etc/passwd", "page.py", "app.js/", "x/../app.js", ""])
def test_names_outside_the_folder_are_refused(name: str) -> None:
    assert asset(name) is None


def test_rate_over_the_window() -> None:
    w = RateWindow(span=5.0)
    assert w.rate() is None
    for i in range(11):  # 20 msg/s, 100 B each, sampled once a second for 10 s
        w.add(float(i), 20 * i, 2000 * i)
    hz, bps = w.rate() or (0, 0)
    assert hz == pytest.approx(20.0) and bps == pytest.approx(2000.0)


def test_a_counter_that_restarts_restarts_the_window() -> None:
    w = RateWindow(span=5.0)
    w.add(0.0, 100, 1000)
    w.add(1.0, 110, 1100)
    w.add(2.0, 3, 30)  # the subscription was closed and opened again
    assert w.rate() is None
    w.add(3.0, 13, 130)
    assert w.rate() == (10.0, 100.0)


@given(st.lists(st.tuples(st.floats(0.01, 3.0), st.integers(0, 1000), st.integers(0, 10**6)), max_size=50))
def test_the_window_stays_bounded_and_rates_are_never_negative(steps: list[tuple[float, int, int]]) -> None:
    w = RateWindow(span=5.0)
    t = m = b = 0.0
    for dt, dm, db in steps:
        t, m, b = t + dt, m + dm, b + db
        w.add(t, int(m), int(b))
        assert len(w._samples) <= 5 / 0.01 + 2
        rate = w.rate()
        assert rate is None or (rate[0] >= 0 and rate[1] >= 0)
