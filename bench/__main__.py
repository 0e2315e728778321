"""Run every benchmark in turn: ``python -m bench`` (or ``python -m bench msg master`` for some).

Options after the names go to each named benchmark: ``python -m bench shm --latency``,
``python -m bench web --quick``.
"""

from __future__ import annotations

import importlib
import sys

#: Run by a bare ``python -m bench``, in this order.
PARTS = ["msg", "master", "tcpros", "ixm", "cli", "bag", "web", "fleet", "images", "tf"]
#: Run only when named: ``shm`` needs a C++ toolchain for its roscpp rows and takes minutes.
NAMED_ONLY = ["shm"]
NAMED_ONLY += ["ros2"]  # needs the ros2 extra and Debian's rosmaster; about 45 s


def main(argv: list[str]) -> int:
    split = next((i for i, arg in enumerate(argv) if arg.startswith("-")), len(argv))
    names, options = argv[:split], argv[split:]
    wanted = names or PARTS
    unknown = [part for part in wanted if part not in PARTS + NAMED_ONLY]
    if unknown:
        print(f"unknown benchmark {', '.join(unknown)}; choose from {', '.join(PARTS + NAMED_ONLY)}", file=sys.stderr)
        return 2
    status = 0
    for part in wanted:
        print(f"== {part}", flush=True)
        module = importlib.import_module(f"bench.{part}")
        status |= int(module.main(list(options)) or 0)
    return status


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
