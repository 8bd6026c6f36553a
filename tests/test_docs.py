"""The README and the pages under docs/ hold together: every relative link and picture resolves (its file, and its
anchor to a heading of that file), every repository path they cite exists, a document they name is a link, every
page is reachable from the README, and the README starts with the two commands a new user runs.

Links are read as GitHub renders them: ``[text](target)`` and ``![alt](target)``, outside fenced code; an anchor is
GitHub's slug of a heading (lower case, punctuation but ``-`` and ``_`` dropped, spaces to ``-``, a repeated
heading numbered ``-1``, ``-2``...).
"""

from __future__ import annotations

import re
from collections import Counter
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DOCS = sorted((ROOT / "docs").glob("*.md"))
PAGES = [README, *DOCS]

#: The two commands the README starts with (the team's rule: both work on a fresh machine).
COMMANDS = ["pip install -e . && hils run", "make test"]

#: The lines a reader sees before scrolling.
SCREEN = 25

#: Folders of the repository whose paths the pages cite; a cited path under one of them must exist.
TRACKED = ("hils/", "emulator/", "harness/", "tests/", "docs/", "examples/", "fault_scenarios/", "reports/")

_FENCE = re.compile(r"^(```|~~~).*?^\1[ \t]*$", re.S | re.M)
_LINK = re.compile(r"!?\[(?P<text>[^\]]*)\]\((?P<target>[^)\s]+)(?:\s+\"[^\"]*\")?\)")
_HEADING = re.compile(r"^(#{1,6})\s+(.+?)\s*#*\s*$", re.M)
_CODE_SPAN = re.compile(r"`([^`\n]+)`")
_DOCUMENT = re.compile(r"(?<![\w/.-])[\w/.-]+\.md\b")

#: Folders the commands write into (a run's, a sweep's): cited as where to look, not held by the repository.
OUTPUTS = ("reports/runs/", "reports/sweeps/")


def _shown(path: Path) -> str:
    return str(path.relative_to(ROOT)) if path.is_relative_to(ROOT) else str(path)


def _placeholder(word: str) -> bool:
    """``<run folder>``, ``...``, ``NAME``, ``OUT``: a span that stands for a file rather than naming one."""
    return bool(re.search(r"[<>]|\.\.\.", word)) or any(
        part.isupper() and len(part) > 1 and part != "README" for part in re.split(r"[/.]", word))


def _prose(text: str) -> str:
    """The text without its fenced code blocks (a ``#`` comment in a shell block is no heading, a link in a block
    no link); each block keeps its lines, so that line numbers still count."""
    return _FENCE.sub(lambda m: "\n" * m.group(0).count("\n"), text)


def slug(heading: str) -> str:
    """GitHub's anchor of a heading's text."""
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", heading)  # a link in a heading anchors by its text
    return re.sub(r"[^\w\- ]", "", text.strip().lower()).replace(" ", "-")


def anchors(path: Path) -> set[str]:
    """Every anchor of a page: its headings' slugs, a repeated one numbered as GitHub numbers it."""
    seen: Counter[str] = Counter()
    out = set()
    for match in _HEADING.finditer(_prose(path.read_text(encoding="utf-8"))):
        base = slug(match.group(2))
        out.add(base if not seen[base] else f"{base}-{seen[base]}")
        seen[base] += 1
    return out


def links(path: Path) -> list[tuple[int, str]]:
    """The relative link and picture targets of a page, with their line numbers."""
    prose = _prose(path.read_text(encoding="utf-8"))
    found = []
    for number, line in enumerate(prose.splitlines(), 1):
        for match in _LINK.finditer(_CODE_SPAN.sub("", line)):
            target = match.group("target")
            if not re.match(r"[a-z][a-z0-9+.-]*:", target):  # http:, https:, mailto: are not this repository's
                found.append((number, target))
    return found


def broken_links(path: Path) -> list[str]:
    """What is wrong with each relative link of a page: a file that is not there, or an anchor no heading has."""
    problems = []
    for number, target in links(path):
        file, _, anchor = target.partition("#")
        resolved = (path.parent / file).resolve() if file else path
        where = f"{_shown(path)}:{number}: {target}"
        if not resolved.exists():
            problems.append(f"{where}: no file {_shown(resolved)}")
        elif anchor and resolved.suffix == ".md" and anchor not in anchors(resolved):
            problems.append(f"{where}: {resolved.name} has no heading with anchor #{anchor}")
    return problems


def cited_paths(path: Path) -> list[tuple[int, str]]:
    """Repository paths a page cites in code spans of its prose (``hils/data/four_leg.toml``); a span with a
    placeholder (``<run folder>``, ``NAME``, ``...``) names no one file and is left out."""
    found = []
    for number, line in enumerate(_prose(path.read_text(encoding="utf-8")).splitlines(), 1):
        for span in _CODE_SPAN.findall(line):
            for word in span.split():
                word = word.rstrip(".,:;)").split("#")[0].split("(")[0]
                named_file = word.endswith("/") or "." in word.rsplit("/", 1)[-1]  # not an id: hils/Intersection-v1
                if word.startswith(TRACKED) and named_file and not word.startswith(OUTPUTS) and not _placeholder(word):
                    found.append((number, word))
    return found


def missing_paths(path: Path) -> list[str]:
    problems = []
    for number, cited in cited_paths(path):
        if not any(ROOT.glob(cited)) if "*" in cited else not (ROOT / cited).exists():
            problems.append(f"{_shown(path)}:{number}: cites {cited}, which the repository does not hold")
    return problems


def unlinked_documents(path: Path) -> list[str]:
    """Documents a page names in its prose (``DESIGN.md``) but does not link: a reader cannot follow the name, and
    nothing checks that the document exists. A name in a code span is a file a command writes, or a cited path
    (checked by :func:`missing_paths`)."""
    problems = []
    for number, line in enumerate(_prose(path.read_text(encoding="utf-8")).splitlines(), 1):
        bare = _LINK.sub(" ", _CODE_SPAN.sub(" ", line))
        problems += [f"{_shown(path)}:{number}: names {name} without linking it"
                     for name in _DOCUMENT.findall(bare)]
    return problems


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_resolves(page: Path) -> None:
    assert broken_links(page) == []


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_cited_path_exists(page: Path) -> None:
    assert missing_paths(page) == []


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_a_document_named_is_a_link(page: Path) -> None:
    assert unlinked_documents(page) == []


def test_every_docs_page_is_linked_from_the_readme() -> None:
    linked = {(README.parent / target.partition("#")[0]).resolve() for _, target in links(README)}
    assert [str(page.relative_to(ROOT)) for page in DOCS if page.resolve() not in linked] == []


def test_the_readme_starts_with_the_two_commands() -> None:
    """The first code block holds exactly the two commands, on the first screen, and what hils is is said there too,
    before anything about the tests (how they run, how long they take)."""
    text = README.read_text(encoding="utf-8")
    first = re.search(r"^```[a-z]*\n(.*?)^```", text, re.S | re.M)
    assert first is not None, "the README has no code block"
    assert [line.strip() for line in first.group(1).splitlines() if line.strip()] == COMMANDS
    screen = "\n".join(text.splitlines()[:SCREEN])
    assert first.end() <= len(screen), f"the two commands are in the first {SCREEN} lines"
    assert "hils is" in screen, f"what hils is is said in the first {SCREEN} lines"
    tests = re.search(r"pytest|minutes", text)
    assert tests is None or text.index("hils is") < tests.start(), "what hils is comes before the tests' details"


def test_the_checks_catch_what_they_are_for(tmp_path: Path) -> None:
    """Each check finds its fault in a page written with it: a missing file, a missing anchor, a cited path the
    repository does not hold, a document named but not linked; and passes the same page written right."""
    page = tmp_path / "page.md"
    page.write_text("# A title\n\n## Two words\n\nSee [it](#two-words), [that](#a-title) and `hils/__init__.py`.\n"
                    "```sh\n# not a heading; [not a link](nowhere.md)\n```\n", encoding="utf-8")
    assert anchors(page) == {"a-title", "two-words"}
    assert links(page) == [(5, "#two-words"), (5, "#a-title")]
    assert broken_links(page) == []
    assert unlinked_documents(page) == []
    (tmp_path / "other.md").write_text("# Other\n", encoding="utf-8")
    page.write_text("[a](missing.md) [b](other.md#nope) [c](other.md#other) as DESIGN.md says\n", encoding="utf-8")
    assert [p.split(": ", 2)[2] for p in broken_links(page)] == ["no file " + str(tmp_path / "missing.md"),
                                                                 "other.md has no heading with anchor #nope"]
    assert len(unlinked_documents(page)) == 1 and "DESIGN.md" in unlinked_documents(page)[0]
    assert slug("Reinforcement learning: the gymnasium environment") == (
        "reinforcement-learning-the-gymnasium-environment")
    assert slug("`hils run`, step by step") == "hils-run-step-by-step"
