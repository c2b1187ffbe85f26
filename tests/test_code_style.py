"""The code reads as a description of what it does, not as a diary: ruff is clean, docstrings and
comments carry no development history, and no file points outside the repository.

A docstring says what a function does and why it is shaped so; an episode of the development
that justifies a choice ("measured: draw 13 failed ...", "the commit before ...") belongs in a
regression test or on the documentation's validation page, where it names the command that
reproduces it. The phrases below mark such episodes.
"""
from __future__ import annotations

import ast
import io
import re
import subprocess
import sys
import tokenize
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent

#: phrases that mark development history inside a docstring or a comment
HISTORY = {
    "a numbered draw of a randomized suite": r"(?<![-\w])draws? \d+\b",
    "a commit relative to another": r"\b(?:the|one|a) commit (?:before|earlier|later|after)\b",
    "a commit hash": r"\bcommit [0-9a-f]{7,40}\b",
    "a measurement quoted as a note": r"\bmeasured:",
    "a development session": r"\b(?:the|this|a|previous|earlier|last) session\b(?! parameters?\b)|\bsession before\b",
    "what the code had done": r"\bhad been\b|\bpreviously\b|\bformerly\b|\bused to be\b",
    "a fix or a change": r"\bbefore the (?:fix|change|refactor)\b|\bafter the (?:fix|change|refactor)\b",
    "an issue number": r"\bissue \d+\b",
}
_HISTORY = re.compile("|".join(f"(?:{p})" for p in HISTORY.values()), re.IGNORECASE)

#: where the check applies: the library, the workflow, the benchmarks (tests may name the issue
#: whose behaviour they pin down)
CHECKED = ("ssamb/**/*.py", "workflow/**/*.py", "bench/*.py")


def _python_files() -> list[Path]:
    files = {p for g in CHECKED for p in ROOT.glob(g)}
    return sorted(files)


def _docs_and_comments(path: Path):
    """``(line, text)`` of every docstring, bare string statement and comment of a Python file."""
    src = path.read_text(encoding="utf-8")
    for node in ast.walk(ast.parse(src)):
        if isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant) and isinstance(node.value.value, str):
            yield node.lineno, node.value.value
    for tok in tokenize.generate_tokens(io.StringIO(src).readline):
        if tok.type == tokenize.COMMENT:
            yield tok.start[0], tok.string


def _yaml_comments(path: Path):
    for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        if "#" in line:
            yield n, line.split("#", 1)[1]


def _text_files():
    yield from ((p, _docs_and_comments(p)) for p in _python_files())
    for p in [ROOT / "Snakefile", *sorted((ROOT / "workflow" / "rules").glob("*.smk"))]:
        yield p, _yaml_comments(p)
    for p in (ROOT / "config.yaml", ROOT / "workflow" / "schemas" / "config.schema.yaml"):
        yield p, _yaml_comments(p)


def test_no_development_history_in_docstrings_or_comments():
    found = []
    for path, texts in _text_files():
        for line, text in texts:
            for m in _HISTORY.finditer(text):
                snippet = " ".join(text[max(0, m.start() - 50):m.end() + 50].split())
                found.append(f"{path.relative_to(ROOT)}:{line}: '{m.group(0)}' in ...{snippet}...")
    assert not found, "development history (make it a test or a line on docs/validation.md):\n" + "\n".join(found)


@pytest.mark.parametrize("text, flagged", [
    ("(measured: draw 13 failed)", True), ("the commit before the fix", True),
    ("a 6 N unbalance had been rejected", True), ("as the session before found", True), ("see issue 13", True),
    ("measured on the shipped data set by bench/closeloop_speed.py", False),
    ("the response is no longer linear", False), ("a random draw of the excitation phases", False),
    ("before the sweep starts", False), ("python bench/suite.py [--draws 24]", False),
    ("the session parameters of one recording", False), ("as the last session found", True),
])
def test_the_history_phrases_catch_what_they_should(text, flagged):
    assert bool(_HISTORY.search(text)) is flagged


def test_ruff_check_is_clean():
    r = subprocess.run([sys.executable, "-m", "ruff", "check", "--no-cache", str(ROOT)], capture_output=True,
                       text=True, cwd=ROOT)
    assert r.returncode == 0, r.stdout[-4000:] + r.stderr[-2000:]


def test_no_file_outside_the_repository_is_referred_to():
    """The repository documents itself: no path to the sibling folder of shared documents, nor to
    a contract document or paper file it does not hold (the pattern is assembled from its parts,
    so that this file passes its own check)."""
    shared, names = "shar" + "ed", ("ARCHITEC" + "TURE", "seed-" + "paper")
    outside = re.compile(rf"\.\./{shared}|/work/{shared}|" + "|".join(rf"{n}\.md" for n in names))
    files = [*ROOT.glob("*.md"), *ROOT.glob("docs/**/*.md"), *ROOT.glob("docs/**/*.py"),
             *ROOT.glob("ssamb/**/*.py"), *ROOT.glob("workflow/**/*"), ROOT / "Snakefile", ROOT / "config.yaml",
             *ROOT.glob("bench/*.py"), *ROOT.glob("tests/*.py")]
    hits = []
    for f in sorted(set(files)):
        if not f.is_file() or "_build" in f.parts:
            continue
        for n, line in enumerate(f.read_text(encoding="utf-8", errors="replace").splitlines(), 1):
            if outside.search(line):
                hits.append(f"{f.relative_to(ROOT)}:{n}: {line.strip()[:120]}")
    assert not hits, "\n".join(hits)


def test_the_readme_is_short_and_starts_with_the_two_commands():
    """Under 150 lines; its first code block holds exactly two commands: the full reproduction
    and the tests, the latter exactly what CI runs (.ci/run)."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    assert len(text.splitlines()) < 150
    block = text.split("```bash\n", 1)[1].split("```", 1)[0]
    commands = [ln for ln in block.splitlines() if ln.strip()]
    assert len(commands) == 2, commands
    assert commands[0].endswith("pip install -e . && snakemake --cores 2")
    assert commands[1].endswith('pip install -e ".[test]" && pytest -q')
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    assert 'pip install -e ".[test]" && pytest -q' in ci


def test_config_comments_are_one_short_reason():
    """Each comment of config.yaml gives the reason in a line (the report's configuration
    appendix shows it beside the value); the argument behind it lives in docs/."""
    long = [f"config.yaml:{n}: {len(c)} characters"
            for n, c in _yaml_comments(ROOT / "config.yaml") if len(c.strip()) > 160]
    assert not long, "\n".join(long)


def test_no_control_characters_in_the_sources():
    """No tab or other control character in the library, tests or benchmarks: in a docstring one
    is a backslash escape gone wrong (``\\theta`` written where a raw string was meant)."""
    bad = []
    for folder in ("ssamb", "tests", "bench", "workflow"):
        for p in sorted((ROOT / folder).rglob("*.py")):
            for i, line in enumerate(p.read_text(encoding="utf-8").splitlines(), 1):
                if re.search(r"[\x00-\x08\x0b\x0c\x0e-\x1f\t]", line):
                    bad.append(f"{p.relative_to(ROOT)}:{i}")
    assert not bad, bad
