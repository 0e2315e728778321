"""Every parser of untrusted input accepts or refuses with its documented error, whatever the bytes.

A short hypothesis run per target in the default suite; ``python -m bench.fuzz TARGET --minutes N`` runs the
same targets for as long as wanted. The suite's runs are derandomized (the same examples every time, so CI is
deterministic); bench.fuzz draws fresh ones on every round.
"""

from __future__ import annotations

from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings

from tests.fuzz.targets import TARGETS


@pytest.mark.parametrize("name", sorted(TARGETS))
def test_a_parser_of_untrusted_input_only_ever_raises_its_documented_error(name: str) -> None:
    target = TARGETS[name]

    @settings(max_examples=100, deadline=None, suppress_health_check=list(HealthCheck), database=None, derandomize=True)
    @given(target.strategy)
    def run(value: Any) -> None:
        target.check(value)

    run()
