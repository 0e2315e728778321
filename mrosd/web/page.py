"""The page mrosd serves at ``/`` of its Foxglove port: the graph, topics, live values, plots and images.

The page is one more Foxglove WebSocket client of the same server (no second data path): it decodes ROS 1
bodies in the browser from the ``message_definition`` the server advertises. Its assets are package data
under ``mrosd/web/static/`` (hand-written modules, no build step, no CDN: the robot may be offline).

``asset()`` is the pure core of serving them: a name is served only if it matches ``ASSET_NAME`` (one path
segment of safe characters and a known suffix) and is one of the files shipped, so no request path can name
anything outside the folder (``..``, ``/``, ``%2f``, NUL and absolute paths never match).
"""

from __future__ import annotations

import functools
import importlib.resources
import re

from aiohttp import web

__all__ = ["ASSET_NAME", "CONTENT_TYPES", "asset", "page_routes"]

#: Content type of each suffix served (anything else is not an asset).
CONTENT_TYPES = {
    ".html": "text/html; charset=utf-8",
    ".js": "text/javascript; charset=utf-8",
    ".css": "text/css; charset=utf-8",
    ".svg": "image/svg+xml",
}
#: What an asset name may look like: one segment, no dot-dot, a known suffix.
ASSET_NAME = re.compile(r"[a-z0-9][a-z0-9_-]{0,63}\.(?:html|js|css|svg)")


@functools.cache
def _shipped() -> frozenset[str]:
    root = importlib.resources.files("mrosd.web") / "static"
    return frozenset(p.name for p in root.iterdir() if p.is_file() and ASSET_NAME.fullmatch(p.name))


def asset(name: str) -> tuple[bytes, str] | None:
    """The bytes and content type of shipped asset ``name``, or None (not a valid name, or not shipped)."""
    if not ASSET_NAME.fullmatch(name) or name not in _shipped():
        return None
    data = (importlib.resources.files("mrosd.web") / "static" / name).read_bytes()
    return data, CONTENT_TYPES[name[name.rindex(".") :]]


def _response(name: str) -> web.Response:
    found = asset(name)
    if found is None:
        raise web.HTTPNotFound(text="no such asset\n")
    data, content_type = found
    # no-cache: a daemon upgrade must not leave an old module in the browser next to a new one
    return web.Response(
        body=data,
        headers={
            "Content-Type": content_type,
            "Cache-Control": "no-cache",
            "X-Content-Type-Options": "nosniff",
        },
    )


def index() -> web.Response:
    """The page itself (``GET /`` without a WebSocket upgrade)."""
    return _response("index.html")


async def _static(request: web.Request) -> web.Response:
    return _response(request.match_info["name"])


def page_routes(app: web.Application) -> None:
    """Add ``/static/{name}`` to ``app`` (``/`` is shared with the WebSocket handler, see ``WebServer``)."""
    app.router.add_get("/static/{name}", _static)
