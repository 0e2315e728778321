"""The ``mros`` CLI against rostopic/rosmsg, in the same run: start-up, then ``mros topic echo``'s throughput.

``startup``: with Debian's ``/usr/share`` on ``ROS_PACKAGE_PATH`` (as on a machine with ROS), the time from
starting ``mros topic pub`` / ``rostopic pub`` to their publisher's registration at a Debian rosmaster (seen by
polling ``getSystemState`` every 2 ms), and the wall time of ``mros msg show`` / ``rosmsg show``; the two tools
alternate, each round, and the medians are printed.

``mros topic echo`` against ``rostopic echo``: messages shown per second, same publisher, same run.
Two scenarios, each with a rospy publisher on a real Debian rosmaster and both echo processes subscribed at
once (so they see the same stream on the same machine):
  * ``string``: std_msgs/String at 10,000 msgs/s, then flat out (a roscpp publisher with no pacing), which
    offers more than either tool can show, so the ratio is each tool's capacity, not the publisher's rate;
  * ``image``:  sensor_msgs/Image of 1 MB (640x546 rgb8-ish, random bytes) at 30 Hz, then flat out.
Each echo's stdout is drained by a thread that counts rostopic's ``---`` separators; the rate is measured
over a window after a warm-up. Prints msgs/s for both tools, the publisher's actual rate, and the ratio.

Run: ``python -m bench.cli [--seconds S] [--scenario startup|string|image] [--rounds N]``.
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import threading
import time
import xmlrpc.client
from pathlib import Path
from tempfile import TemporaryDirectory

from tests.rosenv import ROS_PYTHON, Processes, ros_available, ros_env, start_rosmaster

PUBLISHER = r"""
import sys, time, os, rospy
from std_msgs.msg import String
from sensor_msgs.msg import Image
kind, seconds = sys.argv[1], float(sys.argv[2])
rospy.init_node("bench_pub", anonymous=True)
if kind == "string":
    pub = rospy.Publisher("/bench", String, queue_size=10000)
    msg = String(data="hello world, this is message payload")
    rate_hz, batch = 10000, 10
else:
    pub = rospy.Publisher("/bench", Image, queue_size=10)
    msg = Image(height=546, width=640, encoding="rgb8", step=640 * 3 // 1, data=os.urandom(1 << 20))
    rate_hz, batch = 30, 1
deadline = time.monotonic() + 20
while pub.get_num_connections() < 2 and time.monotonic() < deadline:
    time.sleep(0.05)
print("connected", flush=True)
period = batch / rate_hz
sent, start = 0, time.monotonic()
next_t = start
while time.monotonic() - start < seconds:
    for _ in range(batch):
        pub.publish(msg)
    sent += batch
    next_t += period
    delay = next_t - time.monotonic()
    if delay > 0:
        time.sleep(delay)
print("sent %d %.3f" % (sent, time.monotonic() - start), flush=True)
"""


#: The roscpp publisher: rospy alone cannot reach 10k msgs/s on this machine. Built once per run with g++.
CPP_PUBLISHER = r"""
#include <ros/ros.h>
#include <std_msgs/String.h>
#include <sensor_msgs/Image.h>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <thread>

int main(int argc, char** argv) {
  ros::init(argc, argv, "bench_cpp_pub", ros::init_options::AnonymousName);
  std::string kind = argv[1];
  double rate = atof(argv[2]), seconds = atof(argv[3]);
  int subs = atoi(argv[4]);
  ros::NodeHandle nh;
  ros::Publisher pub;
  std_msgs::String s;
  sensor_msgs::Image img;
  if (kind == "string") {
    pub = nh.advertise<std_msgs::String>("/bench", 100000);
    s.data = "hello world, this is message payload";
  } else {
    pub = nh.advertise<sensor_msgs::Image>("/bench", 10);
    img.height = 546;
    img.width = 640;
    img.encoding = "rgb8";
    img.step = 1920;
    img.data.resize(1 << 20);
    for (size_t i = 0; i < img.data.size(); ++i) img.data[i] = (uint8_t)rand();
  }
  auto until = std::chrono::steady_clock::now() + std::chrono::seconds(20);
  while ((int)pub.getNumSubscribers() < subs && std::chrono::steady_clock::now() < until)
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  printf("connected\n");
  fflush(stdout);
  // rate 0: flat out (no pacing), to offer more than either echo tool can show
  int batch = rate >= 1000 ? (int)(rate / 1000) : (rate <= 0 && kind == "string" ? 100 : 1);
  auto period = std::chrono::duration<double>(rate > 0 ? batch / rate : 0.0);
  auto start = std::chrono::steady_clock::now();
  auto next = start;
  long sent = 0;
  while (std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count() < seconds) {
    for (int i = 0; i < batch; ++i) {
      if (kind == "string") pub.publish(s); else pub.publish(img);
    }
    sent += batch;
    if (rate > 0) {
      next += std::chrono::duration_cast<std::chrono::steady_clock::duration>(period);
      std::this_thread::sleep_until(next);
    }
  }
  double elapsed = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  printf("sent %ld %.3f\n", sent, elapsed);
  fflush(stdout);
  return 0;
}
"""

CPP_LIBS = ["-lroscpp", "-lrostime", "-lcpp_common", "-lroscpp_serialization", "-lrosconsole"]


def build_cpp_publisher(workdir: Path) -> Path | None:
    """Compile the roscpp publisher; None when g++ or the roscpp headers are missing."""
    if shutil.which("g++") is None or not Path("/usr/include/ros/ros.h").exists():
        return None
    src = workdir / "bench_pub.cpp"
    exe = workdir / "bench_pub"
    src.write_text(CPP_PUBLISHER)
    out = subprocess.run(["g++", "-O2", "-o", str(exe), str(src), *CPP_LIBS], capture_output=True, check=False)
    return exe if out.returncode == 0 else None


class Counter:
    """Drains a process's stdout in a thread, counting rostopic's message separators."""

    def __init__(self, proc: subprocess.Popen[bytes]) -> None:
        self.count = 0
        self.stamps: list[tuple[float, int]] = []
        self._proc = proc
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        assert self._proc.stdout is not None
        tail = b""
        fd = self._proc.stdout.fileno()
        while True:
            chunk = os.read(fd, 1 << 20)
            if not chunk:
                return
            data = tail + chunk
            self.count += data.count(b"\n---\n") - tail.count(b"\n---\n")
            tail = data[-8:]
            self.stamps.append((time.monotonic(), self.count))

    def rate_between(self, t0: float, t1: float) -> float:
        """Messages per second shown between two monotonic instants."""

        def count_at(t: float) -> int:
            best = 0
            for stamp, count in self.stamps:
                if stamp > t:
                    break
                best = count
            return best

        return (count_at(t1) - count_at(t0)) / (t1 - t0)


def scenario(kind: str, seconds: float, warmup: float, cpp: Path | None, rate: float) -> tuple[float, float, float]:
    """(mros msgs/s, rostopic msgs/s, published msgs/s) for one scenario."""
    with TemporaryDirectory() as tmp:
        procs = Processes(Path(tmp))
        try:
            master = start_rosmaster(procs)
            env = ros_env(master, Path(tmp))
            ours_env = dict(env, PATH=os.path.dirname(sys.executable) + ":" + env["PATH"])
            ours = procs.start([sys.executable, "-m", "mros_cli.main", "topic", "echo", "/bench"], ours_env)
            theirs = procs.start(["rostopic", "echo", "/bench"], env)
            counters = {"mros": Counter(ours), "rostopic": Counter(theirs)}
            duration = str(seconds + warmup)
            argv = [str(cpp), kind, str(rate), duration, "2"] if cpp else [ROS_PYTHON, "-c", PUBLISHER, kind, duration]
            pub = procs.start(argv, env, stderr=subprocess.DEVNULL)
            assert pub.stdout is not None
            line = pub.stdout.readline()
            if not line.startswith(b"connected"):
                raise RuntimeError(f"publisher did not start: {line!r}")
            t0 = time.monotonic() + warmup
            t1 = t0 + seconds
            done = pub.stdout.readline().split()
            sent = int(done[1]) / float(done[2]) if len(done) == 3 else float("nan")
            time.sleep(0.5)
            return counters["mros"].rate_between(t0, t1), counters["rostopic"].rate_between(t0, t1), sent
        finally:
            procs.close()


def registered_after(argv: list[str], env: dict[str, str], master: str, topic: str, limit: float = 30.0) -> float:
    """Seconds from starting ``argv`` to ``topic`` having a publisher at ``master``; the process is then killed."""
    proxy = xmlrpc.client.ServerProxy(master)
    start = time.monotonic()
    proc = subprocess.Popen(argv, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        while time.monotonic() - start < limit:
            publishers = proxy.getSystemState("/bench")[2][0]
            if any(name == topic for name, _ in publishers):
                return time.monotonic() - start
            if proc.poll() is not None:
                raise RuntimeError(f"{argv[0]} exited with {proc.returncode} before registering {topic}")
            time.sleep(0.002)
        raise RuntimeError(f"{argv[0]} did not register {topic} within {limit} s")
    finally:
        proxy("close")()
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def wall_time(argv: list[str], env: dict[str, str]) -> float:
    """Seconds ``argv`` runs to completion (it must succeed)."""
    start = time.monotonic()
    subprocess.run(argv, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, timeout=60, check=True)
    return time.monotonic() - start


def startup(rounds: int) -> None:
    """Start-up rows: ``pub`` to registration and ``msg show``, mros and the ROS tool alternating each round."""
    with TemporaryDirectory() as tmp:
        procs = Processes(Path(tmp))
        try:
            master = start_rosmaster(procs)
            env = ros_env(master, Path(tmp), ROS_PACKAGE_PATH="/usr/share")
            mros = [os.path.join(os.path.dirname(sys.executable), "mros")]
            times: dict[str, list[float]] = {"mros pub": [], "rostopic pub": [], "mros show": [], "rosmsg show": []}
            for i in range(rounds):
                pub = ["topic", "pub", "-r", "1"]
                args = ["std_msgs/String", "data: hi"]
                times["mros pub"].append(registered_after([*mros, *pub, f"/m{i}", *args], env, master, f"/m{i}"))
                times["rostopic pub"].append(
                    registered_after(["rostopic", "pub", "-r", "1", f"/r{i}", *args], env, master, f"/r{i}")
                )
                times["mros show"].append(wall_time([*mros, "msg", "show", "std_msgs/String"], env))
                times["rosmsg show"].append(wall_time(["rosmsg", "show", "std_msgs/String"], env))
        finally:
            procs.close()
    med = {name: statistics.median(values) for name, values in times.items()}
    for what, ours, theirs in (
        ("pub to registration", "mros pub", "rostopic pub"),
        ("msg show", "mros show", "rosmsg show"),
    ):
        print(
            f"startup {what:22s} mros {med[ours]:6.3f} s  {theirs.split()[0]} {med[theirs]:6.3f} s"
            f"  ratio {med[theirs] / med[ours]:5.2f}x  (median of {rounds}, ROS_PACKAGE_PATH=/usr/share)",
            flush=True,
        )


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.cli", description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=8.0, help="measurement window per scenario")
    parser.add_argument("--warmup", type=float, default=2.0)
    parser.add_argument("--scenario", choices=["startup", "string", "image"], action="append")
    parser.add_argument("--rounds", type=int, default=5, help="start-up rounds (each tool, alternating)")
    parser.add_argument(
        "--string-rate",
        type=float,
        action="append",
        help="String messages per second (repeatable; 0 = flat out; default 10000, then flat out for capacity)",
    )
    parser.add_argument(
        "--image-rate",
        type=float,
        action="append",
        help="1 MB images per second (repeatable; 0 = flat out; default 30, then flat out for capacity)",
    )
    args = parser.parse_args(argv)
    if not ros_available():
        print("cli: skipped, Debian ROS (rostopic, rospy) is not installed")
        return 0
    scenarios = args.scenario or ["startup", "string", "image"]
    if "startup" in scenarios:
        startup(args.rounds)
    scenarios = [kind for kind in scenarios if kind != "startup"]
    if not scenarios:
        return 0
    with TemporaryDirectory() as build:
        cpp = build_cpp_publisher(Path(build))
        print(f"publisher: {'roscpp' if cpp else 'rospy (g++ or roscpp headers missing)'}", flush=True)
        for kind in scenarios:
            # 0 = flat out: the publisher offers more than either tool shows, so the ratio is capacity
            rates = (args.string_rate or [10000.0, 0.0]) if kind == "string" else (args.image_rate or [30.0, 0.0])
            if cpp is None:
                rates = [r for r in rates if r > 0]  # the rospy fallback publisher paces itself
            for rate in rates:
                report(kind, rate, *scenario(kind, args.seconds, args.warmup, cpp, rate))
    return 0


def report(kind: str, rate: float, ours: float, theirs: float, sent: float) -> None:
    """One line per scenario with the ratio."""
    ratio = ours / theirs if theirs > 0 else float("inf")
    pace = f"@{rate:g}/s" if rate > 0 else "flat out"
    label = f"std_msgs/String {pace}" if kind == "string" else f"sensor_msgs/Image 1 MB {pace}"
    print(
        f"echo {label:30s} published {sent:8.1f}/s  mros {ours:8.1f} msgs/s  rostopic {theirs:8.1f} msgs/s"
        f"  ratio {ratio:5.1f}x",
        flush=True,
    )


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
