"""The documentation's links: README.md (the front door, read on the forge, outside the MkDocs site) and the
pages in docs/ (CI also builds them with ``mkdocs build --strict``, which fails on a broken link or anchor)."""
from __future__ import annotations

import re
import unicodedata
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
PAGES = sorted(DOCS.glob("*.md"))
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")
FENCE = re.compile(r"^```.*?^```", re.S | re.M)


def slug(heading: str) -> str:
    """The anchor Python-Markdown's toc extension (MkDocs) gives a heading."""
    text = unicodedata.normalize("NFKD", re.sub(r"`", "", heading)).encode("ascii", "ignore").decode()
    text = re.sub(r"[^\w\s-]", "", text).strip().lower()
    return re.sub(r"[-\s]+", "-", text)


def anchors(page: Path) -> set[str]:
    text = FENCE.sub("", page.read_text())
    return {slug(m.group(1)) for m in re.finditer(r"^#{1,6}\s+(.+?)\s*$", text, re.M)}


def links(page: Path) -> list[str]:
    return [m.group(1) for m in LINK.finditer(FENCE.sub("", page.read_text()))]


def broken(page: Path) -> list[str]:
    """The relative links of ``page`` whose file, or heading anchor in a Markdown file, does not exist."""
    out = []
    for link in links(page):
        if re.match(r"^[a-z][a-z0-9+.-]*:", link):  # http:, mailto:, ...: not ours to check here
            continue
        path, _, anchor = link.partition("#")
        target = (page.parent / path).resolve() if path else page
        if not target.exists():
            out.append(f"{link}: no such file")
        elif anchor and target.suffix == ".md" and anchor not in anchors(target):
            out.append(f"{link}: no heading with that anchor")
    return out


@pytest.mark.parametrize("page", [ROOT / "README.md", *PAGES], ids=lambda p: p.relative_to(ROOT).as_posix())
def test_every_relative_link_and_anchor_resolves(page):
    assert broken(page) == []


def test_the_checker_finds_a_broken_file_and_a_broken_anchor(tmp_path):
    (tmp_path / "a.md").write_text("# A page\n\n## Some `code` here\n")
    page = tmp_path / "b.md"
    page.write_text("[ok](a.md#some-code-here) [file](c.md) [anchor](a.md#nowhere)\n```\n[in code](x.md)\n```\n"
                    "[web](https://example.org/x) ![picture](a.md)\n")
    assert broken(page) == ["c.md: no such file", "a.md#nowhere: no heading with that anchor"]


def test_the_site_lists_every_page_and_only_existing_ones():
    nav = re.findall(r"^\s*-\s*[^:]+:\s*(\S+\.md)\s*$", (ROOT / "mkdocs.yml").read_text(), re.M)
    assert sorted(nav) == [p.name for p in PAGES]


def test_the_readme_links_every_page():
    linked = {Path(link.partition("#")[0]).name for link in links(ROOT / "README.md") if link.startswith("docs/")}
    assert linked >= {p.name for p in PAGES}


def test_the_settings_page_lists_every_setting():
    from app.settings import Settings

    page = (DOCS / "settings.md").read_text()
    missing = [f"SWEEPCAST_{name.upper()}" for name in Settings.model_fields if f"SWEEPCAST_{name.upper()}" not in page]
    assert missing == []
