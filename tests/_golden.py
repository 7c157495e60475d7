"""Golden files: compare produced text with an expected file under ``tests/golden/``.

Set ``RDSL_UPDATE_GOLDEN=1`` to rewrite the expected files from what the code produces now
(``RDSL_UPDATE_GOLDEN=1 pytest tests/test_golden*.py``), then review the diff.  A missing
expected file is written and the test fails, so that a new case is always reviewed.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from rdsl.compiler.ir import Module
from rdsl.compiler.printer import print_function

GOLDEN = Path(__file__).parent / "golden"


def user_functions(module: Module) -> str:
    """The functions of the program's own file (the prelude and imports are left out)."""
    return "".join(print_function(f, locs=False) + "\n" for f in module.functions.values()
                   if f.attrs.get("export"))


def check_golden(got: str, expected: Path) -> None:
    """Assert that ``got`` is the text of ``expected`` (or rewrite it, see above)."""
    update = bool(os.environ.get("RDSL_UPDATE_GOLDEN"))
    if update or not expected.exists():
        expected.write_text(got)
        if not update:
            pytest.fail(f"{expected.name} was missing and has been written; review it")
    assert got == expected.read_text(), \
        f"{expected} differs; after an intended change run RDSL_UPDATE_GOLDEN=1 pytest " \
        f"{os.environ.get('PYTEST_CURRENT_TEST', '').split('::')[0]} and review the diff"
