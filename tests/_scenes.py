"""Where the tests find the Cornell box: the shared scenes folder next to this checkout when
it is there, else the copy in examples/cbox/ (a fresh clone has only that one)."""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
_SHARED = ROOT.parent / "shared" / "scenes"
SCENES = _SHARED if (_SHARED / "cbox" / "cbox.xml").is_file() else ROOT / "examples"
CBOX = SCENES / "cbox" / "cbox.xml"
