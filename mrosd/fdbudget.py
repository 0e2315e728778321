"""The daemon's descriptor budget: one share of RLIMIT_NOFILE per part, summing below the limit.

Each part of the daemon sizes its own caps, and each alone stays under the limit; together they did not:
the master's connection cap (the limit minus 64) plus IXM's share (three quarters of the limit) could take
every descriptor, and the next uid was told that the IXM daemon is out of file descriptors. So the daemon
splits the limit once, at start, with ``fd_budgets``: a reserve for its own work (log files, the signal
thread, outgoing XML-RPC calls, the kernel's accept backlog turning into descriptors) and one budget per part,
which that part is given as its cap. Pure: the limit in, numbers out.
"""

from __future__ import annotations

import msgspec

__all__ = ["FdBudgets", "fd_budgets"]

#: Descriptors kept for the daemon's own work, at least.
MIN_RESERVE = 32

#: Each part's share (in percent) of what is left after the reserve.
SHARES = {"master": 40, "ixm": 33, "tcpros": 14, "shm": 5, "web": 5, "fleet": 3}


class FdBudgets(msgspec.Struct, frozen=True, kw_only=True):
    """Descriptors each part of the daemon may hold; ``sum(parts) + reserve <= limit``.

    Attributes:
        limit: the RLIMIT_NOFILE these were derived from.
        reserve: left to the daemon's own work (never given to a part).
        master: the master's connections (its ``max_connections``).
        ixm: the IXM registry's connections and the descriptors of keys it holds.
        tcpros: inbound TCPROS connections of the nodes inside the daemon (rosout aggregator, bridges).
        shm: shared-memory topic segments and control sockets of those nodes.
        web: the web part: half for browser clients' sockets (its ``max_clients``), half for its TCPROS links.
        fleet: the fleet part's node (``mrosd.fleet.bridge.fleet_admission``): half for the inbound TCPROS
            connections of local subscribers and callers of what it receives, the rest for its outgoing
            connections (a quarter caps its service calls in flight) and its Zenoh session.
    """

    limit: int
    reserve: int
    master: int
    ixm: int
    tcpros: int
    shm: int
    web: int
    fleet: int

    def parts(self) -> dict[str, int]:
        return {name: getattr(self, name) for name in SHARES}

    def lines(self) -> list[str]:
        """One line per part, for ``mrosd --check``."""
        out = [f"descriptor budget of RLIMIT_NOFILE {self.limit}:"]
        out += [f"  {name:<8} {value}" for name, value in self.parts().items()]
        out.append(f"  {'reserve':<8} {self.reserve} (the daemon's own work)")
        return out


def fd_budgets(limit: int) -> FdBudgets:
    """Split ``limit`` descriptors (RLIMIT_NOFILE, after the daemon raised it) between the parts.

    The reserve is a sixteenth of the limit (at least ``MIN_RESERVE``); the rest is shared by ``SHARES``,
    rounded down, so the parts and the reserve never add up to more than the limit. A limit too small to
    give every part a few descriptors still yields at least one each: the parts then refuse early.
    """
    limit = max(0, int(limit))
    reserve = min(limit, max(MIN_RESERVE, limit // 16))
    rest = limit - reserve
    shares = {name: max(1, rest * percent // 100) for name, percent in SHARES.items()}
    return FdBudgets(limit=limit, reserve=reserve, **shares)
