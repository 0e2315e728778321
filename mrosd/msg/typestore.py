"""Where message and service definitions come from: type name -> spec, md5, full text.

Search order for ``pkg/Type``: the definitions shipped inside mrosd (so the standard types work with no
ROS installed), then ``-I pkg:dir`` includes, then packages under ``$ROS_PACKAGE_PATH`` (directories with
a package.xml), then the system share directories Debian and ROS installs use (``/usr/share/<pkg>``,
``/opt/ros/*/share/<pkg>``). Specs are parsed once per store and cached with their md5s.
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterable, Sequence
from pathlib import Path

from mrosd.errors import MsgNotFoundError, MsgParseError
from mrosd.msg.md5 import compute_md5, compute_srv_md5, full_text
from mrosd.msg.parser import is_valid_type_name, parse_msg, parse_srv
from mrosd.msg.spec import HEADER, HEADER_FULL_NAME, MsgSpec, SrvSpec

#: The definitions shipped in the package (copied verbatim from Debian's ROS packages).
BUILTIN_DIR = Path(__file__).resolve().parent / "definitions"

#: Roots searched last, as ``<root>/<pkg>/msg/<Type>.msg``.
SYSTEM_SHARE_DIRS: tuple[str, ...] = ("/usr/share", "/opt/ros/*/share")

#: How deep a ROS_PACKAGE_PATH walk looks for package.xml files.
MAX_PACKAGE_DEPTH = 6

_PACKAGE_NAME = re.compile(r"<name>\s*([^<\s]+)\s*</name>")


def normalize_type_name(name: str, kind: str = "msg") -> str:
    """``Header`` -> ``std_msgs/Header``; check the ``pkg/Type`` form.

    Raises:
        MsgNotFoundError: the name is not of the form ``pkg/Type``.
    """
    name = name.strip()
    if name == HEADER:
        return HEADER_FULL_NAME
    if name.count("/") != 1 or not is_valid_type_name(name):
        raise MsgNotFoundError(f"invalid {kind} type name {name!r}: expected 'package/Type'")
    return name


def parse_include(text: str) -> tuple[str, Path]:
    """Parse a ``-I pkg:dir`` argument (dir is the package directory or its msg/ directory)."""
    pkg, sep, directory = text.partition(":")
    if not sep or not pkg or not directory:
        raise MsgNotFoundError(f"invalid include {text!r}: expected PACKAGE:DIRECTORY")
    return pkg, Path(directory)


class TypeStore:
    """Finds, parses and caches definitions; the lookup every md5, full text and class goes through."""

    def __init__(
        self,
        includes: Sequence[tuple[str, Path]] = (),
        *,
        builtin: bool = True,
        ros_package_path: str | None = None,
        system_dirs: Sequence[str] | None = None,
    ) -> None:
        self.includes = list(includes)
        self.builtin = builtin
        self.ros_package_path = os.environ.get("ROS_PACKAGE_PATH", "") if ros_package_path is None else ros_package_path
        self.system_dirs = SYSTEM_SHARE_DIRS if system_dirs is None else tuple(system_dirs)
        self._msgs: dict[str, MsgSpec] = {}
        self._srvs: dict[str, SrvSpec] = {}
        self._md5: dict[str, str] = {}
        self._packages: dict[str, list[Path]] | None = None
        self._walked: dict[str, dict[str, list[Path]]] = {}

    # ----------------------------------------------------------------------------------------- search
    def _rpp_packages(self) -> dict[str, list[Path]]:
        """Every package on ``ROS_PACKAGE_PATH``: name -> directories, in search order (walks every root)."""
        if self._packages is None:
            found: dict[str, list[Path]] = {}
            for root in filter(None, self.ros_package_path.split(os.pathsep)):
                for pkg, paths in self._root_packages(root).items():
                    found.setdefault(pkg, []).extend(paths)
            self._packages = found
        return self._packages

    def _root_packages(self, root: str) -> dict[str, list[Path]]:
        """The packages under one ``ROS_PACKAGE_PATH`` root (walked once per store)."""
        packages = self._walked.get(root)
        if packages is None:
            packages = {}
            for pkg, path in _walk_packages(Path(root)):
                packages.setdefault(pkg, []).append(path)
            self._walked[root] = packages
        return packages

    def _lazy_dirs(self, package: str, kind: str) -> Iterable[Path]:
        """``package_dirs`` as a generator that walks as little as it can: per ``ROS_PACKAGE_PATH`` root, a
        package directory right under it that declares ``package`` stands for the walk of that root (Debian's
        ``/usr/share``, catkin's ``share`` and most workspaces keep packages there); a root without one is
        walked (once). A package found early costs no walk at all."""
        if self.builtin:
            yield BUILTIN_DIR / package / kind
        for pkg, directory in self.includes:
            if pkg == package:
                yield directory / kind if (directory / kind).is_dir() else directory
        for root in filter(None, self.ros_package_path.split(os.pathsep)):
            direct = Path(root) / package
            if root not in self._walked and _package_name(direct / "package.xml") == package:
                yield direct / kind
                continue
            for path in self._root_packages(root).get(package, []):
                yield path / kind
        for pattern in self.system_dirs:
            for system_root in sorted(_glob(pattern)):
                yield Path(system_root) / package / kind

    def package_dirs(self, package: str, kind: str) -> list[Path]:
        """Directories that may hold ``<Type>.<kind>`` for ``package``, in search order."""
        dirs: list[Path] = []
        if self.builtin:
            dirs.append(BUILTIN_DIR / package / kind)
        for pkg, directory in self.includes:
            if pkg == package:
                dirs.append(directory / kind if (directory / kind).is_dir() else directory)
        dirs += [p / kind for p in self.package_roots(package)]
        return dirs

    def package_roots(self, package: str) -> list[Path]:
        """Where ``package`` itself may be, in search order: its directories on ``ROS_PACKAGE_PATH``, then
        ``<system dir>/<package>`` (which may not exist, or hold no ``package.xml``). Also where the web part
        resolves ``package://`` asset URIs, so that an asset is found where the package's types are."""
        roots = list(self._rpp_packages().get(package, []))
        for pattern in self.system_dirs:
            roots += [Path(root) / package for root in sorted(_glob(pattern))]
        return roots

    def find(self, name: str, kind: str) -> Path:
        """The file defining ``pkg/Type`` (kind ``msg`` or ``srv``).

        The order of ``package_dirs``, found lazily (``_lazy_dirs``): the standard types never walk
        ``ROS_PACKAGE_PATH``, which with Debian's ``/usr/share`` on it reads thousands of directories.

        Raises:
            MsgNotFoundError: no search directory has it.
        """
        pkg, _, short = name.partition("/")
        filename = f"{short}.{kind}"
        for directory in self._lazy_dirs(pkg, kind):
            candidate = directory / filename
            if candidate.is_file():
                return candidate
        where = ["mrosd's builtin definitions"] if self.builtin else []
        where += [f"-I {p}:{d}" for p, d in self.includes]
        if self.ros_package_path:
            where.append(f"ROS_PACKAGE_PATH={self.ros_package_path}")
        where += list(self.system_dirs)
        raise MsgNotFoundError(f"unknown {kind} type {name!r} (searched {', '.join(where)})")

    # ------------------------------------------------------------------------------------------ specs
    def msg_spec(self, name: str) -> MsgSpec:
        """The parsed definition of a message type (``pkg/TypeRequest`` works for services' halves).

        Raises:
            MsgNotFoundError: unknown type.
            MsgParseError: the definition file is malformed.
        """
        name = normalize_type_name(name)
        spec = self._msgs.get(name)
        if spec is not None:
            return spec
        for suffix in ("Request", "Response"):
            if name.endswith(suffix) and name not in self._msgs:
                try:
                    srv = self.srv_spec(name[: -len(suffix)])
                except MsgNotFoundError:
                    continue
                return srv.request if suffix == "Request" else srv.response
        path = self.find(name, "msg")
        spec = parse_msg(_read(path), name, str(path))
        self._msgs[name] = spec
        return spec

    def srv_spec(self, name: str) -> SrvSpec:
        """The parsed definition of a service type.

        Raises:
            MsgNotFoundError: unknown type.
            MsgParseError: the definition file is malformed.
        """
        name = normalize_type_name(name, "srv")
        spec = self._srvs.get(name)
        if spec is None:
            path = self.find(name, "srv")
            spec = parse_srv(_read(path), name, str(path))
            self._srvs[name] = spec
            self._msgs[spec.request.full_name] = spec.request
            self._msgs[spec.response.full_name] = spec.response
        return spec

    def add(self, spec: MsgSpec) -> None:
        """Register a spec parsed elsewhere (a message_definition); it shadows files of the same name."""
        self._msgs[spec.full_name] = spec
        self._md5.pop(spec.full_name, None)

    def md5(self, name: str) -> str:
        """The genmsg md5sum of a message type."""
        spec = self.msg_spec(name)
        return compute_md5(spec, self.msg_spec, self._md5)

    def srv_md5(self, name: str) -> str:
        """The genmsg md5sum of a service type."""
        return compute_srv_md5(self.srv_spec(name), self.msg_spec, self._md5)

    def full_text(self, name: str) -> str:
        """The message_definition genpy would send for a message type."""
        return full_text(self.msg_spec(name), self.msg_spec)

    # ------------------------------------------------------------------------------------------- list
    def list_types(self, kind: str = "msg") -> list[str]:
        """Every ``pkg/Type`` of ``kind`` that the search path can find (sorted, first definition wins)."""
        names: set[str] = set()
        roots: list[tuple[str, Path]] = []
        if self.builtin and BUILTIN_DIR.is_dir():
            roots += [(p.name, p / kind) for p in BUILTIN_DIR.iterdir()]
        roots += [(pkg, d / kind if (d / kind).is_dir() else d) for pkg, d in self.includes]
        for pkg, paths in self._rpp_packages().items():
            roots += [(pkg, p / kind) for p in paths]
        for pattern in self.system_dirs:
            for root in _glob(pattern):
                if Path(root).is_dir():
                    roots += [(p.name, p / kind) for p in Path(root).iterdir()]
        for pkg, directory in roots:
            if directory.is_dir():
                names.update(f"{pkg}/{f.stem}" for f in directory.glob(f"*.{kind}"))
        return sorted(names)


def _read(path: Path) -> str:
    try:
        return path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise MsgParseError(f"cannot read definition: {exc}", str(path)) from None


def _glob(pattern: str) -> Iterable[str]:
    if "*" not in pattern:
        return [pattern]
    import glob

    return glob.glob(pattern)


def _package_name(manifest: Path) -> str | None:
    """The ``<name>`` a package.xml declares; None when there is no readable manifest or it names nothing."""
    try:
        text = manifest.read_text(encoding="utf-8", errors="replace")
    except OSError:
        return None
    match = _PACKAGE_NAME.search(text)
    return match.group(1) if match else None


def _walk_packages(root: Path, depth: int = 0) -> Iterable[tuple[str, Path]]:
    """(name, dir) of every ROS package under ``root`` (a dir with package.xml; not below another one)."""
    manifest = root / "package.xml"
    try:
        if manifest.is_file():
            yield (_package_name(manifest) or root.name), root
            return
        if depth >= MAX_PACKAGE_DEPTH or (root / "CATKIN_IGNORE").exists():
            return
        children = sorted(p for p in root.iterdir() if p.is_dir() and not p.name.startswith("."))
    except OSError:
        return
    for child in children:
        yield from _walk_packages(child, depth + 1)
