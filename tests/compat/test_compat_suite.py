"""The compatibility suite: every case of tests/compat/_cases.py (a Mitsuba 3 plugin with one
of its parameters in one form Mitsuba accepts) rendered by rdsl and compared, tile by tile,
with a high-spp Mitsuba 3 reference (refs/, by make_refs.py).  Noise-aware: rdsl's RMSE to
the reference (the median over three seeds) must be at most RATIO times Mitsuba's own at
the same spp, rendered here by Mitsuba's scalar variant when the ``mitsuba`` package is
installed, else read from refs/noise.json (written with the references)."""

from __future__ import annotations

import pytest
from _sheet import ASSETS, RATIO, REFS, measure
from _suite import SHEETS

pytest.importorskip("rdsl.runtime.embree")


def _params():
    for sh in SHEETS:
        for c in sh.cases:
            # one sheet, one worker under `pytest -n N --dist loadgroup` (a sheet renders once)
            marks = [pytest.mark.xdist_group(sh.name)]
            marks += [pytest.mark.xfail(strict=True, reason=c.xfail)] if c.xfail else []
            yield pytest.param(sh.name, c.name, marks=marks, id=c.name)


@pytest.mark.parametrize("sheet,case", list(_params()))
def test_case_matches_mitsuba(sheet, case):
    ours, theirs, src = measure(sheet)[case]
    assert ours <= RATIO * theirs, (f"{case}: RMSE rdsl {ours:.5f}, Mitsuba {theirs:.5f} "
                                    f"({src}), ratio {ours / theirs:.2f} > {RATIO}")


def test_references_are_small():
    """The committed references and assets stay small (a few MB in all)."""
    total = sum(p.stat().st_size for d in (REFS, ASSETS) for p in d.iterdir())
    assert total < 5e6, total
