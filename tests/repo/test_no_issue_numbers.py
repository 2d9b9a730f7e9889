"""The repository names no issue numbers: code, tests and docs say what a thing does, not which
ticket asked for it (an issue's number means nothing to a reader of a fresh clone)."""
from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
ISSUE_NUMBER = re.compile(r"\bissues? ?#?\d+\b", re.IGNORECASE)


def _tracked_text_files() -> list[Path]:
    out = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True, check=True).stdout
    suffixes = {".py", ".md", ".toml", ".txt", ".cfg", ".yml", ".yaml", ".sh", ".html", ".js"}
    return [ROOT / p for p in out.splitlines() if Path(p).suffix in suffixes or p.startswith(".ci/")]


def test_no_file_names_an_issue_number():
    files = _tracked_text_files()
    assert len(files) > 100, "git ls-files found too few files: is this a git checkout?"
    hits = []
    for path in files:
        if path == Path(__file__).resolve() or not path.is_file():
            continue
        for i, line in enumerate(path.read_text(encoding="utf-8", errors="replace").splitlines(), 1):
            if ISSUE_NUMBER.search(line):
                hits.append(f"{path.relative_to(ROOT)}:{i}: {line.strip()[:100]}")
    assert not hits, "issue numbers in the repository:\n" + "\n".join(hits)


@pytest.mark.parametrize("text", ["see issue 23", "Issue #19:", "(issues 18)"])
def test_the_pattern_catches_issue_numbers(text):
    assert ISSUE_NUMBER.search(text)


@pytest.mark.parametrize("text", ["tissue 3", "the issue was 3 m off", "reissue"])
def test_the_pattern_leaves_other_words(text):
    assert not ISSUE_NUMBER.search(text)
