"""The ``netns_lab`` fixture: three network namespaces on a private /24 (root only, skipped with a reason)."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from tests.netns.nsutil import NetnsLab, netns_unavailable


@pytest.fixture
def netns_lab() -> Iterator[NetnsLab]:
    why = netns_unavailable()
    if why is not None:
        pytest.skip(why)
    lab = NetnsLab()
    try:
        lab.setup()
        yield lab
    finally:
        lab.teardown()
    assert lab.leftovers() == [], "a namespace of this test survived its teardown"
