"""Print the versions of the tools a check ran with, one line each, so a CI log says what judged the tree.

The development tools are pinned exactly in pyproject.toml's ``[dev]``; a line here that differs from the pin
means the install did not take (a read-only site-packages, another interpreter on PATH).
"""

from __future__ import annotations

import platform
import shutil
import subprocess
import sys
from importlib import metadata

PACKAGES = (
    "pip",
    "ruff",
    "mypy",
    "pytest",
    "pytest-asyncio",
    "pytest-timeout",
    "hypothesis",
    "aiohttp",
    "msgspec",
    "uvloop",
    "click",
)
COMMANDS = (
    ("node", "--version"),
    ("npm", "--version"),
    ("chromium", "--version"),
    ("dpkg-query", "-W", "-f", "${Package} ${Version}", "python3-rospy"),
)


def main() -> int:
    print(f"python {platform.python_version()} ({sys.executable})")
    for name in PACKAGES:
        try:
            print(f"{name} {metadata.version(name)}")
        except metadata.PackageNotFoundError:
            print(f"{name} not installed")
    for command, *args in COMMANDS:
        path = shutil.which(command)
        if path is None:
            print(f"{command} not found")
            continue
        try:
            done = subprocess.run([path, *args], capture_output=True, text=True, timeout=30, check=False)
        except (OSError, subprocess.TimeoutExpired) as exc:
            print(f"{command} failed: {exc}")
            continue
        lines = (done.stdout or done.stderr).strip().splitlines()
        print(f"{command} {lines[0] if lines else '(no output)'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
