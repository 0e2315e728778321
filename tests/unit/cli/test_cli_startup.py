"""`mros --help` and `mros msg` start light: listing every noun's help never loads aiohttp or the TCPROS stack."""

from __future__ import annotations

import subprocess
import sys

PROBE = r"""
import sys
from click.testing import CliRunner
from mros_cli.main import cli
for argv in (["--help"], ["topic", "--help"], ["node", "--help"], ["msg", "md5", "std_msgs/String"]):
    result = CliRunner().invoke(cli, argv)
    assert result.exit_code == 0, (argv, result.output)
heavy = sorted(m for m in sys.modules if m == "aiohttp" or m.startswith("mrosd.tcpros"))
print(",".join(heavy))
"""


def test_help_and_msg_commands_do_not_import_aiohttp_or_tcpros() -> None:
    out = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True, timeout=60, check=False)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == ""
