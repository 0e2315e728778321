"""fd_budgets: every part gets a share of RLIMIT_NOFILE and the shares plus the reserve fit in it."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from mrosd.fdbudget import MIN_RESERVE, fd_budgets


@given(st.integers(64, 1 << 22))
def test_the_parts_and_the_reserve_fit_the_limit(limit: int) -> None:
    budgets = fd_budgets(limit)
    assert sum(budgets.parts().values()) + budgets.reserve <= limit
    assert budgets.reserve >= MIN_RESERVE
    assert all(value >= 1 for value in budgets.parts().values())


def test_at_512_the_master_and_ixm_together_leave_room() -> None:
    budgets = fd_budgets(512)
    assert budgets.master + budgets.ixm + budgets.reserve < 512
    assert budgets.lines()[0] == "descriptor budget of RLIMIT_NOFILE 512:"


def test_check_prints_the_configuration_and_the_budgets(
    tmp_path: object, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from pathlib import Path

    from mrosd.daemon import main

    config = Path(str(tmp_path)) / "mrosd.toml"
    config.write_text("[master]\nport = 11999\n")
    monkeypatch.delenv("ROS_MASTER_URI", raising=False)
    assert main(["--config", str(config), "--check"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("configuration OK")
    assert "descriptor budget of RLIMIT_NOFILE" in out and "  master " in out and "reserve" in out
