"""The documentation holds together: links resolve, the index lists every page, figures are shown.

Read as text (nothing imported, nothing run; well under a second):

- every relative Markdown link and image (``[text](target)``, ``![alt](target)``) in
  ``README.md``, ``docs/*.md`` and the dated records (``experiments/notes/*.md``,
  ``benchmarks/notes/*.md``) names an existing file, and its ``#anchor``, when it has one, a
  heading of that Markdown file (GitHub's anchors: lower case, punctuation dropped, spaces as
  hyphens, a repeated heading numbered); links in fenced code blocks are code, not links;
- every raw-row or figure path the docs name in backticks (``experiments/results/...``,
  ``docs/figures/...``, without a pattern such as ``*`` or ``{a,b}``) exists;
- ``docs/index.md`` links every page of ``docs/`` and ``README.md`` links ``docs/index.md``;
- every file in ``docs/figures`` is shown or named by a page of ``docs/`` or the README (the
  raw rows of the studies live in ``experiments/results/``).
"""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")
NAMED_PATH = re.compile(r"`((?:experiments/results|docs/figures)/[^`\s]+)`")


def pages() -> list[Path]:
    """The Markdown files whose links are checked."""
    found = [ROOT / "README.md", *sorted(DOCS.glob("*.md"))]
    for notes in ("experiments/notes", "benchmarks/notes"):
        found += sorted((ROOT / notes).glob("*.md"))
    return found


def prose(text: str) -> str:
    """The text without its fenced code blocks."""
    return re.sub(r"^```.*?^```[^\n]*$", "", text, flags=re.M | re.S)


def anchors(path: Path) -> set[str]:
    """GitHub's anchors of a Markdown file's headings."""
    seen: dict[str, int] = {}
    out = set()
    for line in prose(path.read_text()).splitlines():
        match = re.match(r"#{1,6}\s+(.*?)\s*#*\s*$", line)
        if not match:
            continue
        slug = re.sub(r"[^\w\- ]", "", match.group(1).lower()).replace(" ", "-")
        count = seen.get(slug, 0)
        seen[slug] = count + 1
        out.add(slug if count == 0 else f"{slug}-{count}")
    return out


def broken_links(path: Path) -> list[str]:
    """The relative links of one Markdown file that do not resolve, with the reason."""
    bad = []
    for target in LINK.findall(prose(path.read_text())):
        if re.match(r"[a-z][a-z0-9+.-]*:", target):  # http:, https:, mailto:
            continue
        file_part, _, anchor = target.partition("#")
        dest = (path.parent / file_part).resolve() if file_part else path
        if not dest.exists():
            bad.append(f"{target}: no such file")
        elif anchor and dest.suffix == ".md" and anchor not in anchors(dest):
            bad.append(f"{target}: no heading with that anchor")
    return bad


def test_every_relative_link_resolves():
    bad = {str(p.relative_to(ROOT)): b for p in pages() if (b := broken_links(p))}
    assert not bad, bad


def test_every_path_the_docs_name_exists():
    missing = []
    for path in [ROOT / "README.md", *sorted(DOCS.glob("*.md"))]:
        for named in NAMED_PATH.findall(path.read_text()):
            if not re.search(r"[*{<]|\.\.\.", named) and not (ROOT / named).exists():
                missing.append(f"{path.name}: {named}")
    assert not missing, missing


def test_the_index_lists_every_page_and_the_readme_links_the_index():
    linked = {(DOCS / t.partition("#")[0]).resolve()
              for t in LINK.findall((DOCS / "index.md").read_text())}
    unlisted = [p.name for p in DOCS.glob("*.md") if p.name != "index.md" and p not in linked]
    assert not unlisted, f"docs/index.md does not link {unlisted}"
    assert "docs/index.md" in LINK.findall((ROOT / "README.md").read_text())


def test_every_figure_in_docs_is_shown_by_the_docs():
    text = "\n".join(p.read_text() for p in [ROOT / "README.md", *DOCS.glob("*.md")])
    unused = [f.name for f in (DOCS / "figures").iterdir() if f"figures/{f.name}" not in text]
    assert not unused, f"docs/figures holds files no page shows: {unused}"


def test_the_checks_see_a_broken_link_and_a_wrong_anchor(tmp_path):
    (tmp_path / "a.md").write_text("# A title, here\n\n[ok](b.md#b-section) [x](c.md)\n"
                                   "[y](b.md#nowhere) [z](#a-title-here) [w](https://x.y)\n"
                                   "```\n[in code](d.md)\n```\n")
    (tmp_path / "b.md").write_text("## B section\n")
    assert broken_links(tmp_path / "a.md") == ["c.md: no such file",
                                               "b.md#nowhere: no heading with that anchor"]
