"""``mros bag record`` beside ``rosbag record``: messages recorded / offered, same publishers, same run.

Load (the issue's bar): a sensor_msgs/Image of 1 MB at 30 Hz on /camera/image plus std_msgs/String at
1 kHz on /small, from two roscpp publishers (bench.cli's, remapped; g++ and roscpp headers needed) on a real
Debian rosmaster. Each recorder runs alone in turn (the machine has 2 cores), for the same number of
seconds; the publishers start once the recorder is connected and print what they sent, the recorder is
stopped with SIGINT a second later, and the bag is counted with ``mrosd.bag`` (rosbags). Prints, for each
tool, recorded/offered per topic, the bag's size and the recorder's CPU seconds.

Run: ``python -m bench.bag [--seconds S]``.
"""

from __future__ import annotations

import argparse
import os
import resource
import signal
import subprocess
import sys
import time
from pathlib import Path
from tempfile import TemporaryDirectory

from bench.cli import build_cpp_publisher
from mrosd.bag.files import open_bag
from tests.rosenv import Processes, ros_available, ros_env, start_rosmaster

TOPICS = {"/camera/image": ("image", 30.0), "/small": ("string", 1000.0)}


def children_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def run_tool(tool: str, seconds: float, cpp: Path, tmp: Path) -> dict[str, object]:
    procs = Processes(tmp)
    try:
        master = start_rosmaster(procs)
        env = ros_env(master, tmp)
        out = tmp / f"{tool}.bag"
        if tool == "mros":
            argv = [sys.executable, "-m", "mros_cli.main", "bag", "record", *TOPICS, "-O", str(out), "--no-status"]
        else:
            argv = ["rosbag", "record", *TOPICS, "-O", str(out)]
        cpu0 = children_cpu()
        rec = procs.start(argv, env, stdout=subprocess.DEVNULL)
        pubs = {}
        for topic, (kind, rate) in TOPICS.items():
            pub_argv = [str(cpp), kind, str(rate), str(seconds), "1", f"/bench:={topic}"]
            pubs[topic] = procs.start(pub_argv, env, stderr=subprocess.DEVNULL)
        offered: dict[str, int] = {}
        for topic, pub in pubs.items():
            assert pub.stdout is not None
            line = pub.stdout.readline()
            if not line.startswith(b"connected"):
                raise RuntimeError(f"publisher of {topic} did not start: {line!r}")
        for topic, pub in pubs.items():
            assert pub.stdout is not None
            done = pub.stdout.readline().split()
            offered[topic] = int(done[1]) if len(done) == 3 else -1
        time.sleep(1.0)  # let the recorder take the last messages off its sockets
        os.killpg(rec.pid, signal.SIGINT)
        try:
            _, err = rec.communicate(timeout=60)
        except subprocess.TimeoutExpired:
            return {"error": "recorder did not stop within 60 s"}
        cpu = children_cpu() - cpu0
        reader = open_bag(str(out))
        try:
            counts = {t.topic: t.messages for t in reader.summary().topics}
        finally:
            reader.close()
        return {
            "offered": offered,
            "recorded": counts,
            "size": out.stat().st_size,
            "cpu": cpu,
            "stderr": err.decode(errors="replace").strip().splitlines()[-2:],
        }
    finally:
        procs.close()


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.bag", description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=12.0, help="publishing time per tool")
    args = parser.parse_args(argv)
    if not ros_available():
        print("bag: skipped (Debian ROS 1 is not installed)")
        return 0
    with TemporaryDirectory() as tmpdir:
        tmp = Path(tmpdir)
        cpp = build_cpp_publisher(tmp)
        if cpp is None:
            print("bag: skipped (the roscpp publisher needs g++ and the roscpp headers)")
            return 0
        print(f"publishers: roscpp; 1 MB Image at 30 Hz + String at 1 kHz, "
              f"{args.seconds:.0f} s per tool", flush=True)  # fmt: skip
        results = {}
        for tool in ("mros", "rosbag"):
            work = tmp / tool
            work.mkdir()
            results[tool] = run_tool(tool, args.seconds, cpp, work)
            report(tool, results[tool])
    return 0


def report(tool: str, result: dict[str, object]) -> None:
    if "error" in result:
        print(f"{tool:>7}: {result['error']}", flush=True)
        return
    offered = result["offered"]
    recorded = result["recorded"]
    assert isinstance(offered, dict) and isinstance(recorded, dict)
    parts = [f"{topic} {recorded.get(topic, 0)}/{offered[topic]}" for topic in TOPICS]
    size = result["size"]
    assert isinstance(size, int)
    print(f"{tool:>7} record: " + ", ".join(parts) + f" recorded/offered; {size / 2**20:.0f} MB; "
          f"cpu {result['cpu']:.1f} s", flush=True)  # fmt: skip


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
