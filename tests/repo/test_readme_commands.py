"""The ``swarmseek ...`` commands a user would copy from README.md and docs/*.md must parse.

Every command in README.md (code blocks and inline code) and in the fenced code blocks of
docs/*.md is extracted, its placeholders (``LAT,LON,ALT``, ``LOG``, ``N``, ``a|b`` ...) are
replaced by example values and it is parsed by the real ``swarmseek`` argument parser: an
unknown option, a missing required one or a bad value fails the test, without flying anything.
Checks a command's ``main`` makes before it starts (``sensor`` needs a zenoh endpoint, ``run``
its ``--n`` range, ``mock`` its ``--fault`` sysids) are checked too, through the same functions.
"""
from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest

from mission.cli import COMMANDS, build_parser

ROOT = Path(__file__).resolve().parents[2]
SAMPLE_PLAN = str(ROOT / "mission" / "examples" / "sitl_plan.toml")
#: options whose value is a file the user provides (certificates, keys): made empty, chmod 600
USER_FILE_OPTIONS = ("--zenoh-tls-ca", "--zenoh-tls-cert", "--zenoh-tls-key", "--zenoh-password-file",
                     "--signing-key-file")

#: placeholder token -> example value (whole tokens only; ``LAT,LON,ALT`` also after ``=``)
PLACEHOLDERS = {
    "LAT,LON,ALT": "45.19,5.72,230",
    "E,N,U": "1,2,14",
    "plan.toml": SAMPLE_PLAN,
    "PLAN": SAMPLE_PLAN,
    "LOG": "logs/mission.jsonl",
    "LOG_DIR": "logs",
    "DIR": "out",
    "N": "4",
    "S": "10",
    "NAME": "sigma2",
    "FLEET": "swarmseek",
    "EP": "tcp/127.0.0.1:7447",
}


def _shell_arithmetic(text: str) -> str:
    """``$((5762 + 10 * i))`` -> ``5762`` (the first iteration of the docs' ``for i`` loops)."""
    def value(m: re.Match) -> str:
        expr = m.group(1).replace("i", "0")
        if not re.fullmatch(r"[0-9+*() -]+", expr):
            raise ValueError(f"cannot evaluate shell arithmetic {m.group(0)!r}")
        return str(eval(expr))  # noqa: S307 - digits and + * ( ) only, checked above

    return re.sub(r"\$\(\((.*?)\)\)", value, text)


def _fenced_lines(text: str):
    """Logical lines of the fenced code blocks (``\\`` continuations joined, comments dropped)."""
    for block in re.findall(r"```[a-z]*\n(.*?)```", text, flags=re.S):
        joined = re.sub(r"\\\n\s*", " ", block)
        for line in joined.splitlines():
            line = line.split(" #")[0].strip()
            if line.startswith("#"):
                continue
            yield line


def extract_commands(path: Path, inline: bool) -> list[str]:
    """The ``swarmseek ...`` commands of a markdown file, as written (before substitution)."""
    text = path.read_text()
    found = []
    for line in _fenced_lines(text):
        for part in re.split(r"&&|;|(?<!\\)&", line):
            part = part.strip()
            if part.startswith("swarmseek ") and not part.split()[1].endswith(":"):  # not output
                found.append(part)
    if inline:
        outside = re.sub(r"```.*?```", "", text, flags=re.S)
        found.extend(span for span in re.findall(r"`(swarmseek [^`]+)`", outside))
    return found


def _substitute(command: str) -> list[str] | None:
    """argv for the parser (without ``swarmseek``), or None for an elided command (``...``)."""
    if "..." in command or "…" in command:
        return None
    command = _shell_arithmetic(command).replace("\\|", "|").replace("[", "").replace("]", "")
    argv = []
    for token in shlex.split(command)[1:]:
        key, eq, value = token.partition("=")
        if eq and key.startswith("--"):
            token = f"{key}={PLACEHOLDERS.get(value, value)}"
        else:
            token = PLACEHOLDERS.get(token, token)
        if "|" in token and not token.startswith("-"):
            token = token.split("|")[0]  # a choice: the first alternative
        argv.append(token)
    return argv


def _all_commands() -> list[tuple[str, str]]:
    cases = [("README.md", c) for c in extract_commands(ROOT / "README.md", inline=True)]
    for doc in sorted((ROOT / "docs").glob("*.md")):
        cases.extend((f"docs/{doc.name}", c) for c in extract_commands(doc, inline=False))
    return cases


COMMAND_CASES = _all_commands()


def _pre_run_problem(args) -> str | None:
    """The checks a command's ``main`` makes on its arguments before it contacts anything."""
    if args.command == "sensor" and not (args.zenoh_listen or args.zenoh_connect):
        return "swarmseek sensor needs --zenoh-listen or --zenoh-connect"
    if args.command == "run":
        from mission.cli.cmd_run import _check_args

        return _check_args(args)
    if args.command == "mock":
        bad = [sysid for sysid, _name, _value in args.fault if sysid > args.vehicles]
        return f"--fault for sysids {bad} beyond --vehicles {args.vehicles}" if bad else None
    return None


def test_the_docs_hold_commands_of_every_kind():
    commands = {_substitute(c)[0] for _, c in COMMAND_CASES if _substitute(c)}
    assert len(COMMAND_CASES) >= 20
    assert {"run", "fly", "dry-run", "plot", "resume", "audit", "mock", "sensor", "paper"} <= commands


def _make_user_files(argv: list[str], directory: Path) -> None:
    """Create the certificate / key / password files a command names (the user's own files)."""
    for flag, value in zip(argv, argv[1:]):
        if flag in USER_FILE_OPTIONS:
            path = directory / value
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text("placeholder\n")
            path.chmod(0o600)


@pytest.mark.parametrize("source,command", COMMAND_CASES, ids=[f"{s}:{c[:60]}" for s, c in COMMAND_CASES])
def test_documented_command_parses(source, command, tmp_path, monkeypatch, capsys):
    argv = _substitute(command)
    if argv is None:
        pytest.skip("elided command (...)")
    monkeypatch.chdir(tmp_path)
    _make_user_files(argv, tmp_path)
    if argv[0].startswith("-"):  # a top-level option (--version, --help): prints and exits 0
        with pytest.raises(SystemExit) as exc:
            build_parser(argv).parse_args(argv)
        assert exc.value.code == 0, f"{source}: {command!r}: {capsys.readouterr().err}"
        return
    assert argv and argv[0] in COMMANDS, f"{source}: {command!r} names no swarmseek command"
    parser = build_parser(argv)
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:
        pytest.fail(f"{source}: {command!r} does not parse (exit {exc.code}): {capsys.readouterr().err}")
    problem = _pre_run_problem(args)
    assert problem is None, f"{source}: {command!r} would be refused: {problem}"


def test_a_broken_command_is_caught(capsys):
    """The checker itself: a missing value, an unknown option and a sensor without endpoint fail."""
    for command in ("swarmseek sensor --connect tcp:127.0.0.1:5762 --field sigma2 --origin LAT,LON,ALT",
                    "swarmseek run --bogus", "swarmseek plot"):
        argv = _substitute(command)
        try:
            args = build_parser(argv).parse_args(argv)
        except SystemExit as exc:
            assert exc.code == 2
            continue
        assert _pre_run_problem(args) is not None, command
    capsys.readouterr()


def test_placeholders_and_shell_forms_are_substituted():
    assert _substitute("swarmseek sensor --connect tcp:127.0.0.1:$((5762 + 10 * i)) --sysid $((i + 1)) "
                       "--origin=LAT,LON,ALT") == ["sensor", "--connect", "tcp:127.0.0.1:5762", "--sysid", "1",
                                                   "--origin=45.19,5.72,230"]
    assert _substitute("swarmseek mock --personality ardupilot\\|px4 --vehicles N") == [
        "mock", "--personality", "ardupilot", "--vehicles", "4"]
    assert _substitute("swarmseek resume LOG [--plan plan.toml]") == [
        "resume", "logs/mission.jsonl", "--plan", SAMPLE_PLAN]
    assert _substitute("swarmseek plot ... --out DIR") is None
