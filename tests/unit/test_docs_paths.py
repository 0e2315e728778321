"""Every file or folder the docs point to exists: README.md and docs/*.md are checked against the tree.

A path is a token with a slash that ends in a file name with an extension (`mrosd/wire/framing.py`) or in a
slash (`mrosd/bag/`). It is looked up from the repository root; a Markdown link target (`[x](embedding.md)`)
from the folder of the page that holds it. Absolute paths (`/run/mrosd/ixm.sock`), URLs, `~`/`$` paths and
ROS names (`std_msgs/String`: no extension, no trailing slash) are not repository paths and are skipped.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PAGES = sorted([ROOT / "README.md", *(ROOT / "docs").glob("*.md")])

#: Folders that programs create when they run (ignored by git): a fresh checkout has neither them nor their files.
CREATED_AT_RUN_TIME = ("bench/out/",)

_EXTENSIONS = "py|md|toml|service|sh|txt|cfg|ini|yaml|yml|json|msg|srv|png|svg"
_PATH = re.compile(rf"(?<![\w./~$:/@-])((?:[A-Za-z_.][\w.-]*/)+(?:[\w-][\w.-]*\.(?:{_EXTENSIONS}))?)(?![\w/{{*(<-])")
_LINK = re.compile(r"\]\(([^)#\s]+)(?:#[^)]*)?\)")


def paths_in(text: str) -> set[str]:
    """The repository paths a page mentions, link targets excluded (they resolve elsewhere)."""
    text = _LINK.sub("]()", text)
    return {m for m in _PATH.findall(text) if "/" in m and not m.startswith("./")}


def links_in(text: str) -> set[str]:
    """Relative Markdown link targets (URLs excluded)."""
    return {t for t in _LINK.findall(text) if "://" not in t and not t.startswith("mailto:")}


def test_the_extractor_finds_paths_and_skips_what_is_not_one() -> None:
    text = (
        "`mrosd/wire/framing.py` and mrosd/bag/ but not /run/mrosd/ixm.sock, std_msgs/String, "
        "http://localhost:11311/, ~/.ros/log/, OUT/<pkg>/msg/ or $XDG_RUNTIME_DIR/mrosd/x.sock; "
        "see [the map](architecture.md)"
    )
    assert paths_in(text) == {"mrosd/wire/framing.py", "mrosd/bag/"}
    assert links_in(text) == {"architecture.md"}


def test_the_pages_exist() -> None:
    assert ROOT / "README.md" in PAGES and len(PAGES) > 5


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_path_a_page_mentions_exists(page: Path) -> None:
    text = page.read_text(encoding="utf-8")
    missing = sorted(p for p in paths_in(text) if not p.startswith(CREATED_AT_RUN_TIME) and not (ROOT / p).exists())
    missing += sorted(t for t in links_in(text) if not (page.parent / t).exists())
    assert not missing, f"{page.relative_to(ROOT)} points to paths that do not exist: {missing}"
