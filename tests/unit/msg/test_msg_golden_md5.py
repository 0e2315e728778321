"""Golden genmsg values for every shipped definition, checked with no ROS installed.

tests/data/msg/genmsg_md5.json was produced by Debian's genmsg (tests/interop/msg/genpy_oracle.py md5):
the md5sum of every message and service, and the md5 of each message's full definition text.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

from mrosd.msg.typestore import TypeStore

GOLDEN = Path(__file__).resolve().parents[2] / "data" / "msg" / "genmsg_md5.json"


def test_every_shipped_type_has_genmsgs_md5_and_definition_text() -> None:
    golden = json.loads(GOLDEN.read_text())
    store = TypeStore(ros_package_path="", system_dirs=())  # shipped definitions only
    assert len(golden) >= 150
    wrong = []
    for key, expected in golden.items():
        kind, name = key.split(":")
        if kind == "msg":
            got = {"md5": store.md5(name), "full_text_md5": hashlib.md5(store.full_text(name).encode()).hexdigest()}
        else:
            srv = store.srv_spec(name)
            got = {
                "md5": store.srv_md5(name),
                "request_md5": store.md5(srv.request.full_name),
                "response_md5": store.md5(srv.response.full_name),
            }
        if got != expected:
            wrong.append(key)
    assert wrong == []
