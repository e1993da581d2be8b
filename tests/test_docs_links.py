"""The Markdown docs stay valid as they move and split.  Every relative link leads somewhere: the file exists
and, where the link names a heading (``file.md#anchor``), the file has that heading (GitHub's anchor rules);
a link left pointing at the old place fails here, not in a reader's browser.  Every command in a ``bash``
block is one that parses (``d5rl`` commands through d5rl's own argument parser, scripts and modules exist),
and every ``python`` block of the docs pages runs.  The README is a front page: short, and its links reach
every docs page."""

import re
import shlex
from pathlib import Path

import pytest

from tests.test_readme import run_python

ROOT = Path(__file__).resolve().parents[1]
DOCS = sorted([ROOT / "README.md", ROOT / "CHANGELOG.md", *(ROOT / "docs").rglob("*.md")])
PAGES = sorted((ROOT / "docs").glob("*.md"))  # the pages the README leads to
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
    assert "how-our-data-differs-from-the-papers" in anchors(ROOT / "docs/data-differences.md")
    # "## Table 2, offline-to-online, on A1"
    assert "table-2-offline-to-online-on-a1" in anchors(ROOT / "docs/results.md")


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


def test_readme_is_a_front_page_that_leads_to_every_docs_page():
    readme = ROOT / "README.md"
    assert len(readme.read_text().splitlines()) < 200, "README.md is the front page: move detail to docs/"
    linked = {(readme.parent / t.partition("#")[0]).resolve() for t in links(readme)}
    assert PAGES and not [p.name for p in PAGES if p not in linked], "docs pages the README does not link to"


# --- commands ---------------------------------------------------------------------------------------------
def blocks(path: Path, lang: str) -> list[str]:
    return re.findall(rf"^```{lang}\n(.*?)^```", path.read_text(), flags=re.S | re.M)


def commands(block: str) -> list[list[str]]:
    """The commands of a bash block, as argument lists: continuation lines joined, comments dropped, the
    block's own variables (``S="..."``) expanded, ``&&`` / ``;`` / ``|`` / ``&`` split, and leading
    environment assignments (``STEPS=3000 bash ...``) dropped."""
    out, env = [], {}
    for line in block.replace("\\\n", " ").splitlines():
        for var, value in env.items():
            line = line.replace(f"${var}", value)
        words = shlex.split(line, comments=True)
        m = re.fullmatch(r"([A-Z_][A-Z0-9_]*)=(.*)", " ".join(words)) if len(words) == 1 else None
        if m:
            env[m.group(1)] = m.group(2)
            continue
        cmd: list[str] = []
        for w in words + [";"]:
            if w in ("&&", ";", "|", "&", "||"):
                while cmd and re.fullmatch(r"[A-Z_][A-Z0-9_]*=.*", cmd[0]):
                    cmd.pop(0)
                if cmd:
                    out.append(cmd)
                cmd = []
            else:
                cmd.append(w.rstrip("&") if w.endswith("&") and w != "&" else w)
    return out


def command_problem(cmd: list[str]) -> str | None:
    """What is wrong with one documented command, or None.  ``d5rl`` commands must parse with d5rl's own
    parser; ``bash X`` / ``python X`` need the file X in the repository, ``python -m M`` an importable M."""
    import contextlib
    import importlib.util
    import io

    from d5rl.cli import build_parser

    head = cmd[0]
    if head == "d5rl":
        err = io.StringIO()
        try:
            with contextlib.redirect_stderr(err):
                build_parser().parse_args(cmd[1:])
        except SystemExit as e:
            if e.code:
                return err.getvalue().strip().splitlines()[-1]
        return None
    if head in ("bash", "python", "python3") and len(cmd) > 1:
        if cmd[1] == "-m":
            return None if importlib.util.find_spec(cmd[2]) else f"no module {cmd[2]}"
        if cmd[1] == "-c" or cmd[1].startswith("-"):
            return None
        return None if (ROOT / cmd[1]).is_file() else f"no file {cmd[1]}"
    return None


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: str(p.relative_to(ROOT)))
def test_documented_commands_parse(doc):
    bad = [
        f"`{shlex.join(c)}`: {why}"
        for block in blocks(doc, "bash")
        for c in commands(block)
        if (why := command_problem(c))
    ]
    spans = re.findall(r"`((?:d5rl|python|bash) [^`\n]+)`", prose(doc))
    for span in spans:  # inline commands often hold placeholders (TASK, RUN_DIR): the command and file must exist
        words = span.split()
        if words[0] == "d5rl":
            from d5rl.cli import build_parser

            sub = next(a for a in build_parser()._actions if a.dest == "command")
            if words[1] not in sub.choices:
                bad.append(f"`{span}`: no command d5rl {words[1]}")
        elif (why := command_problem(words[:3])) and not re.search(r"[A-Z]{3,}", span):
            bad.append(f"`{span}`: {why}")
    assert not bad, f"{doc.relative_to(ROOT)}: " + "; ".join(bad)


def test_command_checks_can_fail():
    block = 'S="--seeds 0-2"\nd5rl bench --tasks a1 \\\n  $S  # c\nX=1 bash scripts/test.sh && d5rl list &'
    assert commands(block) == [
        ["d5rl", "bench", "--tasks", "a1", "--seeds", "0-2"],
        ["bash", "scripts/test.sh"],
        ["d5rl", "list"],
    ]
    assert command_problem(["d5rl", "train", "a1-walk-v0", "--algo", "iql"])  # not how train is called
    assert command_problem(["d5rl", "bench", "--no-such-flag"])
    assert command_problem(["python", "bench/no_such_script.py"]) == "no file bench/no_such_script.py"
    assert command_problem(["python", "-m", "d5rl.no_such_module"])
    assert command_problem(["d5rl", "train", "iql", "a1-walk-v0", "--offline-steps", "10"]) is None


DOCS_PYTHON = [(p, i) for p in PAGES for i in range(len(blocks(p, "python")))]


@pytest.mark.parametrize("page,index", DOCS_PYTHON, ids=[f"{p.name}-{i}" for p, i in DOCS_PYTHON])
def test_python_blocks_of_the_docs_pages_run(page, index, tmp_path):
    run_python(blocks(page, "python")[index], tmp_path)
