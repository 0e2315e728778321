"""Run every benchmark in turn: ``python -m bench`` (or ``python -m bench msg master`` for some)."""

from __future__ import annotations

import importlib
import sys

PARTS = ["msg", "master", "tcpros", "ixm", "cli", "bag", "web", "fleet"]


def main(argv: list[str]) -> int:
    wanted = argv or PARTS
    unknown = [part for part in wanted if part not in PARTS]
    if unknown:
        print(f"unknown benchmark {', '.join(unknown)}; choose from {', '.join(PARTS)}", file=sys.stderr)
        return 2
    status = 0
    for part in wanted:
        print(f"== {part}", flush=True)
        module = importlib.import_module(f"bench.{part}")
        status |= int(module.main([]) or 0)
    return status


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
