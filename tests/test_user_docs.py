"""The user docs stay short and current: the README within 250 lines, its links resolving, and
no history told session by session (that is git's and CHANGELOG.md's). The docs site itself is
checked by ``mkdocs build --strict`` (``scripts/docs.sh``): a broken link or anchor fails it."""

from __future__ import annotations

import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
README = REPO / "README.md"
README_MAX_LINES = 250
# "session 12", "issue 22 item 4": the lab notebook's way of dating a figure.
HISTORY = re.compile(r"\b(session|issue)s? \d", re.I)
LINK = re.compile(r"\]\(([^)\s#]+)(#[^)]*)?\)")


def user_pages() -> list[Path]:
    return [README, REPO / "CHANGELOG.md", REPO / "ARCHITECTURE.md", *sorted((REPO / "docs").rglob("*.md"))]


def test_readme_is_short() -> None:
    lines = README.read_text(encoding="utf-8").count("\n")
    assert lines <= README_MAX_LINES, f"README.md has {lines} lines (at most {README_MAX_LINES}): move detail to docs/"


def test_readme_links_resolve() -> None:
    missing = [target for target, _ in LINK.findall(README.read_text(encoding="utf-8"))
               if not target.startswith(("http://", "https://")) and not (REPO / target).exists()]
    assert not missing, f"README.md links to files that do not exist: {missing}"


def test_no_history_in_user_docs() -> None:
    found = [f"{page.relative_to(REPO)}:{number}: {line.strip()}"
             for page in user_pages()
             for number, line in enumerate(page.read_text(encoding="utf-8").splitlines(), start=1)
             if HISTORY.search(line)]
    assert not found, "history in the user docs (keep current figures; history is git's):\n  " + "\n  ".join(found)


def test_the_history_pattern_catches_a_session_line() -> None:
    assert HISTORY.search("measured in session 12's flights") and HISTORY.search("Issue 22 item 4")
    assert not HISTORY.search("a session of PX4 SITL")
