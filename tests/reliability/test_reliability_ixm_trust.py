"""Who may stand where: the IXM runtime directory, an impostor daemon, and what a listing shows to whom.

Needs root: another user owns the hostile directory, runs the impostor and lists keys.
"""

from __future__ import annotations

import os
import socket
import stat
from pathlib import Path
from typing import Any

import pytest

from mrosd.errors import IxmError
from mrosd.ixm.client import IxmClient
from mrosd.ixm.protocol import Ok, encode
from mrosd.ixm.server import IxmServer
from tests.integration.ixm.conftest import start_daemon
from tests.integration.ixm.hostile import Child, nobody, shared_dir
from tests.rosenv import Processes

pytestmark = pytest.mark.root


async def refused(path: str) -> str:
    server = IxmServer(path)
    try:
        await server.start()
    except IxmError as exc:
        return str(exc)
    finally:
        await server.aclose()
    return "started"


async def test_a_socket_directory_owned_by_another_user_is_refused_with_the_fix() -> None:
    user = nobody()
    with shared_dir() as tmp:
        hostile = Path(tmp) / "run"
        hostile.mkdir(mode=0o755)
        os.chown(hostile, user.pw_uid, user.pw_gid)
        message = await refused(str(hostile / "ixm.sock"))
        assert str(hostile) in message and "owned by uid" in message and "\n" not in message, message


async def test_a_socket_directory_that_is_a_symlink_is_refused() -> None:
    user = nobody()
    with shared_dir() as tmp:
        target = Path(tmp) / "theirs"
        target.mkdir(mode=0o700)
        os.chown(target, user.pw_uid, user.pw_gid)
        link = Path(tmp) / "run"
        link.symlink_to(target)
        message = await refused(str(link / "ixm.sock"))
        assert str(link) in message and "symlink" in message, message
        assert not (target / "ixm.sock").exists()


async def test_a_socket_directory_writable_by_others_is_refused() -> None:
    with shared_dir() as tmp:
        open_dir = Path(tmp) / "run"
        open_dir.mkdir()
        os.chmod(open_dir, 0o777)
        message = await refused(str(open_dir / "ixm.sock"))
        assert str(open_dir) in message and "writable" in message, message


async def test_a_missing_socket_directory_is_created_private() -> None:
    with shared_dir() as tmp:
        new = Path(tmp) / "fresh"
        server = IxmServer(str(new / "ixm.sock"))
        await server.start()
        try:
            st = os.lstat(new)
            assert stat.S_ISDIR(st.st_mode) and st.st_mode & 0o777 == 0o700 and st.st_uid == os.geteuid()
        finally:
            await server.aclose()


def test_a_client_refuses_a_daemon_run_by_an_untrusted_uid() -> None:
    """An impostor of another uid answers on the socket: root's client must not trust it."""
    user = nobody()
    with shared_dir() as tmp:
        run = Path(tmp) / "run"
        run.mkdir(mode=0o755)
        os.chown(run, user.pw_uid, user.pw_gid)
        path = str(run / "ixm.sock")

        def impostor(report: Any) -> dict[str, Any]:
            listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            listener.bind(path)
            os.chmod(path, 0o666)
            listener.listen(8)
            listener.settimeout(10)
            report({"listening": True})
            conn, _ = listener.accept()
            conn.settimeout(5)
            conn.recv(4096)
            conn.sendall(encode(Ok()))  # answers Hello like a daemon would
            conn.recv(4096)
            return {"served": True}

        child = Child(user, impostor)
        try:
            child.line()
            child.go()
            with pytest.raises(IxmError) as excinfo:
                IxmClient(path, timeout=3).close()
            message = str(excinfo.value)
            assert f"uid {user.pw_uid}" in message and path in message and "\n" not in message, message
        finally:
            child.close()


def test_a_listing_shows_each_user_only_the_keys_its_rules_let_it_open(procs: Processes) -> None:
    user = nobody()
    with shared_dir() as tmp:
        config = Path(tmp) / "mrosd.toml"
        config.write_text(f'[ixm.rules]\ndefault = "deny"\n[ixm.rules.keys."/public"]\nread_uids = [{user.pw_uid}]\n')
        path = os.path.join(tmp, "ixm.sock")
        start_daemon(procs, path, str(config))
        with IxmClient(path, name="rootproc") as ixm:
            ixm.open("/secret", "float64", mode="w").write(1.0)
            ixm.open("/public", "float64", mode="w").write(2.0)

            def lister(report: Any) -> dict[str, Any]:
                with IxmClient(path, name="snoop") as c:
                    listing = c.list()
                    one = c.list("/secret")
                return {
                    "keys": sorted(s.key for s in listing.segments),
                    "processes": sorted((p.name, sorted(p.keys)) for p in listing.processes),
                    "secret": [s.key for s in one.segments] + [p.name for p in one.processes],
                }

            child = Child(user, lister)
            try:
                seen = child.line()
            finally:
                child.close()
            everything = ixm.list()
        assert seen["keys"] == ["/public"]
        assert ["rootproc", ["/public"]] in seen["processes"]
        assert all("/secret" not in keys for _name, keys in seen["processes"])
        assert seen["secret"] == []
        assert sorted(s.key for s in everything.segments) == ["/public", "/secret"]  # root sees all
