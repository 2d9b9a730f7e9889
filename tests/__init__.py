"""The test suite, laid out like the code: one package per room (docs/architecture.md).

A test of ``ROOM/x.py`` (or ``mission/ROOM/x.py``) goes in ``tests/ROOM/`` (``tests/mission/ROOM/``);
helpers shared by several rooms in ``tests/support/``; fixtures shared by a folder in its ``conftest.py``.
Every folder is a package, so a test imports its helpers by their full name
(``from tests.support.wait_helpers import wait_until``) under any pytest import mode.
"""
