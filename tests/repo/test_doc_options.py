"""The command-line options README.md and docs/*.md name exist, in the command that takes them.

``tests/repo/test_readme_commands.py`` parses the complete commands; this file checks what it cannot:

* every ``--flag`` inside a ``swarmseek CMD ...`` command, elided ones (``...``) and inline ones
  in docs/*.md included, is an option of ``CMD`` (``run|simulate|sitl``: of each), and a choice
  written after it (``--field plume``, ``--seeker model|ste``) is one of its choices;
* a prose option list (a paragraph opening with "`swarmseek CMD` options:") names options of
  ``CMD`` only, and a list of choices in it (``--field sigma1|sigma2|...``) is complete;
* an option table (header ``| flag | ...``) names options of every command named between the
  section's heading and the table;
* every option of every command is named somewhere in the docs;
* the docs' relative links and ``DIR/README`` references point at files (and headings) that exist.
"""
from __future__ import annotations

import argparse
import re
from functools import cache
from pathlib import Path

import pytest

from mission.cli import COMMANDS, build_parser

ROOT = Path(__file__).resolve().parents[2]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
FLAG = re.compile(r"(?<![\w-])(--[a-z][a-z0-9-]*)(?:[ =]([^\s`,;)]+))?")


@cache
def options(command: str) -> dict[str, argparse.Action]:
    """``command``'s option strings and their argparse actions (its real parser)."""
    parser = build_parser([command])
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return {s: a for a in sub.choices[command]._actions for s in a.option_strings}


def _text(path: Path) -> str:
    return path.read_text(encoding="utf-8")


def _name(path: Path) -> str:
    return str(path.relative_to(ROOT)) if path.is_relative_to(ROOT) else path.name


def command_mentions(text: str) -> list[str]:
    """Every ``swarmseek CMD ...`` written in ``text``: fenced code lines (continuations joined,
    comments dropped, split at ``&&``/``;``) and inline code spans; not program output
    (``swarmseek run: error: ...``)."""
    found = []
    for block in re.findall(r"```[a-z]*\n(.*?)```", text, flags=re.S):
        for line in re.sub(r"\\\n\s*", " ", block).splitlines():
            line = line.split(" #")[0]
            for part in re.split(r"&&|;", line):
                found.extend(m.group(1) for m in re.finditer(r"(?:^|[\s(])(swarmseek [a-z][^&;]*)", part))
    outside = re.sub(r"```.*?```", "", text, flags=re.S)
    found.extend(re.findall(r"`(swarmseek [a-z][^`]*)`", outside))
    return [c.strip() for c in found if not c.split()[1].endswith(":")]


def _commands_named(word: str) -> list[str]:
    """``run`` -> [run]; ``run|simulate|sitl`` -> each."""
    return [c for c in word.replace("\\|", "|").split("|")]


def _choice_values(value: str | None, action: argparse.Action) -> list[str]:
    """The choices written after an option with choices (``a|b``, ``[a]``), placeholders skipped."""
    if value is None or not action.choices or value.startswith("-"):
        return []
    words = value.replace("\\|", "|").strip("[]'\"").split("|")
    return [w for w in words if w and not w.isupper() and w != "..."]


def command_problems(path: Path) -> list[str]:
    """What is wrong with the options of ``path``'s ``swarmseek`` commands."""
    problems = []
    for command in command_mentions(_text(path)):
        for cmd in _commands_named(command.split()[1]):
            if cmd not in COMMANDS:
                problems.append(f"{_name(path)}: {command!r}: no command {cmd!r}")
                continue
            for flag, value in FLAG.findall(command):
                action = options(cmd).get(flag)
                if action is None:
                    problems.append(f"{_name(path)}: {command!r}: `swarmseek {cmd}` has no option {flag}")
                    continue
                bad = [v for v in _choice_values(value or None, action) if v not in action.choices]
                if bad:
                    problems.append(f"{_name(path)}: {command!r}: {flag} {bad} not among {list(action.choices)}")
    return problems


def option_list_problems(path: Path) -> list[str]:
    """What is wrong with ``path``'s prose option lists ("`swarmseek CMD` options: ...")."""
    problems = []
    for cmd, para in re.findall(r"`swarmseek ([a-z-]+)` options:(.*?)(?:\n\s*\n|\Z)", _text(path), flags=re.S):
        para = re.sub(r"\s*\n\s*", " ", para)
        for span in re.findall(r"`(--[^`]+)`", para):
            flag, _, value = span.partition(" ")
            action = options(cmd).get(flag)
            if action is None:
                problems.append(f"{_name(path)}: `swarmseek {cmd}` options list {flag}, which it has not")
                continue
            if action.choices and "|" in value:
                written = set(value.split("|"))
                if written != set(action.choices):
                    problems.append(f"{_name(path)}: `swarmseek {cmd}` options: {span!r} but the choices "
                                    f"are {'|'.join(action.choices)}")
    return problems


def option_tables(text: str) -> list[tuple[list[str], list[str]]]:
    """``(commands, flags)`` of each ``| flag | ...`` table: the commands are those named
    (`swarmseek CMD`) between the section's heading and the table, the flags its first column's."""
    tables = []
    lines = text.splitlines()
    for i, line in enumerate(lines):
        if not re.match(r"\|\s*flag\s*\|", line):
            continue
        start = max((j for j in range(i) if lines[j].startswith("#")), default=0)
        cmds = re.findall(r"`swarmseek ([a-z-]+)`", "\n".join(lines[start:i]))
        flags = []
        for row in lines[i + 2:]:
            if not row.startswith("|"):
                break
            flags.extend(FLAG.findall(row.split("|")[1]))
        tables.append((cmds, [f for f, _ in flags]))
    return tables


def table_problems(path: Path) -> list[str]:
    problems = []
    for cmds, flags in option_tables(_text(path)):
        if not cmds:
            problems.append(f"{_name(path)}: an option table ({flags[:3]}...) names no `swarmseek CMD` above it")
        problems.extend(f"{_name(path)}: option table: `swarmseek {cmd}` has no option {flag}"
                        for cmd in cmds for flag in flags if flag not in options(cmd))
    return problems


@pytest.mark.parametrize("path", DOCS, ids=_name)
def test_every_option_of_a_documented_command_exists(path):
    problems = command_problems(path) + option_list_problems(path) + table_problems(path)
    assert not problems, "\n".join(problems)


def test_the_checks_see_the_docs_commands_lists_and_tables():
    """The extractors find what the docs hold (so that an empty result is no false pass)."""
    mentions = [c for p in DOCS for c in command_mentions(_text(p))]
    assert len(mentions) >= 60
    assert "swarmseek run|simulate|sitl --seeker ste" in mentions
    mission = _text(ROOT / "docs" / "mission.md")
    assert re.search(r"`swarmseek run` options:.*`--field sigma1\|sigma2\|plume\|intermittent`", mission, re.S)
    tables = {_name(p): option_tables(_text(p)) for p in DOCS}
    fields_cmds, fields_flags = tables["docs/fields.md"][0]
    assert fields_cmds == ["run", "mock", "sensor"] and "--wind-from" in fields_flags
    assert set(tables["docs/zenoh.md"][0][0]) == {"sensor", "mock"} and "--zenoh-mtls" in tables["docs/zenoh.md"][0][1]


def test_a_wrong_option_a_wrong_choice_and_an_incomplete_list_are_caught(tmp_path):
    doc = tmp_path / "docs" / "bad.md"
    doc.parent.mkdir()
    doc.write_text("Try `swarmseek run --bogus` and\n\n```\nswarmseek run --field plume ... --seeker magic\n"
                   "swarmseek plot LOG --out DIR --dpi 300\n```\n\n"
                   "`swarmseek run` options: `--field sigma1|sigma2`, `--gone`.\n\n"
                   "## Mock\n\n`swarmseek mock` takes:\n\n| flag | meaning |\n|---|---|\n| `--wind-from DEG` | ok |\n"
                   "| `--nope N` | no |\n")
    problems = command_problems(doc) + option_list_problems(doc) + table_problems(doc)
    text = "\n".join(problems)
    assert "`swarmseek run` has no option --bogus" in text
    assert "--seeker ['magic'] not among" in text
    assert "`swarmseek plot` has no option --dpi" in text
    assert "'--field sigma1|sigma2' but the choices are sigma1|sigma2|plume|intermittent" in text
    assert "options list --gone" in text
    assert "`swarmseek mock` has no option --nope" in text and "--wind-from" not in text
    assert len(problems) == 6, text


def test_every_option_is_named_in_the_docs():
    text = "\n".join(_text(p) for p in DOCS)
    missing = [f"swarmseek {cmd} {a.option_strings[-1]}" for cmd in COMMANDS
               for a in dict.fromkeys(options(cmd).values()) if a.option_strings and "-h" not in a.option_strings
               and not any(re.search(re.escape(s) + r"(?![\w-])", text) for s in a.option_strings)]
    assert not missing, "options no doc names: " + ", ".join(missing)


def _slug(heading: str) -> str:
    """GitHub's anchor of a markdown heading."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def test_relative_links_and_readme_references_resolve():
    problems = []
    for path in DOCS:
        text = _text(path)
        for target in re.findall(r"\]\(([^)\s]+)\)", text):
            if re.match(r"[a-z]+:", target):
                continue
            file, _, anchor = target.partition("#")
            dest = (path.parent / file) if file else path
            if not dest.exists():
                problems.append(f"{_name(path)}: link {target} (no such file)")
            elif anchor and dest.suffix == ".md" and anchor not in {
                    _slug(h) for h in re.findall(r"^#+\s+(.*)$", _text(dest), flags=re.M)}:
                problems.append(f"{_name(path)}: link {target} (no such heading)")
        for ref in re.findall(r"(?<![\w./-])([\w.-]+(?:/[\w.-]+)*/README(?:\.md)?)\b", text):
            if not (ROOT / ref).exists() and not (ROOT / (ref + ".md")).exists():
                problems.append(f"{_name(path)}: refers to {ref}, which does not exist")
    assert not problems, "\n".join(problems)
