"""Compile the repository's Python sources once, before the workers start (tests/conftest.py).

CI's machine sets ``PYTHONDONTWRITEBYTECODE=1``: no Python process writes a ``.pyc``, so every
pytest worker and every ``python -m mission ...`` process a test starts (the suite starts a few
hundred, from the checkout) compiled each module it imported again, about 0.3 CPU s for a
``swarmseek`` command's imports and more for a worker. Compiled once here (``compileall``
writes the files whatever that variable says, about 1.5 CPU s for the whole tree), they are read by
every later process, which only skips *writing*: reading a valid ``.pyc`` is always allowed.
Nothing changes when the variable is unset (Python then writes them on first import).

The test modules themselves are imported through pytest's assertion rewriting, which under that
variable writes no cache either: each of the four workers rewrote all of them again while
collecting (14 CPU s a worker against 5.7 s with the cache, at the start of a session when every
worker collects at once). :func:`rewrite_tests` writes that cache once, with pytest's own
rewriting, in two forked processes; a worker reads a valid cached module whatever the variable says.
"""
from __future__ import annotations

import compileall
import os
from pathlib import Path

__all__ = ["compile_sources", "rewrite_tests"]


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


def _rewrite_share(files: list[Path], config) -> int:
    """Write pytest's rewritten ``.pyc`` of each test module of ``files`` that has no valid one;
    1 if one of them failed (it is left to the worker's collection), else 0."""
    from _pytest.assertion import rewrite  # pytest's own rewriting: tests/repo/test_bytecode.py checks its use

    status = 0
    for fn in files:
        pyc = rewrite.get_cache_dir(fn) / (fn.name[:-3] + rewrite.PYC_TAIL)
        try:
            if rewrite._read_pyc(fn, pyc) is None:
                pyc.parent.mkdir(exist_ok=True)
                source_stat, co = rewrite._rewrite_test(fn, config)
                rewrite._write_pyc(config.stash[rewrite.assertstate_key], co, source_stat, pyc)
        except (OSError, SyntaxError, ValueError):
            status = 1
    return status


def rewrite_tests(tests_dir: Path, config, processes: int = 2) -> int:
    """Write the assertion-rewritten ``.pyc`` of every ``test_*.py`` and ``conftest.py`` under ``tests_dir``.

    Parameters
    ----------
    tests_dir : Path
        The tests' folder.
    config : pytest.Config
        The session's configuration (its assertion rewriting's settings).
    processes : int
        Forked processes sharing the files (the work is CPU-bound Python).

    Returns
    -------
    int
        Processes that failed (a file that does not parse is left to the worker's collection, which
        reports it; an unwritable folder leaves the workers rewriting as before).
    """
    files = sorted(p for p in Path(tests_dir).rglob("*.py")
                   if (p.name.startswith("test_") or p.name == "conftest.py") and "__pycache__" not in p.parts)
    pids = []
    for part in range(processes):
        pid = os.fork()
        if pid == 0:  # the child: its share, then out without pytest's exit handlers, whatever happens
            status = 1    # (an exception must never unwind into a second pytest session in the child)
            try:
                status = _rewrite_share(files[part::processes], config)
            finally:
                os._exit(status)
        pids.append(pid)
    return sum(os.waitpid(pid, 0)[1] != 0 for pid in pids)
