"""The fleet tests use the netns lab of tests/netns (root only; skipped with a reason otherwise)."""

from tests.netns.conftest import netns_lab

__all__ = ["netns_lab"]
