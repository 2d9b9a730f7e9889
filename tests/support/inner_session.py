"""A pytest session of its own, for the tests of this suite's pytest plugins (tests/support/*_plugin.py)."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

#: where the plugins live (put on the inner session's PYTHONPATH)
PLUGIN_DIR = Path(__file__).resolve().parent

__all__ = ["PLUGIN_DIR", "run_inner_session"]


def run_inner_session(tmp_path: Path, plugin: str, test_source: str, *args: str,
                      env: dict | None = None) -> subprocess.CompletedProcess:
    """Run ``test_source`` (written to ``tmp_path/test_inner.py``) in a new pytest process with only
    ``plugin`` loaded (plus pytest's own and installed ones), a bare ini, ``args`` appended.

    Parameters
    ----------
    tmp_path : Path
        The inner session's directory (its rootdir and working directory).
    plugin : str
        Module name of the plugin under test (in :data:`PLUGIN_DIR`).
    test_source : str
        The inner test file's text.
    *args : str
        More pytest arguments.
    env : dict, optional
        The environment (default: this process's), PYTHONPATH set to :data:`PLUGIN_DIR`.
    """
    (tmp_path / "pytest.ini").write_text("[pytest]\n")
    (tmp_path / "test_inner.py").write_text(test_source)
    env = dict(os.environ if env is None else env, PYTHONPATH=str(PLUGIN_DIR))
    env.pop("PYTEST_ADDOPTS", None)  # the outer session's options (e.g. --cpu-report) are not the inner one's
    return subprocess.run([sys.executable, "-m", "pytest", "-p", plugin, "-p", "no:cacheprovider",
                           "-c", str(tmp_path / "pytest.ini"), "--rootdir", str(tmp_path),
                           str(tmp_path / "test_inner.py"), *args],
                          capture_output=True, text=True, env=env, timeout=180, cwd=tmp_path)
