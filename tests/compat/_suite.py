"""Every sheet of the compat suite: the BSDFs' (_cases.py), the rest (_cases_scene.py), and
each case rdsl does not load alone on its own sheet (so that it fails by itself)."""

from __future__ import annotations

from _cases import BSDF_SHEETS, UNSUPPORTED
from _cases_outputs import OUTPUT_SHEETS
from _cases_scene import SCENE_SHEETS, UNSUPPORTED_SCENE
from _sheet import Sheet

SHEETS: list[Sheet] = [*BSDF_SHEETS, *SCENE_SHEETS, *OUTPUT_SHEETS,
                       *(Sheet(c.name, (c,)) for c in UNSUPPORTED + UNSUPPORTED_SCENE)]
BY_NAME = {s.name: s for s in SHEETS}
assert len(BY_NAME) == len(SHEETS), "two sheets of one name"
assert len({c.name for s in SHEETS for c in s.cases}) == sum(len(s.cases) for s in SHEETS), \
    "two cases of one name"
