"""benchmarks/README.md is the index of benchmarks/: a row for every script, saying what it measures
and the command, and every option that command gives exists in the script it runs."""
from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
BENCHMARKS = ROOT / "benchmarks"


def _rows(readme: str) -> list[tuple[str, str, str]]:
    """``(script, what it measures, command cell)`` of each table row naming a script."""
    rows = []
    for line in readme.splitlines():
        if line.startswith("| `") and line.rstrip().endswith("|"):
            cells = [cell.strip() for cell in line.strip().strip("|").split("|")]
            rows.append((cells[0].strip("`"), cells[1] if len(cells) > 2 else "", cells[-1]))
    return rows


def index_problems(readme: str, sources: dict[str, str]) -> list[str]:
    """What the index gets wrong about the scripts ``sources`` (file name -> source text).

    Parameters
    ----------
    readme : str
        The text of benchmarks/README.md.
    sources : dict of str to str
        Each script of benchmarks/ by file name, with its source.

    Returns
    -------
    list of str
        One line per problem: a script without a row or with two, a row for no script, a row that
        says nothing or gives no command, a command option its script does not define.
    """
    rows = _rows(readme)
    named = [script for script, _, _ in rows]
    problems = [f"{name}: no row in benchmarks/README.md" for name in sorted(sources) if name not in named]
    problems += [f"{name}: {named.count(name)} rows" for name in sorted(set(named)) if named.count(name) > 1]
    for script, measures, command in rows:
        if script not in sources:
            problems.append(f"{script}: a row, but no such script in benchmarks/")
        commands = [c for c in re.findall(r"`([^`]*)`", command) if "benchmarks/" in c]
        if not measures or not commands:
            problems.append(f"{script}: the row must say what it measures and give the command")
        for text in commands:
            ran = re.search(r"benchmarks/([\w.]+\.py)(.*)", text)
            if ran is None or ran.group(1) not in sources:
                problems.append(f"{script}: the command {text!r} runs no script of benchmarks/")
                continue
            for flag in re.findall(r"(?<![\w-])(--[a-z][\w-]*)", ran.group(2)):
                if not re.search(rf"[\"']{re.escape(flag)}[\"']", sources[ran.group(1)]):
                    problems.append(f"{script}: {ran.group(1)} defines no option {flag}")
    return problems


def test_every_benchmark_script_has_a_row_with_a_command_that_parses():
    sources = {path.name: path.read_text(encoding="utf-8") for path in sorted(BENCHMARKS.glob("*.py"))}
    assert len(sources) > 20
    problems = index_problems((BENCHMARKS / "README.md").read_text(encoding="utf-8"), sources)
    assert not problems, "\n".join(problems)


def test_the_index_check_finds_a_missing_row_an_unknown_option_and_a_stray_row():
    sources = {"bench_a.py": 'ap.add_argument("--n", type=int)\n', "bench_b.py": ""}
    readme = ("| script | what it measures | command |\n|---|---|---|\n"
              "| `bench_a.py` | speed | `python benchmarks/bench_a.py --n 4 --quick` |\n"
              "| `bench_c.py` | nothing yet | `python benchmarks/bench_c.py` |\n")
    assert index_problems(readme, sources) == [
        "bench_b.py: no row in benchmarks/README.md",
        "bench_a.py: bench_a.py defines no option --quick",
        "bench_c.py: a row, but no such script in benchmarks/",
        "bench_c.py: the command 'python benchmarks/bench_c.py' runs no script of benchmarks/",
    ]
