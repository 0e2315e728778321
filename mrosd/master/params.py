"""The parameter tree as pure data, and which parameter subscribers to tell about a change.

``ParamTree`` stores XML-RPC values in nested dicts (a dict is a namespace); keys arrive resolved
and global. ``param_updates`` computes the ``paramUpdate`` notifications for a set or delete with
rosmaster's rules: subscribers of the key or of any parent get ``(key/, value)``; when a namespace
(dict) is written or deleted, subscribers of keys below it get their new sub-value, or ``{}`` when it
is gone. Subscription keys and notified keys carry a trailing ``/``, as rosmaster sends them.
One deliberate difference: a scalar written over a namespace also tells the subscribers below it
(rosmaster forgets them).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from mrosd.master.registry import Notification, param_update

SEP = "/"


def split_key(key: str) -> list[str]:
    """The non-empty components of a global key: ``/a//b/`` -> ``['a', 'b']``."""
    return [p for p in key.split(SEP) if p]


def subscription_key(key: str) -> str:
    """The canonical form a parameter subscription is stored under: ``/a/b`` -> ``/a/b/``."""
    parts = split_key(key)
    return SEP + SEP.join(parts) + SEP if parts else SEP


class ParamTree:
    """Nested dict of parameters; every method takes a resolved global key."""

    def __init__(self) -> None:
        self.root: dict[str, Any] = {}
        #: Bumped by every ``set``/``delete`` (the HTTP layer's reply cache is valid for one version).
        self.version = 0

    def get(self, key: str) -> Any:
        """The value at ``key`` (a dict for a namespace).

        Raises:
            KeyError: nothing is set at ``key``.
        """
        value: Any = self.root
        for part in split_key(key):
            if not isinstance(value, dict) or part not in value:
                raise KeyError(key)
            value = value[part]
        return value

    def has(self, key: str) -> bool:
        """Whether anything is set at ``key``."""
        try:
            self.get(key)
        except KeyError:
            return False
        return True

    def set(self, key: str, value: Any) -> None:
        """Set ``key``; a dict replaces the whole namespace; scalars in the way become namespaces.

        Raises:
            TypeError: the root is set to something other than a dict.
        """
        self.version += 1
        parts = split_key(key)
        if not parts:
            if not isinstance(value, dict):
                raise TypeError("cannot set root of parameter tree to non-dictionary")
            self.root = value
            return
        node = self.root
        for part in parts[:-1]:
            child = node.get(part)
            if not isinstance(child, dict):
                child = {}
                node[part] = child
            node = child
        node[parts[-1]] = value

    def delete(self, key: str) -> None:
        """Delete ``key`` and everything below it.

        Raises:
            KeyError: nothing is set at ``key``, or ``key`` is the root.
        """
        self.version += 1
        parts = split_key(key)
        if not parts:
            raise KeyError("cannot delete root of parameter tree")
        node: Any = self.root
        for part in parts[:-1]:
            if not isinstance(node, dict) or part not in node:
                raise KeyError(key)
            node = node[part]
        if not isinstance(node, dict) or parts[-1] not in node:
            raise KeyError(key)
        del node[parts[-1]]

    def names(self) -> list[str]:
        """Every leaf key; an empty namespace (one emptied by deletes, too) is not listed, as in rosmaster."""
        out: list[str] = []

        def walk(prefix: str, node: dict[str, Any]) -> None:
            for k, v in node.items():
                full = prefix + k
                if isinstance(v, dict):
                    walk(full + SEP, v)
                else:
                    out.append(full)

        walk(SEP, self.root)
        return out

    def search(self, namespace: str, key: str) -> str | None:
        """rosmaster's searchParam: the first namespace, from ``namespace`` upwards, holding ``key``'s head.

        ``namespace`` is the caller's node name or namespace (global). A global ``key`` is returned
        only if set. For a relative ``key`` such as ``a/b`` the search looks for ``a`` in the caller's
        namespace and then each parent, and returns ``<that namespace>/a/b`` whether or not ``b`` exists.

        Raises:
            ValueError: ``key`` is empty or private, or ``namespace`` is not global.
        """
        if not key or key.startswith("~"):
            raise ValueError("invalid key")
        if not namespace.startswith(SEP):
            raise ValueError("namespace must be global")
        if key.startswith(SEP):
            return key if self.has(key) else None
        key_parts = split_key(key)
        head = key_parts[0]
        ns_parts = split_key(namespace)
        for depth in range(len(ns_parts), -1, -1):
            prefix = ns_parts[:depth]
            if self.has(SEP + SEP.join([*prefix, head])):
                return SEP + SEP.join([*prefix, *key_parts])
        return None


def _all_subkeys(key: str, value: Mapping[str, Any], out: dict[str, Any]) -> None:
    """Collect ``{key/child/: subvalue}`` for every namespace and leaf below ``key`` (which ends in ``/``)."""
    for k, v in value.items():
        sub = key + k + SEP
        out[sub] = v
        if isinstance(v, dict):
            _all_subkeys(sub, v, out)


def param_updates(
    subscribers: Mapping[str, Mapping[str, str]],
    key: str,
    value: Any,
    *,
    had_subtree: bool = True,
    ignore_node: str | None = None,
) -> list[Notification]:
    """The paramUpdate calls owed after ``key`` was set to ``value`` (``{}`` means deleted).

    Args:
        subscribers: ``{subscription key (ending in /): {node: api}}``.
        key: the resolved key that was set or deleted.
        value: the new value; ``{}`` for a delete.
        had_subtree: whether something may have existed below ``key`` before (for scalar writes).
        ignore_node: the caller of a set: it is not told about its own change of a key it watches.
    """
    if not subscribers:
        return []
    pkey = subscription_key(key)
    below: dict[str, Any] | None = None
    if isinstance(value, dict):
        below = {}
        _all_subkeys(pkey, value, below)
    out: list[Notification] = []
    for sub_key, nodes in subscribers.items():
        if pkey.startswith(sub_key):
            for node, api in nodes.items():
                if node != ignore_node:
                    out.append(param_update(api, pkey, value))
        elif sub_key.startswith(pkey):
            if below is None:
                if had_subtree:
                    out.extend(param_update(api, sub_key, {}) for api in nodes.values())
            elif sub_key in below:
                out.extend(param_update(api, sub_key, below[sub_key]) for api in nodes.values())
            else:
                out.extend(param_update(api, sub_key, {}) for api in nodes.values())
    return out
