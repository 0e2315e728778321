"""The asyncio client against an in-process IxmServer: async for woken on each write, zero-copy views."""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest

from mrosd import backports
from mrosd.errors import IxmError, IxmPermissionError
from mrosd.ixm import AccessRules, AsyncIxmClient, IxmClient
from mrosd.ixm.server import IxmServer
from tests.integration.ixm.conftest import ShmGuard


async def test_async_for_yields_each_write_without_polling(shm_guard: ShmGuard, tmp_path: Path) -> None:
    sock = str(tmp_path / "ixm.sock")
    async with IxmServer(sock), AsyncIxmClient(sock) as a, AsyncIxmClient(sock) as b:
        reader = await b.open("/speed", "float32")
        writer = await a.open("/speed", "float32", mode="w")
        got: asyncio.Queue[float] = asyncio.Queue(maxsize=10)
        waiting = asyncio.Event()

        async def consume() -> None:
            waiting.set()
            async for value in reader:
                await got.put(value)
                if value == 3.0:
                    return

        task = asyncio.create_task(consume())
        async with backports.timeout(5):
            await waiting.wait()
            for v in (1.0, 2.0, 3.0):
                writer.write(v)
                assert await got.get() == v
            await task
        with pytest.raises(TimeoutError):
            await reader.wait(timeout=0.05)
        listing = await a.list("/speed")
        assert [s.key for s in listing.segments] == ["/speed"]
        await reader.close()
        await writer.close()


async def test_a_raw_array_is_written_and_read_through_zero_copy_views(shm_guard: ShmGuard, tmp_path: Path) -> None:
    sock = str(tmp_path / "ixm.sock")
    async with IxmServer(sock), AsyncIxmClient(sock) as a:
        img = await a.open("/image", "uint8", max_size=1024, mode="rw")
        with img.writing() as view:
            view[:4] = b"\x01\x02\x03\x04"
        assert img.seq == 2
        view = img.view()
        assert (view.readonly, view.format, len(view), bytes(view[:4])) == (True, "B", 1024, b"\x01\x02\x03\x04")
        view.release()
        out = bytearray(1024)
        assert img.read_into(out) == 1024
        joints = await a.open("/joints", "float64", count=3, mode="w")
        with joints.writing() as jv:
            jv[1] = 2.5
        assert joints.view().tolist() == [0.0, 2.5, 0.0]
        with pytest.raises(IxmError, match="zero-copy"):
            (await a.open("/scalar", "float64", mode="w")).view()


async def test_a_view_keeps_the_value_it_was_taken_of_across_one_flip_and_partial_writes_keep_the_rest(
    shm_guard: ShmGuard, tmp_path: Path
) -> None:
    sock = str(tmp_path / "ixm.sock")
    async with IxmServer(sock), AsyncIxmClient(sock) as a:
        joints = await a.open("/joints", "float64", count=3, mode="rw")
        joints.write([1.0, 2.0, 3.0])
        seq = joints.seq
        old = joints.view()
        with joints.writing() as jv:  # starts from the published value: only element 0 changes
            jv[0] = 9.0
        assert joints.read() == [9.0, 2.0, 3.0]
        # the old view does not follow the flip, and its slot is untouched until the write after this one
        assert old.tolist() == [1.0, 2.0, 3.0] and joints.seq <= (seq | 1) + 1
        new = joints.view()
        assert new.tolist() == [9.0, 2.0, 3.0]
        joints.write([4.0, 5.0, 6.0])  # the write after: old's slot now holds the newest value
        assert joints.seq > (seq | 1) + 1
        assert old.tolist() == [4.0, 5.0, 6.0] and new.tolist() == [9.0, 2.0, 3.0]
        old.release()
        new.release()
        await joints.close()


async def test_reloaded_rules_apply_to_later_opens(shm_guard: ShmGuard, tmp_path: Path) -> None:
    sock = str(tmp_path / "ixm.sock")
    async with IxmServer(sock, {"default": "deny"}) as server, AsyncIxmClient(sock) as a:
        # this test runs as the daemon's own uid, which is always allowed: take that away for the check
        server.registry.rules = AccessRules(default="deny", superusers=frozenset())
        with pytest.raises(IxmPermissionError, match="may not read /x"):
            await a.open("/x", "float64")
        server.reload_rules({"default": "allow"})
        key = await a.open("/x", "float64", mode="rw")
        key.write(1.0)
        assert key.read() == 1.0


async def test_a_client_over_a_cap_gets_the_daemons_one_line_reason_sync_or_async(tmp_path: Path) -> None:
    sock = str(tmp_path / "ixm.sock")
    async with IxmServer(sock, max_clients_per_uid=1, max_keys_per_uid=1), AsyncIxmClient(sock) as first:
        await first.open("/one", "int32", mode="w")
        with pytest.raises(IxmError, match=r"holds 1 IXM keys, the per-user limit \(max_keys_per_uid\)"):
            await first.open("/two", "int32", mode="w")
        with pytest.raises(IxmError, match=r"already has 1 IXM connections, the per-user limit") as exc:
            await AsyncIxmClient(sock).connect()
        assert "\n" not in str(exc.value)
        loop = asyncio.get_running_loop()
        with pytest.raises(IxmError, match=r"the per-user limit \(max_clients_per_uid\)"):
            await loop.run_in_executor(None, lambda: IxmClient(sock, timeout=2))
