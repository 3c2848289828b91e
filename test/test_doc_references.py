"""What the repository cites about the original DynEnv is in the repository: docs/original.md (the original code and
the paper, in numbers) and docs/spl_localization.md. No file points at notes outside it (a team's facts sheet, a
``shared/`` folder), and every citation of docs/original.md names a section that exists there.

Citations look like ``docs/original.md §9.6`` (Python, YAML), ``[original §9.6](original.md#96-…)`` (Markdown) or a
bare ``§9.6`` in docs/differences.md, whose sections are docs/original.md's (it says so at its top)."""
from __future__ import annotations

import os
import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
ORIGINAL = REPO / "docs" / "original.md"
SUFFIXES = {".py", ".md", ".yaml", ".yml"}
SKIP_DIRS = {".git", ".venv", "build", "install", "log", "runs", "shared", "__pycache__", ".pytest_cache"}
THIS_FILE = Path(__file__).resolve()

# Pointers outside the repository; the pieces are joined so that this file does not match itself.
FORBIDDEN = [
    ("a citation of the facts sheet", re.compile("fact" + r"s? sheet|" + "facts" + r" §|dynenv_" + "facts", re.I)),
    ("a path into shared/", re.compile(r"(?<![\w.\-])" + "shared" + "/")),
]
SECTION = r"\d+(?:\.\d+)?"
# "original.md §9.6", "original §9.6", chained: ", §12.18", " and §5.1", "/§12.15", a range "–12.3".
CITATION = re.compile(rf"\boriginal(?:\.md)? §({SECTION}(?:(?:, | and |/)§{SECTION}|–{SECTION})*)")
LINK = re.compile(r"\[([^\]]*)\]\((?:\./)?original\.md#([^)\s]+)\)")


def repository_files() -> list[Path]:
    found = []
    for root, dirs, files in os.walk(REPO):
        dirs[:] = [d for d in dirs if d not in SKIP_DIRS and not d.startswith(".")]
        found.extend(Path(root) / name for name in files if Path(name).suffix in SUFFIXES)
    return sorted(path for path in found if path.resolve() != THIS_FILE)


def github_anchor(heading: str) -> str:
    """The anchor GitHub gives a Markdown heading: lower case, punctuation dropped, spaces to hyphens."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def original_sections() -> dict[str, str]:
    """Section number → anchor of each numbered heading of docs/original.md ("## 6 Rewards", "### 9.6 …")."""
    sections = {}
    for line in ORIGINAL.read_text().splitlines():
        match = re.match(rf"#{{2,3}} ({SECTION}) \S", line)
        if match:
            sections[match.group(1)] = github_anchor(line.lstrip("#"))
    return sections


def cited_sections(text: str) -> list[tuple[int, str]]:
    """(line number, section) of every docs/original.md section the text cites."""
    cited = []
    for number, line in enumerate(text.splitlines(), 1):
        for match in CITATION.finditer(line):
            cited.extend((number, section) for section in re.findall(SECTION, match.group(1)))
    return cited


def test_the_original_is_described_in_numbered_sections():
    sections = original_sections()
    for needed in ["1", "2.7", "3", "5.1", "5.2", "6.1", "6.2", "6.3", "8", "9.6", "9.7", "11", "12.1", "12.19"]:
        assert needed in sections, f"docs/original.md has no section {needed}"
    assert len(set(sections.values())) == len(sections), "two sections of docs/original.md share an anchor"


def test_no_file_cites_notes_outside_the_repository():
    bad = []
    for path in repository_files():
        for number, line in enumerate(path.read_text(errors="replace").splitlines(), 1):
            bad.extend(f"{path.relative_to(REPO)}:{number}: {what}: {line.strip()[:100]}"
                       for what, pattern in FORBIDDEN if pattern.search(line))
    assert not bad, "cite docs/original.md (or docs/spl_localization.md) instead:\n" + "\n".join(bad)


def test_every_citation_of_the_original_names_one_of_its_sections():
    sections = original_sections()
    missing, count = [], 0
    for path in repository_files():
        for number, section in cited_sections(path.read_text(errors="replace")):
            count += 1
            if section not in sections:
                missing.append(f"{path.relative_to(REPO)}:{number}: §{section}")
    assert count > 50, f"only {count} citations of docs/original.md found: is the pattern still right?"
    assert not missing, "docs/original.md has no such section:\n" + "\n".join(missing)


def test_every_link_into_the_original_reaches_the_section_it_names():
    sections = original_sections()
    anchors = set(sections.values())
    wrong, count = [], 0
    for path in repository_files():
        if path.suffix != ".md":
            continue
        for number, line in enumerate(path.read_text().splitlines(), 1):
            for text, anchor in LINK.findall(line):
                count += 1
                where = f"{path.relative_to(REPO)}:{number}: [{text}](original.md#{anchor})"
                named = re.search(rf"§({SECTION})", text)
                if anchor not in anchors:
                    wrong.append(f"{where}: no such heading")
                elif named and sections.get(named.group(1)) != anchor:
                    wrong.append(f"{where}: §{named.group(1)} is #{sections.get(named.group(1))}")
    assert count > 10, f"only {count} links into docs/original.md found"
    assert not wrong, "\n".join(wrong)


def test_the_differences_cite_sections_of_the_original():
    """docs/differences.md cites the original by bare section numbers: each must exist in docs/original.md."""
    sections = original_sections()
    text = (REPO / "docs" / "differences.md").read_text()
    assert "[original.md](original.md)" in text.split("\n## ")[0], "differences.md must say whose sections it cites"
    cited = {section for chain in re.findall(rf"§({SECTION}(?:–{SECTION})?)", text)
             for section in re.findall(SECTION, chain)}
    # "§10–12" is a range of top-level sections; every number in it is checked.
    assert cited, "no § citations found in docs/differences.md"
    assert not cited - set(sections), f"docs/differences.md cites missing sections: {sorted(cited - set(sections))}"


def test_the_anchor_rule_matches_githubs():
    assert github_anchor(" 9.6 Localization and reconstruction") == "96-localization-and-reconstruction"
    assert github_anchor("12.1 The second team's frame is half mirrored") == "121-the-second-teams-frame-is-half-mirrored"
    assert github_anchor("9.5 Curiosity: ICM, RCM and LTP") == "95-curiosity-icm-rcm-and-ltp"
