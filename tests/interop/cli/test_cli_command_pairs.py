"""The command-pair table of docs/cli.md: each ROS tool and its `mros` twin, same scenario, on both masters.

Every pair runs against Debian's rosmaster and against ours (``python -m mrosd.master``), with the same rospy
fixture node, parameters and services; stdout and the exit code must be equal, or the pair must be listed in
``EXPLAINED`` with the reason (and an explained pair that no longer differs fails too, so the table stays
true). The test renders the table and checks it against docs/cli.md; ``MROS_WRITE_PAIRS=1`` rewrites it.
"""

from __future__ import annotations

import concurrent.futures
import os
import re
import subprocess
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pytest

from tests.interop.cli.cliutil import mask_seq, mros, ros_tool, start_our_master, start_rospy
from tests.rosenv import PROJECT_ROOT, Processes, needs_ros, start_rosmaster

pytestmark = [needs_ros, pytest.mark.interop]

DOC = PROJECT_ROOT / "docs" / "cli.md"
BEGIN = "<!-- command-pairs:begin (written by tests/interop/cli/test_cli_command_pairs.py) -->"
END = "<!-- command-pairs:end -->"

FIXTURE = """
import rospy
from std_msgs.msg import String
from geometry_msgs.msg import PoseStamped
from sensor_msgs.msg import JointState
from std_srvs.srv import SetBool, SetBoolResponse
from roscpp.srv import SetLoggerLevel, SetLoggerLevelResponse
rospy.init_node("fixture")
rospy.set_param("/pid", {"p": 1.0, "i": 0.1, "limits": {"max": 5, "names": ["a", "b"]}})
rospy.set_param("/text", "line one\\nline two")
rospy.set_param("/rate", 10)
rospy.Publisher("/chatter", String, queue_size=1, latch=True).publish(String("hi"))
pose = PoseStamped()
pose.header.stamp = rospy.Time(1234, 500)
pose.header.frame_id = "map"
pose.pose.position.x = 1.5
pose.pose.orientation.w = 1.0
rospy.Publisher("/pose", PoseStamped, queue_size=1, latch=True).publish(pose)
joints = JointState()
joints.header.stamp = rospy.Time(7, 8)
joints.name = ["elbow", "wrist"]
joints.position = [0.5, -1.25]
rospy.Publisher("/joints", JointState, queue_size=1, latch=True).publish(joints)
rospy.Subscriber("/cmd", String, lambda m: None)
rospy.Service("/set", SetBool, lambda r: SetBoolResponse(success=r.data, message="got %s" % r.data))
rospy.Service("/set_level", SetLoggerLevel, lambda r: SetLoggerLevelResponse())
print("up", flush=True)
rospy.spin()
"""

NOUNS = {
    "rostopic": "topic",
    "rosnode": "node",
    "rosparam": "param",
    "rosservice": "service",
    "rosmsg": "msg",
    "rossrv": "srv",
}


def _receive_time(text: str) -> str:
    """echo -p of a message without a Header: the first column is the receive time."""
    return re.sub(r"(?m)^\d+,", "<now>,", text)


def _node_ports(text: str) -> str:
    """``list -u``/``-a``: each tool's own anonymous node has its own port."""
    return re.sub(r"http://127\.0\.0\.1:\d+/", "http://127.0.0.1:<port>/", text)


def _ping_time(text: str) -> str:
    return re.sub(r"time=[0-9.]+ms", "time=<t>ms", text)


@dataclass(frozen=True)
class Pair:
    ros: tuple[str, ...]
    normalize: Callable[[str], str] | None = None
    needs_master: bool = True
    #: the command is expected to keep waiting: both run for WAIT_TIME, then "still waiting" is the outcome.
    waits: bool = False

    @property
    def observes_graph(self) -> bool:
        """Its output lists nodes, topics or services, so no pair that registers a node (echo, call, ping) may run
        beside it; it registers nothing itself, so other observers may (as each pair's two commands always do)."""
        return self.ros[1] in {"list", "info", "find", "machine"}

    @property
    def ours(self) -> tuple[str, ...]:
        return (NOUNS[self.ros[0]], *self.ros[1:])

    @property
    def ros_text(self) -> str:
        return " ".join(a if " " not in a and a else repr(a) for a in self.ros)

    @property
    def ours_text(self) -> str:
        return "mros " + " ".join(a if " " not in a and a else repr(a) for a in self.ours)


PAIRS = [
    Pair(("rostopic", "list")),
    Pair(("rostopic", "list", "-v")),
    Pair(("rostopic", "info", "/chatter")),
    Pair(("rostopic", "info", "/nope")),
    Pair(("rostopic", "type", "/chatter")),
    Pair(("rostopic", "type", "/pose/pose/position")),
    Pair(("rostopic", "type", "/nope")),
    Pair(("rostopic", "find", "std_msgs/String")),
    Pair(("rostopic", "find", "nope_msgs/Nope")),
    Pair(("rostopic", "echo", "-n", "1", "/chatter")),
    Pair(("rostopic", "echo", "-n", "1", "/pose/pose/position")),
    Pair(("rostopic", "echo", "-n", "1", "--nostr", "/joints"), mask_seq),
    Pair(("rostopic", "echo", "-n", "1", "--noarr", "/joints"), mask_seq),
    Pair(("rostopic", "echo", "-n", "1", "--filter", "m.data == 'hi'", "/chatter")),
    Pair(("rostopic", "echo", "-n", "1", "-p", "/pose"), mask_seq),
    Pair(("rostopic", "echo", "-n", "1", "-p", "/joints"), mask_seq),
    Pair(("rostopic", "echo", "-n", "1", "-p", "--nostr", "--noarr", "/joints"), mask_seq),
    Pair(("rostopic", "echo", "-n", "1", "-p", "/chatter"), _receive_time),
    Pair(("rostopic", "echo", "-n", "1", "/joints/name")),
    Pair(("rostopic", "echo", "-n", "1", "-p", "/joints/position"), _receive_time),
    Pair(("rostopic", "echo", "-n", "1", "--filter", "m.data == 'other'", "/chatter"), waits=True),
    Pair(("rostopic", "echo", "-n", "1", "--filter", "m.nope", "/chatter"), waits=True),
    Pair(("rostopic", "echo", "-n", "1", "/chatter/nope"), waits=True),
    Pair(("rostopic", "echo", "-n", "1", "/later"), waits=True),
    Pair(("rostopic", "echo", "-n", "1", "/later/data"), waits=True),
    Pair(("rostopic", "type", "/chatter/nope")),
    Pair(("rosnode", "list")),
    Pair(("rosnode", "list", "-u"), _node_ports),
    Pair(("rosnode", "list", "-a"), _node_ports),
    Pair(("rosnode", "info", "-q", "/fixture")),
    Pair(("rosnode", "info", "/nope")),
    Pair(("rosnode", "kill", "/nope")),
    Pair(("rosnode", "ping", "-c", "1", "/fixture"), _ping_time),
    Pair(("rosnode", "ping", "-c", "1", "/nope")),
    Pair(("rosnode", "machine")),
    Pair(("rosnode", "machine", "127.0.0.1")),
    Pair(("rosnode", "machine", "nohost.invalid")),
    Pair(("rosparam", "list")),
    Pair(("rosparam", "get", "/pid")),
    Pair(("rosparam", "get", "-p", "/pid")),
    Pair(("rosparam", "get", "-p", "/text")),
    Pair(("rosparam", "get", "/rate")),
    Pair(("rosparam", "get", "/nope")),
    Pair(("rosparam", "delete", "/nope")),
    Pair(("rosservice", "list")),
    Pair(("rosservice", "list", "-n")),
    Pair(("rosservice", "type", "/set")),
    Pair(("rosservice", "type", "/nope")),
    Pair(("rosservice", "uri", "/nope")),
    Pair(("rosservice", "info", "/set")),
    Pair(("rosservice", "info", "/nope")),
    Pair(("rosservice", "args", "/set_level")),
    Pair(("rosservice", "args", "/nope")),
    Pair(("rosservice", "find", "std_srvs/SetBool")),
    Pair(("rosservice", "call", "/set", "{data: true}")),
    Pair(("rosservice", "call", "--wait", "/set", "{data: false}")),
    Pair(("rosservice", "call", "/nope")),
    Pair(("rosservice", "call", "/set", "{dta: 1}")),
    Pair(("rosmsg", "show", "Twist"), needs_master=False),
    Pair(("rosmsg", "show", "Header"), needs_master=False),
    Pair(("rosmsg", "show", "geometry_msgs/PoseStamped"), needs_master=False),
    Pair(("rosmsg", "show", "-r", "std_msgs/Header"), needs_master=False),
    Pair(("rosmsg", "show", "Nope"), needs_master=False),
    Pair(("rosmsg", "show", "std_msgs/Nope"), needs_master=False),
    Pair(("rossrv", "show", "roscpp/SetLoggerLevel"), needs_master=False),
    Pair(("rossrv", "show", "GetLoggers"), needs_master=False),
]

_NO_SRV_FILES = (
    "Debian installs no .srv files, so rossrv finds no service type at all (and says `msg`); mros ships the "
    "definitions of the standard packages and shows them."
)

#: Pairs whose stdout or exit code differ on purpose, and why.
EXPLAINED: dict[str, str] = {
    "rossrv show roscpp/SetLoggerLevel": _NO_SRV_FILES,
    "rossrv show GetLoggers": _NO_SRV_FILES,
}


#: Pairs whose stderr differs on purpose (stdout and exit code still match), and why.
STDERR_EXPLAINED: dict[str, str] = {
    "rostopic echo -n 1 --filter m.nope /chatter": (
        "stderr: rostopic prints a traceback for every message the expression fails on, mros one warning line."
    ),
    "rosservice call /set '{dta: 1}'": (
        "stderr: mros names the field and the request type in one line where rosservice prints four; the "
        "`Service arguments are: [data]` hint after the blank line is the same."
    ),
    "rosmsg show std_msgs/Nope": (
        "stderr: mros says which definitions it searched (its built-in ones, the share directories) where "
        "rosmsg names rospack's package paths."
    ),
}


@dataclass
class Outcome:
    same: bool
    detail: str
    #: stderr too (not compared for commands that keep waiting: they are cut short at an arbitrary moment)
    same_stderr: bool = True


#: How long a command that waits (for a topic not published yet) is left running before its outcome is taken.
WAIT_TIME = 3.0
#: Pairs run this many at a time: the ones that read the graph first, then the others.
PARALLEL = 4


def _outcome(run: Callable[..., subprocess.CompletedProcess[str]], *args: object, waits: bool) -> tuple[object, ...]:
    """(exit code or 'still waiting', stdout, stderr) of one command."""
    try:
        done = run(*args, timeout=WAIT_TIME if waits else 60)
    except subprocess.TimeoutExpired as exc:
        if not waits:
            raise
        out = exc.output.decode() if isinstance(exc.output, bytes) else exc.output or ""
        err = exc.stderr.decode() if isinstance(exc.stderr, bytes) else exc.stderr or ""
        return ("still waiting", out, err)
    return (done.returncode, done.stdout, done.stderr)


def _run_pair(pair: Pair, master: str, tmp: Path) -> Outcome:
    with concurrent.futures.ThreadPoolExecutor(2) as pool:
        theirs_f = pool.submit(_outcome, ros_tool, master, tmp, *pair.ros, waits=pair.waits)
        ours_f = pool.submit(_outcome, mros, master, tmp, *pair.ours, waits=pair.waits)
        theirs, ours = theirs_f.result(), ours_f.result()
    norm = pair.normalize or (lambda text: text)
    a = (theirs[0], norm(str(theirs[1])))
    b = (ours[0], norm(str(ours[1])))
    detail = f"ROS {a!r} stderr {str(theirs[2])[-300:]!r}\nmros {b!r} stderr {str(ours[2])[-300:]!r}"
    # stderr of a command cut short after WAIT_TIME holds what it printed by then: timing, not behaviour
    same_stderr = pair.waits or norm(str(theirs[2])) == norm(str(ours[2]))
    return Outcome(a == b, detail, same_stderr)


def _run_pairs(master: str, tmp: Path, pairs: list[Pair]) -> dict[str, Outcome]:
    """Graph-reading pairs PARALLEL at a time, then (once they have all ended) the others PARALLEL at a time."""
    results: dict[str, Outcome] = {}
    for observers in (True, False):
        with concurrent.futures.ThreadPoolExecutor(PARALLEL) as pool:
            batch = {p.ros_text: pool.submit(_run_pair, p, master, tmp) for p in pairs if p.observes_graph is observers}
            results.update({text: future.result() for text, future in batch.items()})
    return results


def render_table(results: dict[str, dict[str, Outcome]]) -> str:
    lines = [
        "| ROS tool | mros | rosmaster | mrosd master | stderr | difference |",
        "|---|---|---|---|---|---|",
    ]
    for pair in PAIRS:
        cells = []
        stderr_same = True
        for master in ("rosmaster", "mrosd"):
            outcome = results[master].get(pair.ros_text) or results["none"][pair.ros_text]
            cells.append("same" if outcome.same else "differs")
            stderr_same = stderr_same and outcome.same_stderr
        note = " ".join(n for n in (EXPLAINED.get(pair.ros_text), STDERR_EXPLAINED.get(pair.ros_text)) if n)
        err = "same" if stderr_same else "differs"
        lines.append(f"| `{pair.ros_text}` | `{pair.ours_text}` | {cells[0]} | {cells[1]} | {err} | {note} |")
    return "\n".join(lines)


@pytest.mark.timeout(600)
def test_every_command_pair_matches_or_is_explained(procs: Processes, tmp_path: Path) -> None:
    online = [p for p in PAIRS if p.needs_master]
    offline = [p for p in PAIRS if not p.needs_master]
    results: dict[str, dict[str, Outcome]] = {}
    ours_master = start_our_master(procs)
    real_master = start_rosmaster(procs)
    start_rospy(procs, FIXTURE, real_master)
    start_rospy(procs, FIXTURE, ours_master)
    with concurrent.futures.ThreadPoolExecutor(3) as pool:
        real_f = pool.submit(_run_pairs, real_master, tmp_path / "real", online)
        ours_f = pool.submit(_run_pairs, ours_master, tmp_path / "ours", online)
        none_f = pool.submit(_run_pairs, real_master, tmp_path / "none", offline)
        results["rosmaster"], results["mrosd"], results["none"] = real_f.result(), ours_f.result(), none_f.result()

    problems = []
    for pair in PAIRS:
        for master in ("rosmaster", "mrosd"):
            outcome = results[master].get(pair.ros_text) or results["none"][pair.ros_text]
            if not outcome.same and pair.ros_text not in EXPLAINED:
                problems.append(f"{pair.ros_text} on {master} differs, unexplained:\n{outcome.detail}")
            if outcome.same and not outcome.same_stderr and pair.ros_text not in STDERR_EXPLAINED:
                problems.append(f"{pair.ros_text} on {master}: stderr differs, unexplained:\n{outcome.detail}")
        if pair.ros_text in EXPLAINED and all(
            (results[m].get(pair.ros_text) or results["none"][pair.ros_text]).same for m in ("rosmaster", "mrosd")
        ):
            problems.append(f"{pair.ros_text} is explained as a difference but matches on both masters")
    table = render_table(results)
    text = DOC.read_text(encoding="utf-8")
    assert BEGIN in text and END in text, "docs/cli.md lost its command-pair table markers"
    head, rest = text.split(BEGIN, 1)
    _old, tail = rest.split(END, 1)
    fresh = f"{head}{BEGIN}\n{table}\n{END}{tail}"
    if os.environ.get("MROS_WRITE_PAIRS") == "1":
        DOC.write_text(fresh, encoding="utf-8")
        text = fresh
    assert not problems, "\n\n".join(problems)
    assert fresh == text, "docs/cli.md's command-pair table is stale: rerun this test with MROS_WRITE_PAIRS=1"
