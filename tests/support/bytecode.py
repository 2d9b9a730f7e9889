"""Compile the repository's Python sources once, before the workers start (tests/conftest.py).

CI's machine sets ``PYTHONDONTWRITEBYTECODE=1``: no Python process writes a ``.pyc``, so every
pytest worker and every ``python -m mission ...`` process a test starts (the suite starts a few
hundred, from the checkout) compiled each module it imported again, about 0.3 CPU s for a
``swarmseek`` command's imports and more for a worker. Compiled once here (``compileall``
writes the files whatever that variable says, about 1.5 CPU s for the whole tree), they are read by
every later process, which only skips *writing*: reading a valid ``.pyc`` is always allowed.
Nothing changes when the variable is unset (Python then writes them on first import).
"""
from __future__ import annotations

import compileall
from pathlib import Path

__all__ = ["compile_sources"]


def compile_sources(root: Path) -> list[Path]:
    """Byte-compile every package directly under ``root`` (a folder with ``__init__.py``, not hidden).

    Parameters
    ----------
    root : Path
        The repository root.

    Returns
    -------
    list of Path
        The package folders compiled.

    Raises
    ------
    RuntimeError
        If a source file does not compile (a syntax error: the import would fail anyway).
    """
    packages = sorted(p for p in Path(root).iterdir()
                      if p.is_dir() and not p.name.startswith(".") and (p / "__init__.py").is_file())
    failed = [p for p in packages if not compileall.compile_dir(p, quiet=2, workers=1)]
    if failed:
        raise RuntimeError(f"these packages do not compile: {', '.join(p.name for p in failed)}")
    return packages
