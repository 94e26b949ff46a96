"""The product carries no project history: no numbered stops or issues, no diary of runs.

A user cannot look up a stop or an issue, and a maintainer cannot tell which sentence about
"the run an hour before" still holds. Code, tests, docs, studies, notebooks and scripts say what
is true and why, and name the test, study or ``bayes-mr bench`` figure that reproduces a number;
what was tried when belongs in the commit messages.

The patterns are built from pieces so that this file does not match itself (it is skipped
anyway).
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: Directories whose text files are checked, and single files checked beside them.
DIRECTORIES = ("bayes_mr", "tests", "docs", "studies", "notebooks", "scripts")
FILES = ("README.md", "docs/results.md", "docs/performance.md")
#: Suffixes of the files read as text (data files, compressed records and caches are not prose).
TEXT_SUFFIXES = {".py", ".md", ".rst", ".txt", ".toml", ".cfg", ".ini", ".yaml", ".yml", ".ipynb"}

_NUMBERED = r"\b(" + "st" + "op|" + "is" + "sue" + r")[ -]?[0-9]+"
_HOUR = r"an " + "hour" + r" (earlier|later)|" + "this" + " " + "hour"
#: A numbered stop or issue, or a run dated against another run.
HISTORY = re.compile(f"{_NUMBERED}|{_HOUR}", re.IGNORECASE)


def _text_files(where: Path) -> list[Path]:
    if where.is_file():
        return [where]
    return sorted(p for p in where.rglob("*")
                  if p.is_file() and p.suffix in TEXT_SUFFIXES and "__pycache__" not in p.parts)


def history_in(where: Path) -> list[str]:
    """``path:line: text`` of every line under ``where`` (a file or a directory) that matches :data:`HISTORY`."""
    hits = []
    for path in _text_files(where):
        if path.resolve() == Path(__file__).resolve():
            continue
        text = path.read_text(encoding="utf-8", errors="replace")
        for number, line in enumerate(text.splitlines(), 1):
            if HISTORY.search(line):
                hits.append(f"{path.relative_to(ROOT)}:{number}: {line.strip()[:160]}")
    return hits


def test_the_pattern_finds_what_it_is_meant_to_find():
    for line in ("until " + "st" + "op 50", "Is" + "sue 15 item 4", "the is" + "sue-15 effects",
                 "in the run an " + "hour" + " later", "measured " + "this" + " " + "hour"):
        assert HISTORY.search(line), line
    for line in ("stopped at 500 steps", "the chain stops on the rule", "an issue of scale", "hourly"):
        assert not HISTORY.search(line), line


@pytest.mark.parametrize("name", DIRECTORIES + FILES)
def test_no_project_history_in(name):
    """Every line of ``name`` says what holds, not which stop, issue or run it came from."""
    where = ROOT / name
    if not where.exists():
        pytest.skip(f"{name} is not in this tree")
    hits = history_in(where)
    assert not hits, (f"{len(hits)} line(s) of project history (keep the reason, name the test or study that "
                      "reproduces a number, move the story to a commit message):\n" + "\n".join(hits))
