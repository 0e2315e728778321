"""fetchAsset's cores: which URIs parse (``parse_asset_uri``, hypothesis over any text), the response layout,
the size checks of a read, the byte budget, the allow-list's default, and ``TypeStore.package_roots``."""

from __future__ import annotations

import asyncio
import os
import posixpath
import re
import struct
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from mrosd import backports
from mrosd.msg.typestore import TypeStore
from mrosd.web import foxglove as fg
from mrosd.web.access import DEFAULT_ASSETS, AccessPolicy
from mrosd.web.assets import AssetRef, AssetRefused, _Budget, _read_frame, parse_asset_uri

ROOT = "/ws/robot_pkg"


def test_a_package_uri_splits_into_package_and_segments() -> None:
    assert parse_asset_uri("package://robot_pkg/meshes/base link.STL") == AssetRef(
        "robot_pkg", ("meshes", "base link.STL")
    )
    assert parse_asset_uri("package://my-robot_2/urdf/r.urdf").package == "my-robot_2"


@pytest.mark.parametrize(
    ("uri", "why"),
    [
        ("file:///etc/passwd", "file:// URIs are not served"),
        ("https://example.com/a.stl", "https:// URIs are not served"),
        ("/etc/passwd", "without a scheme"),
        ("package://robot_pkg/../x.stl", "'..'"),
        ("package://robot_pkg/a..b.stl", "'..'"),
        ("package://../x.stl", "'..'"),
        ("package:///etc/passwd", "invalid package name"),
        ("package://./x.stl", "invalid package name"),
        ("package://robot_pkg", "no path"),
        ("package://robot_pkg/", "no path"),
        ("package://robot_pkg//etc/passwd", "invalid path segment"),
        ("package://robot_pkg/./x.stl", "invalid path segment"),
        ("package://robot_pkg/a\\b.stl", "invalid path segment"),
        ("package://robot_pkg/a\x00.stl", "invalid path segment"),
        ("package://robot_pkg/x.stl/", "invalid path segment"),
        ("package://robot_pkg/" + "a/" * 64 + "x.stl", "more than 64"),
    ],
)
def test_uris_that_could_leave_a_package_are_refused_with_a_reason(uri: str, why: str) -> None:
    with pytest.raises(AssetRefused, match=re.escape(why)):
        parse_asset_uri(uri)


@given(st.one_of(st.text(max_size=120), st.text(max_size=120).map(lambda t: "package://" + t)))
def test_any_text_parses_to_a_path_inside_the_package_or_is_refused(uri: str) -> None:
    try:
        ref = parse_asset_uri(uri)
    except AssetRefused:
        return
    joined = posixpath.normpath(posixpath.join(ROOT, *ref.path))
    assert joined.startswith(ROOT + "/"), (uri, joined)
    assert "/" not in ref.package and ref.package not in ("", ".", "..")
    for segment in ref.path:
        assert segment not in ("", ".", "..") and "/" not in segment and "\\" not in segment and "\x00" not in segment


@given(st.integers(0, 0xFFFFFFFF), st.text(max_size=50))
def test_fetch_asset_response_layout(request_id: int, message: str) -> None:
    assert fg.fetch_asset_head(request_id) == struct.pack("<BIBI", 4, request_id, 0, 0)
    frame = fg.fetch_asset_error(request_id, message)
    op, rid, status, n = struct.unpack_from("<BIBI", frame)
    assert (op, rid, status) == (4, request_id, 1)
    assert frame[10:].decode() == message.encode("utf-8", "replace").decode() and len(frame) == 10 + n


def test_a_read_stops_at_the_stat_size_and_refuses_a_file_that_changed(tmp_path: Path) -> None:
    path = tmp_path / "mesh.stl"
    path.write_bytes(b"0123456789")
    head = fg.fetch_asset_head(1)
    fd = os.open(path, os.O_RDONLY)
    try:
        assert _read_frame(fd, 10, head) == bytearray(head + b"0123456789")
        os.lseek(fd, 0, os.SEEK_SET)
        with pytest.raises(AssetRefused, match="longer"):
            _read_frame(fd, 4, head)  # the file grew after its stat: never read past what was reserved
        os.lseek(fd, 0, os.SEEK_SET)
        with pytest.raises(AssetRefused, match="shorter"):
            _read_frame(fd, 20, head)
    finally:
        os.close(fd)


async def test_the_budget_waits_for_room_then_refuses_as_busy() -> None:
    budget = _Budget(100)
    await budget.acquire(80, 1.0)
    waiter = asyncio.get_running_loop().create_task(budget.acquire(30, 5.0))
    await asyncio.sleep(0.01)
    assert not waiter.done()
    budget.release(80)
    await backports.wait_for(waiter, 1.0)
    assert budget.held == 30
    with pytest.raises(AssetRefused, match="busy"):
        await budget.acquire(80, 0.05)
    assert budget.held == 30


def test_the_default_allow_list_serves_meshes_textures_and_descriptions_only() -> None:
    policy = AccessPolicy()
    assert policy.assets == list(DEFAULT_ASSETS)
    for uri in ("package://r/meshes/a.stl", "package://r/m/b.STL", "package://r/urdf/r.urdf", "package://r/t.png"):
        assert policy.allows_asset(uri), uri
    for uri in ("package://r/config/secrets.yaml", "package://r/package.xml", "file:///x.stl", "package://r/a.stl.gz"):
        assert not policy.allows_asset(uri), uri
    assert not AccessPolicy(assets=[]).allows_asset("package://r/a.stl")


def test_package_roots_are_the_type_searchs_package_directories(tmp_path: Path) -> None:
    pkg = tmp_path / "ws" / "src" / "robot_pkg"
    (pkg / "msg").mkdir(parents=True)
    (pkg / "package.xml").write_text("<package><name>robot_pkg</name></package>")
    share = tmp_path / "share"
    store = TypeStore(ros_package_path=str(tmp_path / "ws"), system_dirs=[str(share)], builtin=False)
    assert store.package_roots("robot_pkg") == [pkg, share / "robot_pkg"]
    assert store.package_dirs("robot_pkg", "msg") == [pkg / "msg", share / "robot_pkg" / "msg"]
