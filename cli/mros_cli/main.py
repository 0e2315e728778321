"""The root click group `mros`; each noun lives in its own module and is added here.

Also owns what every noun shares: the global ``--master-uri`` option, running one coroutine per command,
the clients of the master (``master_client``, a ``mrosd.master.client.MasterClient``) and of nodes'
slave APIs (``slave_call``), user-typed name resolution (``resolve_name``, via ``mrosd.names``) and the exit
codes scripts rely on: 0 success, 1 error (on stderr ``ERROR: ...`` as rostopic, rosparam, rosnode and
rosservice print it, with their hint after a blank line where they give one), 2 usage error (click's, and
where rosservice exits 2), 130 interrupted (143 after SIGTERM).
"""

from __future__ import annotations

import importlib
import importlib.util
import os
import sys
from collections.abc import Coroutine
from typing import TYPE_CHECKING, Any, NoReturn, TypeVar

import click

from mrosd.errors import MasterError, MasterUnreachableError, MrosError

if TYPE_CHECKING:
    from mrosd.master.client import MasterClient
    from mrosd.xmlrpc import XmlRpcClient

#: noun -> module that defines a click group named ``group`` (imported lazily so `mros msg` never pays for
#: aiohttp and `mros topic` never pays for the codegen until it needs it).
SUBCOMMANDS = {
    "topic": "mros_cli.topic",
    "msg": "mros_cli.msg",
    "srv": "mros_cli.srv",
    "param": "mros_cli.param",
    "node": "mros_cli.node",
    "service": "mros_cli.service",
    "ixm": "mros_cli.ixm",
    "daemon": "mros_cli.daemon",
    "bag": "mros_cli.bag",
    "graph": "mros_cli.graph",
    "bridge": "mros_cli.bridge",
    "fleet": "mros_cli.fleet",
    "ros2": "mros_cli.ros2",
    "web": "mros_cli.web",
    "action": "mros_cli.action",
    "tf": "mros_cli.tf",
    "reconfigure": "mros_cli.reconfigure",
}

EXIT_OK = 0
EXIT_ERROR = 1
EXIT_USAGE = 2
EXIT_INTERRUPTED = 130

#: What the CLI calls itself on the graph (as rostopic uses /rostopic_<pid>_<ms>).
CALLER_ID = f"/mros_{os.getpid()}"

#: Bound on one call to the master or to a node's slave API from the CLI.
CALL_TIMEOUT = 5.0

T = TypeVar("T")


def master_uri_from_env() -> str:
    """``$ROS_MASTER_URI`` or roscore's default."""
    return os.environ.get("ROS_MASTER_URI") or "http://localhost:11311/"


def master_uri(ctx: click.Context | None = None) -> str:
    """The master URI chosen for this invocation (``--master-uri`` or the environment)."""
    ctx = ctx or click.get_current_context(silent=True)
    while ctx is not None:
        if isinstance(ctx.obj, dict) and ctx.obj.get("master_uri"):
            return str(ctx.obj["master_uri"])
        ctx = ctx.parent
    return master_uri_from_env()


def resolve_name(name: str) -> str:
    """A graph name typed by the user, resolved as rostopic/rosparam do (relative to ``$ROS_NAMESPACE``)."""
    from mrosd.names import script_resolve

    return script_resolve(name, "mros")


def anonymous(name: str) -> str:
    """rostopic's anonymous node names: ``mros_<name>_<pid>_<ms>``."""
    import time

    return f"mros_{name}_{os.getpid()}_{int(time.time() * 1000)}"


def master_client(xmlrpc: XmlRpcClient | None = None) -> MasterClient:
    """A ``MasterClient`` for this invocation's master URI, as ``CALLER_ID``, bounded by ``CALL_TIMEOUT``.

    Without ``xmlrpc`` it owns (and ``aclose()`` closes) its own XML-RPC client; pass one to share it
    with slave API calls (``slave_call``). Imported here, not at module top, so ``mros --help`` and
    ``mros msg`` never load aiohttp.
    """
    from mrosd.master.client import MasterClient

    return MasterClient(master_uri(), CALLER_ID, xmlrpc, timeout=CALL_TIMEOUT)


async def slave_call(xmlrpc: XmlRpcClient, uri: str, method: str, *args: Any, timeout: float | None = None) -> Any:
    """Call a node's slave API ``method`` as ``CALLER_ID`` and return the value of a code-1 answer.

    Raises:
        MasterError: the node answered with a failure code or a malformed triple.
        XmlRpcError: the node is unreachable, timed out or sent a fault.
    """
    from mrosd.master.client import unwrap_reply  # here: the CLI's start-up does not import the XML-RPC stack

    reply = await xmlrpc.call(uri, method, CALLER_ID, *args, timeout=CALL_TIMEOUT if timeout is None else timeout)
    return unwrap_reply(method, reply)


def run(coro: Coroutine[Any, Any, T]) -> T:
    """Run one command's coroutine on a fresh loop chosen by ``mrosd.loop`` (uvloop unless ``MROSD_LOOP=asyncio``).

    SIGINT and SIGTERM, once or repeatedly, cancel it (``mrosd.app.run_until_signal``): its nodes unregister
    and close, then ``StopSignal`` (a ``KeyboardInterrupt``) ends the command quietly: 130 or 143, as a shell
    reports the signal, or 0 where Ctrl-C is the normal end.
    """
    from mrosd.app import Interrupted, run_until_signal

    try:
        return run_until_signal(coro)
    except Interrupted as stop:
        raise StopSignal(stop.signum) from None


class StopSignal(KeyboardInterrupt):
    """SIGINT or SIGTERM ended a command's coroutine, after its clean-up. A ``KeyboardInterrupt``, so the
    commands that end normally on Ctrl-C (echo, hz, bw, delay) end normally on SIGTERM too; the others exit
    128 + ``signum`` (130, 143)."""

    def __init__(self, signum: int) -> None:
        super().__init__()
        self.signum = signum


#: What rostopic, rosparam, rosnode and rosservice print when the master does not answer.
MASTER_UNREACHABLE = "Unable to communicate with master!"


class HintedError(MrosError):
    """An error the ROS tools print with a hint after a blank line (rostopic pub's ``Args are: [x y z]``)."""

    def __init__(self, message: str, hint: str) -> None:
        super().__init__(message)
        self.hint = hint


def error_text(message: str, hint: str = "") -> str:
    """``ERROR: message`` (the ROS tools' prefix), then ``hint`` after a blank line when there is one."""
    return f"ERROR: {message}\n\n{hint}" if hint else f"ERROR: {message}"


def fail(message: str, code: int = EXIT_ERROR, hint: str = "") -> NoReturn:
    """Print the error on stderr as the ROS tools do and exit with ``code`` (1 unless a ROS tool exits
    otherwise there)."""
    click.echo(error_text(message, hint), err=True)
    sys.exit(code)


class LazyGroup(click.Group):
    """Imports each subcommand module only when it is used."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted(name for name, mod in SUBCOMMANDS.items() if importlib.util.find_spec(mod) is not None)

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        module_name = SUBCOMMANDS.get(cmd_name)
        if module_name is None or importlib.util.find_spec(module_name) is None:
            return None
        module = importlib.import_module(module_name)
        command: click.Command = module.group
        return command

    def invoke(self, ctx: click.Context) -> Any:
        try:
            return super().invoke(ctx)
        except MasterUnreachableError as exc:
            # rostopic's line, then what it leaves out: which URI and why (ROS_MASTER_URI wrong, master down)
            fail(MASTER_UNREACHABLE, hint=" ".join(exc.status.split()))
        except MasterError as exc:
            fail(exc.status)
        except MrosError as exc:
            # (HintedError by its attribute: under ``python -m mros_cli.main`` this module is loaded twice)
            fail(" ".join(str(exc).split()), hint=getattr(exc, "hint", ""))
        except KeyboardInterrupt as exc:
            # (StopSignal by its attribute, as HintedError above)
            signum = getattr(exc, "signum", None)
            sys.exit(128 + signum if isinstance(signum, int) else EXIT_INTERRUPTED)
        except BrokenPipeError:
            # `mros topic echo ... | head` closed the pipe: not an error for the user.
            try:
                sys.stdout = open(os.devnull, "w")  # noqa: SIM115  (silence the flush at exit)
            except OSError:
                pass
            sys.exit(EXIT_OK)
        return None


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.option(
    "--master-uri",
    envvar="ROS_MASTER_URI",
    default="http://localhost:11311/",
    show_default=True,
    metavar="URI",
    help="ROS master to talk to (default: $ROS_MASTER_URI).",
)
@click.version_option(package_name="mrosd")
@click.pass_context
def cli(ctx: click.Context, master_uri: str) -> None:
    """mros: talk to a ROS 1 graph (topics, messages, parameters, nodes, services, IXM).

    \b
    Exit codes: 0 success, 1 error (one line on stderr), 2 usage error.
    Shell completion (bash): eval "$(_MROS_COMPLETE=bash_source mros)"
    \b
    Examples:
      mros topic list -v
      mros topic echo /chatter -n 1
      mros topic pub /chatter std_msgs/String "data: hi" -r 10
      mros msg show geometry_msgs/PoseStamped
      mros param get /robot_description
      mros node list
    """
    ctx.ensure_object(dict)
    ctx.obj["master_uri"] = master_uri


if __name__ == "__main__":
    cli(prog_name="mros")
