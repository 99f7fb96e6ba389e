"""The README defines its words: every upper-case abbreviation it uses outside code (UAV,
IMM-UKF, RMSE …) is in its glossary, the words issue readers stumbled on are there too, each
glossary word is linked from the text before the glossary, and every link to the glossary
lands on it."""

import re
from pathlib import Path

README = (Path(__file__).resolve().parents[2] / "README.md").read_text(encoding="utf-8")

#: an abbreviation: two or more capitals (digits and hyphenated parts allowed), a plural "s" dropped
ABBREVIATION = re.compile(r"(?<![\w/.-])([A-Z][A-Z0-9]*[A-Z](?:-[A-Z0-9]+)*)s?(?![\w/-])")


def _prose(text: str) -> str:
    """``text`` without fenced blocks, inline code and link targets (code is not prose)."""
    text = re.sub(r"^```.*?^```", "", text, flags=re.S | re.M)
    text = re.sub(r"`[^`]*`", "", text)
    return re.sub(r"\]\([^)]*\)", "]", text)


def _sections() -> tuple[str, str]:
    head, glossary = README.split("\n## Glossary\n", 1)
    return head, glossary.split("\n## ", 1)[0]


def _terms(glossary: str) -> list[str]:
    return [t for line in glossary.splitlines() if line.startswith("* ")
            for t in re.findall(r"\*\*(.+?)\*\*", line.split(" — ", 1)[0])]


def test_the_pattern_finds_abbreviations_and_nothing_else():
    found = ABBREVIATION.findall(_prose("UAVs and an IMM-UKF; RMSE, λ2, Ctrl-C, `SELECT ALL`, Sun et al. 2011, "
                                        "a C++ compiler, [docs](docs/cli.md), Parquet, DuckDB"))
    assert found == ["UAV", "IMM-UKF", "RMSE"]


def test_every_abbreviation_the_readme_uses_is_in_its_glossary():
    head, glossary = _sections()
    used = set(ABBREVIATION.findall(_prose(head)))
    assert {"UAV", "UUV", "ICF", "CIF", "IMM-UKF", "RMSE"} <= used  # the test reads what the README says
    missing = sorted(a for a in used if not re.search(rf"(?<![\w-]){re.escape(a)}(?![\w-])", glossary))
    assert not missing, f"the README's glossary does not define {missing}"


def test_the_glossary_holds_the_words_readers_asked_about_and_is_short():
    _, glossary = _sections()
    terms = set(_terms(glossary))
    for word in ("ICF", "modified ICF", "CIF", "KCF", "IMM-UKF", "IMM-EKF", "comm radius", "closed loop", "λ2",
                 "NEES", "Params", "held-out seeds"):
        assert word in terms, word
    lines = [line for line in glossary.splitlines() if line.strip()]
    assert len(lines) <= 14, len(lines)  # about ten lines: a glossary, not a second manual


def test_glossary_words_are_linked_from_their_first_use():
    head, _ = _sections()
    assert README.count("\n## Glossary\n") == 1
    linked = " ".join(re.findall(r"\[([^\]]+)\]\(#glossary\)", head)).replace("\n", " ")
    for word in ("UAV", "UUV", "JAX", "closed loop", "ICF", "CIF", "comm radi", "IMM-UKF", "Params", "held-out seeds"):
        assert word in linked, word
    assert not re.findall(r"\]\(#(?!glossary\))[^)]*\)", README)  # no anchor but the glossary's
