"""Every relative link in the Markdown docs leads somewhere: the file exists and, where the link names a
heading (``file.md#anchor``), the file has that heading (GitHub's anchor rules). Docs are moved and split
(the results' evidence lives in ``docs/results/*/analysis.md``); a link left pointing at the old place fails
here, not in a reader's browser."""

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = sorted([ROOT / "README.md", ROOT / "CHANGELOG.md", *(ROOT / "docs").rglob("*.md")])
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")  # [text](target) and ![alt](target)


def prose(path: Path) -> str:
    """``path``'s text without its fenced code blocks (what they hold is neither a heading nor a link)."""
    return re.sub(r"^```.*?^```", "", path.read_text(), flags=re.S | re.M)


def anchors(path: Path) -> set[str]:
    """The anchors GitHub gives the headings of ``path``: lower case, punctuation dropped, spaces to hyphens,
    ``-1``, ``-2``... for repeats. Headings inside fenced code are not headings."""
    text = prose(path)
    seen: dict[str, int] = {}
    out = set()
    for title in re.findall(r"^#{1,6}\s+(.+?)\s*#*\s*$", text, flags=re.M):
        slug = re.sub(r"[^\w\- ]", "", title.lower().replace("`", "")).replace(" ", "-")
        n = seen.get(slug, 0)
        seen[slug] = n + 1
        out.add(slug if n == 0 else f"{slug}-{n}")
    return out


def links(path: Path) -> list[str]:
    return LINK.findall(re.sub(r"`[^`\n]*`", "", prose(path)))  # inline code is not a link


def test_anchor_rules():
    page = ROOT / "README.md"
    assert "how-our-data-differs-from-the-papers" in anchors(page)
    assert "table-2-offline-to-online-on-a1" in anchors(page)  # "### Table 2, offline-to-online, on A1"


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_resolve(doc):
    broken = []
    for target in links(doc):
        if re.match(r"[a-z]+:", target):  # http:, https:, mailto: ... are not checked (no network)
            continue
        file, _, anchor = target.partition("#")
        dest = (doc.parent / file).resolve() if file else doc
        if not dest.exists():
            broken.append(f"{target} (no file {dest.relative_to(ROOT) if dest.is_relative_to(ROOT) else dest})")
        elif anchor and dest.suffix == ".md" and anchor not in anchors(dest):
            broken.append(f"{target} (no heading with anchor #{anchor} in {dest.name})")
    assert not broken, f"{doc.relative_to(ROOT)}: broken links: " + "; ".join(broken)
