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


def test_the_test_modules_are_rewritten_once_for_the_workers(tmp_path, request):
    from _pytest.assertion import rewrite

    from tests.support.bytecode import rewrite_tests

    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "test_one.py").write_text("def test_a():\n    x = 1\n    assert x == 2\n")
    (tmp_path / "conftest.py").write_text("X = 1\n")
    (tmp_path / "helper.py").write_text("Y = 2\n")  # not a test module: imported as any module
    (tmp_path / "test_broken.py").write_text("def f(:\n")  # left to the collection, which reports it
    assert rewrite_tests(tmp_path, request.config) == 1  # the process that met the broken file
    cached = {}
    for fn in (tmp_path / "sub" / "test_one.py", tmp_path / "conftest.py"):
        pyc = rewrite.get_cache_dir(fn) / (fn.name[:-3] + rewrite.PYC_TAIL)
        cached[fn.name] = rewrite._read_pyc(fn, pyc)  # what a worker's import reads before it would rewrite
        assert cached[fn.name] is not None, fn
    test_a = next(c for c in cached["test_one.py"].co_consts if getattr(c, "co_name", None) == "test_a")
    assert any(name.startswith("@py_assert") for name in test_a.co_varnames)  # rewritten, not plain
    assert not (tmp_path / "__pycache__" / ("helper" + rewrite.PYC_TAIL)).exists()
    assert not list((tmp_path / "__pycache__").glob("test_broken*"))
