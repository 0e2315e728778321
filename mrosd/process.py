"""What the daemon sets up in its own process before any part starts: the log format and the descriptor limit.

Also ``reason``, the one-line "why" every daemon log line and ``STATUS=`` gives for a failure. Nothing here
knows the parts.
"""

from __future__ import annotations

import logging
import os
import resource
import sys

from mrosd.errors import MrosError
from mrosd.fdbudget import FdBudgets, fd_budgets

__all__ = ["JournalFormatter", "planned_budgets", "raise_nofile_limit", "reason", "setup_logging"]

log = logging.getLogger("mrosd")

# syslog priorities for journald's "<N>" line prefix (sd-daemon.h).
_PRIORITY = {logging.DEBUG: 7, logging.INFO: 6, logging.WARNING: 4, logging.ERROR: 3, logging.CRITICAL: 2}


class JournalFormatter(logging.Formatter):
    """``<6>mrosd.master: message``: journald reads the priority prefix and adds its own timestamp."""

    def format(self, record: logging.LogRecord) -> str:
        priority = _PRIORITY.get(record.levelno, 6 if record.levelno < logging.WARNING else 4)
        text = super().format(record)
        return "\n".join(f"<{priority}>{line}" for line in text.splitlines() or [""])


def setup_logging(level: str, environ: dict[str, str] | None = None) -> None:
    """Log to stderr: journald style under systemd (``$JOURNAL_STREAM`` set), timestamped otherwise."""
    env = os.environ if environ is None else environ
    handler = logging.StreamHandler(sys.stderr)
    if env.get("JOURNAL_STREAM"):
        handler.setFormatter(JournalFormatter("%(name)s: %(message)s"))
    else:
        handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
    root = logging.getLogger()
    for old in list(root.handlers):
        root.removeHandler(old)
    root.addHandler(handler)
    root.setLevel(level.upper())


def reason(exc: BaseException) -> str:
    """One line saying why, for a log line or STATUS: our own errors carry it, others get their type named."""
    if isinstance(exc, MrosError):
        text = str(exc)
    elif isinstance(exc, OSError) and exc.strerror:
        text = f"{exc.strerror}: {exc.filename}" if exc.filename else exc.strerror
    else:
        text = f"{type(exc).__name__}: {exc}"
    return " ".join(text.split()) or type(exc).__name__


def _nofile_target(soft: int, hard: int) -> int:
    """The soft RLIMIT_NOFILE the daemon runs with: the hard limit, capped at the kernel's ``nr_open``."""
    target = hard
    if hard == resource.RLIM_INFINITY:
        try:
            with open("/proc/sys/fs/nr_open", encoding="ascii") as f:
                target = int(f.read())
        except (OSError, ValueError):
            target = max(soft, 65536) if soft != resource.RLIM_INFINITY else soft
    return target


def planned_budgets() -> FdBudgets:
    """The descriptor budgets the daemon would run with, from the limit it would raise itself to."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    target = _nofile_target(soft, hard)
    limit = soft if soft == resource.RLIM_INFINITY or soft >= target else target
    return fd_budgets(1 << 20 if limit == resource.RLIM_INFINITY else limit)


def raise_nofile_limit() -> int:
    """Raise the soft RLIMIT_NOFILE to the hard limit (capped at the kernel's ``nr_open``); return the result.

    Every client connection and every IXM key costs the daemon descriptors; distributions still start
    services with a soft limit of 1024 although the hard limit allows far more.
    """
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    target = _nofile_target(soft, hard)
    if soft == resource.RLIM_INFINITY or soft >= target:
        log.info("open files: %s", "unlimited" if soft == resource.RLIM_INFINITY else soft)
        return soft
    try:
        resource.setrlimit(resource.RLIMIT_NOFILE, (target, hard))
    except (OSError, ValueError) as exc:
        log.warning("open files: %d (could not raise it to %d: %s)", soft, target, reason(exc))
        return soft
    log.info("open files: %d (soft limit raised from %d)", target, soft)
    return target
