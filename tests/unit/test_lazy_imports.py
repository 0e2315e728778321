"""Top-level re-exports are lazy: the message layer and the wire cores load without aiohttp or the node stack."""

from __future__ import annotations

import subprocess
import sys

import pytest


def _loaded_after(statement: str, modules: list[str]) -> list[str]:
    probe = f"import sys\n{statement}\nprint(' '.join(m for m in {modules!r} if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=60, check=True)
    return out.stdout.split()


HEAVY = ["aiohttp", "mrosd.xmlrpc", "mrosd.tcpros.node", "mrosd.master.client"]


@pytest.mark.parametrize("statement", ["import mrosd.msg", "import mrosd.wire.framing", "import mrosd"])
def test_importing_the_light_parts_loads_neither_aiohttp_nor_the_node_stack(statement: str) -> None:
    assert _loaded_after(statement, HEAVY) == []


def test_the_public_names_still_resolve_from_the_package() -> None:
    import mrosd
    import mrosd.tcpros

    for name in mrosd.__all__:
        assert getattr(mrosd, name).__name__ == name
    for name in mrosd.tcpros.__all__:
        assert getattr(mrosd.tcpros, name).__name__ == name
    assert mrosd.msg.Time is mrosd.Time
    with pytest.raises(AttributeError):
        _ = mrosd.no_such_name  # type: ignore[attr-defined]
