"""Run every benchmark in turn: ``python -m bench`` (or ``python -m bench msg master`` for some)."""

from __future__ import annotations

import importlib
import importlib.util
import sys

PARTS = ["msg", "master", "tcpros", "ixm", "cli"]


def main(argv: list[str]) -> int:
    wanted = argv or PARTS
    status = 0
    for part in wanted:
        name = f"bench.{part}"
        if importlib.util.find_spec(name) is None:
            print(f"== {part}: no benchmark module yet", flush=True)
            continue
        print(f"== {part}", flush=True)
        module = importlib.import_module(name)
        status |= int(module.main([]) or 0)
    return status


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
