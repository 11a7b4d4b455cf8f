"""The documentation resolves inside the repository.

- Every section the code and the tests cite ("MATH.md §7", "MATH.md §4, §4.1", "MATH.md §1–§3",
  "docs/method.md §9") is a heading of docs/method.md, the specification shipped with the code.
- Every relative link in README.md and docs/*.md names a file of the repository, and a link to a
  heading (``file.md#anchor``) names a heading of that file.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
METHOD = REPO / "docs" / "method.md"
DOCS = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]

#: A citation: the file, then one or more sections joined by ", ", " and " or a range dash.
CITATION = re.compile(r"(?:docs/method\.md|MATH\.md)\s+(§\d+(?:\.\d+)?(?:\s*(?:,|–|-|and)\s*§\d+(?:\.\d+)?)*)")
SECTION = re.compile(r"§(\d+(?:\.\d+)?)")


def method_sections(text: str) -> set[str]:
    """Section numbers of the headings ``## 7. ...`` / ``### 4.1 ...``."""
    return set(re.findall(r"^#{2,4}\s+(\d+(?:\.\d+)?)\.?\s", text, flags=re.M))


def cited_sections(text: str) -> list[str]:
    """Every section a text cites, ranges expanded (§1–§3 -> 1, 2, 3)."""
    out = []
    for m in CITATION.finditer(text):
        group = m.group(1)
        nums = SECTION.findall(group)
        out += nums
        for a, b in re.findall(r"§(\d+)\s*[–-]\s*§(\d+)", group):
            out += [str(k) for k in range(int(a), int(b) + 1)]
    return out


def test_citation_parser_reads_every_form_the_code_uses():
    text = ("(MATH.md §4, §4.1) ... MATH.md §1–§3 ... MATH.md §11 (a) ... docs/method.md §9 and "
            "MATH.md §5; eq. 14")
    assert cited_sections(text) == ["4", "4.1", "1", "3", "1", "2", "3", "11", "9", "5"]
    assert method_sections("## 1. Conventions\n### 4.1 Real data\n## 10. Rerun\n#### not 5\n") == {"1", "4.1", "10"}


def _citations_in_code():
    found = []
    for folder in ("rbgp_cli", "tests"):
        for path in sorted((REPO / folder).rglob("*.py")):
            text = path.read_text(encoding="utf-8")
            for section in cited_sections(text):
                found.append((path.relative_to(REPO).as_posix(), section))
    return found


def test_every_cited_section_is_a_heading_of_docs_method_md():
    sections = method_sections(METHOD.read_text(encoding="utf-8"))
    assert {str(k) for k in range(1, 12)} <= sections, sorted(sections)
    cited = _citations_in_code()
    assert len(cited) > 50, len(cited)  # the code cites the specification often; the parser finds them
    missing = sorted({(f, s) for f, s in cited if s not in sections})
    assert missing == [], missing


def test_docs_method_md_covers_what_each_section_is_cited_for():
    """A few facts per section that code cites from it, stated in docs/method.md's own section."""
    text = METHOD.read_text(encoding="utf-8")
    parts = re.split(r"^## (\d+)\.", text, flags=re.M)
    body = {parts[i]: parts[i + 1] for i in range(1, len(parts) - 1, 2)}
    expect = {
        "1": ["x, y, z, w", "(rx, ry, rz, x, y, z)", "seconds, metres and radians"],
        "2": ["u_z > 0", "atan2"],
        "3": ["c = 1 − u2 · u1", "q3 = q2 ⊗ q1"],
        "4": ["log(R_{k+1} R_kᵀ)", "exp(ω_k Δt) R_k", "Sample-and-hold", "left Jacobian"],
        "5": ["4 · atan2(‖q1 − q2‖, ‖q1 + q2‖)", "ρ1 = 0.7", "2 · sin(d_arc / 2)"],
        "6": ["Theorem 1 is false", "−0.18 at λ = 2", "S³ angle", "σ0²"],
        "7": ["α = C⁻¹ y", "L-BFGS-B", "latent", "median pairwise distance"],
        "8": ["Single-step mean prediction", "N(μ(g_k), σ²(g_k))"],
        "9": ["chordal mean", "D_B = ⅛", "log(R̄_tᵀ R)"],
        "10": ["Theorem 1", "sec. 4.2"],
        "11": ["(a)", "t_{K−1, 0.95}", "F_{0.90}(3, K−3)", "K = 20", "c_rot² = q_0.90"],
    }
    for section, phrases in expect.items():
        for phrase in phrases:
            assert phrase in body[section], (section, phrase)


# --------------------------------------------------------------------------------------------------
# links
LINK = re.compile(r"(?<!!)\[[^\]]*\]\(([^)\s]+)\)|!\[[^\]]*\]\(([^)\s]+)\)")


def slug(heading: str) -> str:
    """GitHub's anchor for a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"[`*_]", "", heading.strip().lower())
    text = re.sub(r"[^\w\- ]", "", text)
    return text.replace(" ", "-")


def anchors(path: Path) -> set[str]:
    text = re.sub(r"^```.*?^```", "", path.read_text(encoding="utf-8"), flags=re.M | re.S)
    return {slug(h) for h in re.findall(r"^#{1,6}\s+(.*?)\s*#*$", text, flags=re.M)}


def relative_links(path: Path) -> list[str]:
    text = re.sub(r"^```.*?^```", "", path.read_text(encoding="utf-8"), flags=re.M | re.S)
    text = re.sub(r"`[^`\n]*`", "", text)
    out = []
    for a, b in LINK.findall(text):
        target = a or b
        if re.match(r"^[a-z][a-z0-9+.-]*:", target):  # http:, https:, mailto:
            continue
        out.append(target)
    return out


def test_slug_is_githubs():
    assert slug("Seeing the motion: `--rerun` and `--plot`") == "seeing-the-motion---rerun-and---plot"
    assert slug("crossval: how good are the motions from starts the model has not seen?") == \
        "crossval-how-good-are-the-motions-from-starts-the-model-has-not-seen"


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: p.relative_to(REPO).as_posix())
def test_every_relative_link_resolves(doc):
    broken = []
    for target in relative_links(doc):
        file, _, anchor = target.partition("#")
        dest = (doc.parent / file).resolve() if file else doc
        if not dest.exists() or REPO not in dest.parents and dest != REPO:
            broken.append(target)
        elif anchor and dest.suffix == ".md" and anchor not in anchors(dest):
            broken.append(target)
    assert broken == [], broken


def test_the_readme_links_into_docs_and_is_a_front_page():
    text = (REPO / "README.md").read_text(encoding="utf-8")
    links = set(relative_links(REPO / "README.md"))
    for name in ("data.md", "commands.md", "method.md", "defaults.md", "benchmarks.md", "paper.md", "ARCHITECTURE.md"):
        assert f"docs/{name}" in links, name
    assert len(text.splitlines()) <= 250
    python = text.split("## Python", 1)[1].split("\n## ", 1)[0]
    assert "import rbgp_cli as rbgp" in python and len(python.splitlines()) <= 40
