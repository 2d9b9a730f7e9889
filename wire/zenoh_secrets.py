"""Secret files of the zenoh security settings: password file and user dictionary.

Secrets never sit in the plan itself: the password is read from ``password_file``, which, like
the dictionary of ``user:password`` lines and the TLS private keys, must not be world-readable.
Read alike by the plan's ``[zenoh]`` checks (:mod:`mission.core.zenoh_security`) and the
``--zenoh-password-file`` flag (:mod:`wire.zenoh_flags`).
"""
from __future__ import annotations

import os
import stat
from pathlib import Path

__all__ = ["ZenohSecurityError", "private_file_problem", "read_password_file", "check_dictionary_file"]


class ZenohSecurityError(ValueError):
    """A secret file that cannot be used (missing, world-readable, malformed)."""


def private_file_problem(path: str | Path) -> str | None:
    """Why ``path`` cannot hold a secret (missing, not a file, world-readable), or None."""
    p = Path(path)
    if not p.is_file():
        return f"file not found: {p}"
    if os.name == "posix" and p.stat().st_mode & stat.S_IROTH:
        return f"{p} is world-readable; run chmod 600 {p}"
    return None


def read_password_file(path: str | Path) -> str:
    """The password on the first line of ``path`` (trailing newline stripped).

    Raises
    ------
    ZenohSecurityError
        The file is missing, world-readable, not UTF-8 or its first line is empty.
    """
    why = private_file_problem(path)
    if why:
        raise ZenohSecurityError(why)
    try:
        text = Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ZenohSecurityError(f"cannot read {path}: {exc}") from None
    lines = text.splitlines()
    if not lines or not lines[0]:
        raise ZenohSecurityError(f"{path}: the first line (the password) is empty")
    return lines[0]


def check_dictionary_file(path: Path) -> None:
    """Check a zenoh ``usrpwd`` dictionary: private, UTF-8, at least one ``user:password`` line.

    Raises
    ------
    ZenohSecurityError
        Naming the file (and the line) and what is wrong.
    """
    why = private_file_problem(path)
    if why:
        raise ZenohSecurityError(why)
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise ZenohSecurityError(f"cannot read {path}: {exc}") from None
    entries = [ln for ln in lines if ln.strip()]
    if not entries:
        raise ZenohSecurityError(f"{path}: no user:password line")
    for i, line in enumerate(lines, 1):
        if line.strip() and (":" not in line or not line.split(":", 1)[0] or not line.split(":", 1)[1]):
            raise ZenohSecurityError(f"{path} line {i}: expected user:password")
