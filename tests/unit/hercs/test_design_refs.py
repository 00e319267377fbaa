"""Every citation of docs/DESIGN.md resolves: "DESIGN.md §X" anywhere in the repository, and a
bare "§X" inside DESIGN.md itself, names a heading of DESIGN.md (or a numbered row of one of its
tables), and a quoted part after it ("§3, "The replay table"") occurs in that section. Code
cites DESIGN by section number, so a renumbered or dropped section must fail here, not rot."""

from __future__ import annotations

import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[3]
DESIGN = REPO / "docs" / "DESIGN.md"
THIS = Path(__file__).resolve()  # its examples below are made up

SCANNED_DIRS = ("hercs", "bench", "studies", "tests", "docs", "reports", "examples", "deploy",
                ".ci")
SCANNED_FILES = ("README.md", "Makefile", "Dockerfile", "docker-compose.yml", "pyproject.toml")
SUFFIXES = {".py", ".md", ".toml", ".yml", ".yaml", ".sh", ".txt", ".pyi", ""}

NUMBER = r"\d+(?:\.\d+)*"
HEADING = re.compile(rf"^(#{{2,4}})\s+({NUMBER})\.?\s", re.MULTILINE)
TABLE_ROW = re.compile(rf"^\|\s*({NUMBER})\s*\|", re.MULTILINE)
SECTION_REF = re.compile(rf"§\s?({NUMBER})")
NAMED_REF = re.compile(rf"§\s?({NUMBER})[,;]?\s*\(?[\"“]([^\"”\n]{{2,80}})[\"”]")
DESIGN_MENTION = re.compile(r"DESIGN(?:\.md)?\b")
OTHER_DOC = re.compile(r"[\w./-]+\.md")
# where the citation a DESIGN mention starts ends: a closing parenthesis, a sentence's end, a
# paragraph's end, or the mention of another document
WINDOW_END = re.compile(r"\)|\.\s|\n\s*\n|\n\s*#\s*\n|[\w./-]+\.md")
WINDOW_CHARS = 240


def number_of(ref: str) -> str:
    """'4.2.' at a sentence's end is §4.2."""
    return ref.rstrip(".")


def design_sections(text: str) -> dict[str, str]:
    """Each numbered heading's number → its text up to the next heading of its level or above."""
    headings = [(m.start(), len(m.group(1)), m.group(2)) for m in HEADING.finditer(text)]
    all_headings = [(m.start(), len(m.group(1))) for m in re.finditer(r"^(#{1,4})\s", text,
                                                                      re.MULTILINE)]
    sections = {}
    for start, level, number in headings:
        end = next((s for s, lv in all_headings if s > start and lv <= level), len(text))
        sections[number] = text[start:end]
    return sections


def anchors(text: str) -> set[str]:
    return set(design_sections(text)) | {m.group(1) for m in TABLE_ROW.finditer(text)}


def citations_in(text: str) -> list[tuple[str, str | None]]:
    """(section, quoted part or None) for every DESIGN citation in a file other than DESIGN.md:
    the §s after a DESIGN mention, up to where its citation ends (line breaks and comment
    markers between them allowed)."""
    found: list[tuple[str, str | None]] = []
    for mention in DESIGN_MENTION.finditer(text):
        rest = text[mention.end():mention.end() + WINDOW_CHARS]
        if not re.match(r"[\s#\"*,(]*§", rest):
            continue
        end = WINDOW_END.search(rest)
        window = rest[:end.start()] if end else rest
        named = {m.start(): m.group(2) for m in NAMED_REF.finditer(window)}
        found += [(number_of(m.group(1)), named.get(m.start()))
                  for m in SECTION_REF.finditer(window)]
    return found


def self_citations(text: str) -> list[tuple[str, str | None]]:
    """The bare §s of DESIGN.md that cite DESIGN.md: all but those of another document
    ("docs/PERFORMANCE.md §2", "docs/CLUSTER.md §1, §4")."""
    masked = re.sub(rf"{OTHER_DOC.pattern}(?:[\s,]*(?:and\s+)?§\s?{NUMBER})+",
                    lambda m: " " * len(m.group(0)) if "DESIGN" not in m.group(0) else m.group(0),
                    text)
    named = {m.start(): m.group(2) for m in NAMED_REF.finditer(masked)}
    return [(number_of(m.group(1)), named.get(m.start())) for m in SECTION_REF.finditer(masked)]


def scanned_files() -> list[Path]:
    files = [REPO / name for name in SCANNED_FILES if (REPO / name).is_file()]
    for folder in SCANNED_DIRS:
        for path in sorted((REPO / folder).rglob("*")):
            parts = set(path.relative_to(REPO).parts)
            if (path.is_file() and path.suffix in SUFFIXES and path not in (DESIGN, THIS)
                    and "__pycache__" not in parts and "demo" not in parts):
                files.append(path)
    return files


def problems(cites: list[tuple[str, str | None]], where: str, sections: dict[str, str],
             known: set[str]) -> list[str]:
    out = []
    for number, name in cites:
        if number not in known:
            out.append(f"{where}: cites DESIGN.md §{number}, which is no heading (nor numbered "
                       "table row) there")
        elif name is not None and name.lower() not in sections.get(number, "").lower():
            out.append(f"{where}: cites DESIGN.md §{number} {name!r}, which §{number} lacks")
    return out


def test_the_extraction_reads_the_forms_the_code_uses() -> None:
    comment = "x = 1  # the bound (docs/DESIGN.md\n    # §9.1) and the rest §4 (not DESIGN's)\n"
    assert citations_in(comment) == [("9.1", None)]
    assert citations_in('(docs/DESIGN.md §3 "Bad input", §8 "No hang"): each') == [
        ("3", "Bad input"), ("8", "No hang")]
    assert citations_in("the rule is docs/DESIGN.md §4.2.\nRewards") == [("4.2", None)]
    assert citations_in("(DESIGN §10) and docs/PERFORMANCE.md §2") == [("10", None)]
    assert self_citations("see §4.7 and docs/CLUSTER.md §1, §4, §5; (§6, \"Views\")") == [
        ("4.7", None), ("6", "Views")]


def test_every_design_citation_in_the_repository_names_a_section_of_it() -> None:
    text = DESIGN.read_text(encoding="utf-8")
    sections, known = design_sections(text), anchors(text)
    found, bad = 0, []
    for path in scanned_files():
        try:
            content = path.read_text(encoding="utf-8")
        except UnicodeDecodeError:
            continue
        cites = citations_in(content)
        found += len(cites)
        bad += problems(cites, str(path.relative_to(REPO)), sections, known)
    assert not bad, "\n".join(bad)
    # the code cites DESIGN about a hundred times: far fewer found means the scan went blind
    assert found >= 80, f"only {found} DESIGN.md citations found: the scan misses some"


def test_every_section_design_cites_of_itself_exists() -> None:
    text = DESIGN.read_text(encoding="utf-8")
    sections, known = design_sections(text), anchors(text)
    cites = self_citations(text)
    assert len(cites) >= 20, f"only {len(cites)} § references found in DESIGN.md"
    bad = problems(cites, "docs/DESIGN.md", sections, known)
    assert not bad, "\n".join(bad)


def test_the_sections_code_cites_most_are_there() -> None:
    known = anchors(DESIGN.read_text(encoding="utf-8"))
    assert {"1", "2", "3", "4", "4.9", "5", "6", "8", "9", "9.1", "9.3", "10"} <= known
