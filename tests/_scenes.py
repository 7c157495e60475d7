"""Where the tests find the Cornell box: the shared scenes folder next to this checkout when
it is there, else the copy in examples/cbox/ (a fresh clone has only that one)."""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
_SHARED = ROOT.parent / "shared" / "scenes"
SCENES = _SHARED if (_SHARED / "cbox" / "cbox.xml").is_file() else ROOT / "examples"
CBOX = SCENES / "cbox" / "cbox.xml"


def edited_copy(scene: Path, folder: Path, old: str, new: str) -> Path:
    """``scene`` with its text ``old`` (which must be there) replaced by ``new``, written into
    ``folder`` beside links to the other files of its folder (meshes, plugins)."""
    text = scene.read_text()
    assert old in text, f"{scene} has no `{old}`"
    for f in scene.parent.iterdir():
        if f.name != scene.name:
            (folder / f.name).symlink_to(f)
    path = folder / scene.name
    path.write_text(text.replace(old, new))
    return path
