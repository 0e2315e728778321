"""Route every use of a Python 3.11 standard-library name through mrosd/backports.py (mrosd runs on 3.10 too).

Rewrites, in the .py files under mrosd/, cli/, tests/, bench/ and examples/ (never mrosd/backports.py):

    asyncio.timeout(      -> backports.timeout(      (+ ``from mrosd import backports``)
    asyncio.Runner(       -> backports.Runner(
    asyncio.wait_for(     -> backports.wait_for(     (3.10's raises asyncio.TimeoutError, not TimeoutError)
    import tomllib        -> from mrosd.backports import tomllib
    from enum import StrEnum          -> from mrosd.backports import StrEnum
    from typing import ..., Self, ... -> the same without Self, + from mrosd.backports import Self

and prints the files it changed. Idempotent: run it again after merging code written for 3.11, then
``ruff check --fix --select I,F401 <files> && ruff format <files>`` to place the imports and drop an
``import asyncio`` left unused. ``python -m mypy`` (python_version 3.10) names any 3.11-only use it missed.

Run: ``python scripts/sweep-backports.py``.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TREES = ("mrosd", "cli", "tests", "bench", "examples")
SKIP = {ROOT / "mrosd" / "backports.py"}

CALLS = re.compile(r"\basyncio\.(timeout|Runner|wait_for)\(")
TOMLLIB = re.compile(r"^import tomllib$", re.M)
STRENUM = re.compile(r"^from enum import StrEnum$", re.M)
TYPING_SELF = re.compile(r"^from typing import (.*\bSelf\b.*)$", re.M)
FIRST_IMPORT = re.compile(r"^(?:import|from) (?!__future__)", re.M)


def sweep(text: str) -> str:
    """The text with every 3.11-only name taken from mrosd.backports."""
    imports: list[str] = []
    if CALLS.search(text):
        text = CALLS.sub(r"backports.\1(", text)
        if "from mrosd import backports" not in text:
            imports.append("from mrosd import backports")
    text = TOMLLIB.sub("from mrosd.backports import tomllib", text)
    text = STRENUM.sub("from mrosd.backports import StrEnum", text)

    def drop_self(match: re.Match[str]) -> str:
        names = [n.strip() for n in match.group(1).split(",") if n.strip() != "Self"]
        imports.append("from mrosd.backports import Self")
        return f"from typing import {', '.join(names)}" if names else ""

    text = TYPING_SELF.sub(drop_self, text)
    if imports:
        first = FIRST_IMPORT.search(text)
        at = first.start() if first else 0
        text = text[:at] + "".join(f"{line}\n" for line in imports) + text[at:]
    return text


def main() -> int:
    for tree in TREES:
        for path in sorted((ROOT / tree).rglob("*.py")):
            if path in SKIP or "node_modules" in path.parts:
                continue
            old = path.read_text()
            new = sweep(old)
            if new != old:
                path.write_text(new)
                print(path.relative_to(ROOT))
    return 0


if __name__ == "__main__":
    sys.exit(main())
