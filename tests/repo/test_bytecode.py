"""The sources compiled once for the suite's processes (tests/support/bytecode.py)."""
from __future__ import annotations

import subprocess
import sys

import pytest

from tests.support.bytecode import compile_sources


def _tree(root):
    (root / "pkg" / "sub").mkdir(parents=True)
    (root / "pkg" / "__init__.py").write_text("X = 1\n")
    (root / "pkg" / "sub" / "__init__.py").write_text("")
    (root / "pkg" / "sub" / "mod.py").write_text("def f():\n    return 2\n")
    (root / ".hidden").mkdir()
    (root / ".hidden" / "__init__.py").write_text("")
    (root / "not_a_package").mkdir()
    (root / "not_a_package" / "script.py").write_text("print(1)\n")


def test_every_package_is_compiled_even_when_python_writes_no_bytecode(tmp_path):
    _tree(tmp_path)
    from tests.conftest import TESTS_DIR

    code = (f"import sys; sys.path.insert(0, {str(TESTS_DIR.parent)!r}); "
            "from pathlib import Path; from tests.support.bytecode import compile_sources; "
            f"print([p.name for p in compile_sources(Path({str(tmp_path)!r}))])")
    done = subprocess.run([sys.executable, "-B", "-c", code],  # -B: as PYTHONDONTWRITEBYTECODE=1
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "['pkg']"
    assert list((tmp_path / "pkg" / "__pycache__").glob("__init__.*.pyc"))
    assert list((tmp_path / "pkg" / "sub" / "__pycache__").glob("mod.*.pyc"))
    assert not (tmp_path / ".hidden" / "__pycache__").exists()
    assert not (tmp_path / "not_a_package" / "__pycache__").exists()


def test_a_source_that_does_not_compile_is_named(tmp_path):
    _tree(tmp_path)
    (tmp_path / "pkg" / "sub" / "broken.py").write_text("def f(:\n")
    with pytest.raises(RuntimeError, match="these packages do not compile: pkg"):
        compile_sources(tmp_path)
