"""Long-running fuzzing of every parser of untrusted input: ``python -m bench.fuzz [TARGET|all] --minutes N``.

The targets (strategies and property checks) are those of tests/fuzz/targets.py; the default test run gives each
a few hundred examples, this runs hypothesis rounds of fresh random examples until the time is up. Hypothesis,
not atheris: it needs no new dependency and its structured strategies (mutated valid XML-RPC calls, lying
header lengths, .msg lines) reach deeper than byte-level mutation alone. A failure is shrunk and printed, and the
exit status is 1: turn it into a regression test in tests/fuzz/test_fuzz_regressions.py.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # `tests` importable from any cwd

from hypothesis import HealthCheck, given, settings

from tests.fuzz.targets import TARGETS

ROUND = 200


def fuzz(name: str, seconds: float) -> tuple[int, float]:
    """Run target ``name`` for about ``seconds``; returns (examples run, seconds taken). Raises on a failure."""
    target = TARGETS[name]
    count = 0

    @settings(max_examples=ROUND, deadline=None, suppress_health_check=list(HealthCheck), database=None)
    @given(target.strategy)
    def one_round(value: Any) -> None:
        nonlocal count
        count += 1
        target.check(value)

    start = time.monotonic()
    while True:
        one_round()
        if time.monotonic() - start >= seconds:
            return count, time.monotonic() - start


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.fuzz", description=__doc__.splitlines()[0])
    parser.add_argument("target", nargs="?", default="all", choices=["all", *sorted(TARGETS)])
    parser.add_argument("--minutes", type=float, default=0.05, help="time per target (default: 3 s)")
    parser.add_argument(
        "--strict", action="store_true", help="fail on the known escapes too (KNOWN_*_ESCAPES, pinned as xfails)"
    )
    args = parser.parse_args(argv)
    from tests.fuzz import targets

    known = [n for n in dir(targets) if n.startswith("KNOWN_") and getattr(targets, n)]
    if args.strict:
        for name in known:
            setattr(targets, name, ())
    elif known:
        print("tolerating known escapes: " + ", ".join(f"{n}={getattr(targets, n)}" for n in known), flush=True)
    names = sorted(TARGETS) if args.target == "all" else [args.target]
    status = 0
    for name in names:
        print(f"fuzz {name:16} ({TARGETS[name].what}) for {args.minutes:g} min ...", flush=True)
        try:
            count, took = fuzz(name, args.minutes * 60)
        except Exception as exc:  # hypothesis has printed the shrunk falsifying example
            print(f"  FAILED: {type(exc).__name__}: {exc}", flush=True)
            status = 1
            continue
        print(
            f"  ok: {count} examples in {took:.0f} s ({count / max(took, 1e-9):.0f}/s), nothing unexpected escaped",
            flush=True,
        )
    return status


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
