"""The inverse-rendering examples (examples/inverse/) in a reduced mode: a few iterations at a
small size, checking that the loss decreases and that every recovered component moves toward
the truth.  The full runs and their errors are in docs/ad.md."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

EXAMPLES = Path(__file__).resolve().parents[1] / "examples" / "inverse"
needs_cbox = pytest.mark.skipif(not (EXAMPLES.parents[0] / "cbox" / "cbox.xml").exists(),
                                reason="examples/cbox/cbox.xml is missing")


def example(name: str):
    spec = importlib.util.spec_from_file_location(f"inverse_{name}", EXAMPLES / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def assert_descends(losses, start, got, truth) -> None:
    losses = np.asarray(losses)
    assert losses[-3:].mean() < 0.5 * losses[0], losses
    start, got, truth = (np.asarray(x, np.float64) for x in (start, got, truth))
    assert (np.abs(got - truth) < np.abs(start - truth)).all(), (start, got, truth)


@needs_cbox
def test_light_radiance_example_descends(tmp_path):
    ex = example("light_radiance")
    r = ex.recover(res=16, spp=4, iterations=12, lr=2.0, decay=0.9, out=tmp_path,
                   log=lambda line: None)
    assert_descends(r["losses"], np.full(3, 5.0), r[ex.LIGHT], r["truth"])
    names = {p.name for p in tmp_path.iterdir()}
    assert {"radiance_before.png", "radiance_target.png", "radiance_after.png"} <= names


@needs_cbox
def test_texture_example_descends(tmp_path):
    ex = example("texture")
    r = ex.recover(res=32, spp=2, iterations=8, lr=0.1, decay=0.9, target_spp=64,
                   folder=tmp_path, out=tmp_path, log=lambda line: None)
    assert r[ex.TEXELS].shape == (64, 64, 3)
    m = r["seen"]
    assert m.sum() > 500, m.sum()  # the camera sees a good part of the wall
    losses = np.asarray(r["losses"])
    assert losses[-3:].mean() < 0.7 * losses[0], losses
    err0 = np.abs(r["start"] - r["truth"])[m].mean()
    err = np.abs(r[ex.TEXELS] - r["truth"])[m].mean()
    assert err < 0.8 * err0, (err, err0)
    assert (tmp_path / "texture_recovered.png").is_file()
