"""Output paths of the ``swarmseek`` commands, checked before anything starts.

A log or figure directory that cannot be created or written is an invalid option (exit status 2)
with a message that names the directory and the reason, not a failure blamed on the fleet,
zenoh or the plot after the vehicles were contacted.
"""
from __future__ import annotations

import os
from pathlib import Path

from sitl_mock.cli_args import output_dir_problem

__all__ = ["output_dir_problem", "writable_file_problem"]


def writable_file_problem(path: Path, what: str) -> str | None:
    """Check that an existing file ``path`` can be appended to and that its directory is writable.

    Returns
    -------
    str or None
        None when writable; else a one-line reason (a missing file is left to the caller).
    """
    path = Path(path)
    if not os.path.exists(path):  # os.path: False, not OSError, for a name too long
        return None
    if os.path.isdir(path):
        return f"the {what} {str(path)!r} is a directory, not a file"
    if not os.access(path, os.W_OK):
        return f"cannot write to the {what} {str(path)!r}: permission denied"
    return output_dir_problem(path.parent, f"directory of the {what}")
