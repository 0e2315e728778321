"""The distribution a user installs: built with ``python -m build``, installed non-editable into a fresh venv,
run from outside the source tree.

An editable install (every other test's) reads the package data and the licences from the checkout, so a file
missing from the wheel or the sdist shows only here: the page's assets, the message definitions, the notices
of the vendored definitions, ``mrosd`` and ``mros`` as console scripts of that venv.
"""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
import tarfile
import urllib.request
import venv
import zipfile
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.integration.daemon.daemonproc import NotifyListener
from tests.rosenv import Processes, free_port

ROOT = Path(__file__).resolve().parents[2]

pytestmark = [
    pytest.mark.skipif(
        importlib.util.find_spec("build") is None, reason="needs the 'build' package ([dev] installs it)"
    ),
    # building twice (sdist, then the wheel from it) and installing the dependencies into a fresh venv take
    # half a minute or more on an idle machine, longer than the suite's 120 s per test on a busy one
    pytest.mark.timeout(900),
]


class Dist:
    """The built sdist and wheel, and a venv with the wheel installed."""

    def __init__(self, out: Path) -> None:
        (self.sdist,) = out.glob("mrosd-*.tar.gz")
        (self.wheel,) = out.glob("mrosd-*.whl")
        self.venv = out / "venv"
        self.bin = self.venv / "bin"


@pytest.fixture(scope="module")
def dist(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Dist]:
    out = tmp_path_factory.mktemp("dist")
    # sdist first, then the wheel from the unpacked sdist (build's default): a file the sdist lacks fails here
    built = subprocess.run(
        [sys.executable, "-m", "build", "--outdir", str(out), str(ROOT)],
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    assert built.returncode == 0, built.stdout[-3000:] + built.stderr[-3000:]
    d = Dist(out)
    # The venv gets no pip of its own (ensurepip costs 5-17 s): this pip installs into it (`--python`, pip 22.3+),
    # the wheel and its dependencies resolved as a user's pip would. --no-compile: the test imports a few modules
    # only, so byte-compiling every installed file (pip's default) would be most of the install's time.
    venv.EnvBuilder(with_pip=False).create(d.venv)
    installed = subprocess.run(
        [sys.executable, "-m", "pip", "--python", str(d.bin / "python"), "install", "-q", "--no-compile", str(d.wheel)],
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    assert installed.returncode == 0, installed.stdout[-3000:] + installed.stderr[-3000:]
    yield d


def test_the_wheel_carries_the_licence_the_notices_the_page_and_the_definitions(dist: Dist) -> None:
    with zipfile.ZipFile(dist.wheel) as whl:
        names = set(whl.namelist())
        metadata = next(n for n in names if n.endswith(".dist-info/METADATA"))
        meta = whl.read(metadata).decode()
    info = metadata.rsplit("/", 1)[0]
    assert f"{info}/licenses/LICENSE" in names
    notices = {n for n in names if n.startswith(f"{info}/licenses/mrosd/msg/definitions/")}
    packages = {p.name for p in (ROOT / "mrosd" / "msg" / "definitions").iterdir() if p.is_dir()}
    assert {n.split("/")[-2] for n in notices} == packages  # one notice per vendored package
    assert "License-Expression: BSD-3-Clause" in meta.splitlines()
    assert "mrosd/web/static/index.html" in names
    assert "mrosd/msg/definitions/std_msgs/msg/String.msg" in names


def test_the_sdist_carries_docs_examples_packaging_tests_and_the_licence(dist: Dist) -> None:
    with tarfile.open(dist.sdist) as tar:
        names = {n.split("/", 1)[1] for n in tar.getnames() if "/" in n}
    for wanted in ("LICENSE", "README.md", "docs/daemon.md", "packaging/mrosd.service", "examples/talker.py"):
        assert wanted in names
    assert "tests/packaging/test_wheel_install.py" in names
    assert "mrosd/msg/definitions/std_msgs/copyright" in names
    assert not any("node_modules" in n or "__pycache__" in n for n in names)


def test_the_installed_daemon_serves_the_page_and_a_pub_echo_round_trip_from_outside_the_tree(
    dist: Dist, tmp_path: Path, procs: Processes, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)  # nothing of the checkout on sys.path: only the venv's copy can be imported
    drop = ("ROS_", "MROSD_", "NOTIFY_", "PYTHON", "VIRTUAL_ENV")
    env = {k: v for k, v in os.environ.items() if not k.startswith(drop)}
    env["PATH"] = f"{dist.bin}{os.pathsep}{env.get('PATH', '')}"
    where = subprocess.run(
        [str(dist.bin / "python"), "-c", "import mrosd, mros_cli; print(mrosd.__file__); print(mros_cli.__file__)"],
        capture_output=True,
        text=True,
        env=env,
        timeout=60,
        check=True,
    )
    assert all(Path(line).is_relative_to(dist.venv) for line in where.stdout.split()), where.stdout

    master_port, web_port = free_port(), free_port()
    notify = NotifyListener(tmp_path)
    try:
        daemon_env = dict(
            env,
            NOTIFY_SOCKET=notify.path,
            MROSD_IXM_SOCKET=str(tmp_path / "ixm.sock"),
            MROSD_WEB_PORT=str(web_port),
            MROSD_WEB_ROSBRIDGE_PORT="-1",
            ROS_LOG_DIR=str(tmp_path / "log"),
        )
        daemon = procs.start([str(dist.bin / "mrosd"), "--port", str(master_port)], daemon_env)
        notify.until("READY=1", timeout=30)
        assert daemon.poll() is None
    finally:
        notify.close()

    with urllib.request.urlopen(f"http://127.0.0.1:{web_port}/", timeout=10) as page:
        assert page.status == 200
        assert b"<html" in page.read().lower()

    ros = dict(env, ROS_MASTER_URI=f"http://127.0.0.1:{master_port}/", ROS_HOSTNAME="127.0.0.1")
    ros["MROSD_IXM_SOCKET"] = daemon_env["MROSD_IXM_SOCKET"]
    echo = procs.start([str(dist.bin / "mros"), "topic", "echo", "/chatter", "-n", "1"], ros)
    procs.start(
        [str(dist.bin / "mros"), "topic", "pub", "/chatter", "std_msgs/String", "data: round trip", "-r", "5"], ros
    )
    out, err = echo.communicate(timeout=60)
    assert echo.returncode == 0, err.decode()
    assert b"data: " in out and b"round trip" in out
