"""A scene file rendered by rdsl and by Mitsuba 3 (a scalar variant, skipped where the
`mitsuba` package or the variant is missing), for the noise-aware comparisons of
tests/test_null_bsdf.py and tests/test_principled.py; :func:`mitsuba_variant` for the
tests that call Mitsuba's plugins directly."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import pytest


@contextmanager
def mitsuba_variant(variant: str) -> Iterator[Any]:
    """The `mitsuba` module set to ``variant`` (a test skips without it), and the previous
    variant restored afterwards."""
    mi = pytest.importorskip("mitsuba", reason="the mitsuba package is not installed")
    previous = mi.variant()
    try:
        mi.set_variant(variant)
    except Exception as e:  # noqa: BLE001 - a build without it
        pytest.skip(f"mitsuba variant {variant} unavailable: {e}")
    try:
        yield mi
    finally:
        if previous:
            mi.set_variant(previous)


def render_both(path: Path, variant: str, spp: int) -> tuple[np.ndarray, np.ndarray]:
    """(rdsl's image, Mitsuba's) of the scene file ``path``, RGB, different seeds."""
    pytest.importorskip("rdsl.runtime.embree")
    with mitsuba_variant(f"scalar_{variant}") as mi:
        theirs = np.array(mi.render(mi.load_file(str(path)), spp=spp, seed=1))[..., :3]
    from rdsl.runtime.render.renderer import load_scene

    ours = load_scene(path, variant=variant, target="host").render(spp=spp, seed=2)[..., :3]
    return np.asarray(ours, np.float64), theirs.astype(np.float64)


def block_error(ours: np.ndarray, theirs: np.ndarray, b: int = 6) -> float:
    """The largest difference of b x b block means, relative to Mitsuba's (plus 0.05, so
    that dark blocks are judged in absolute terms)."""
    def blocks(img: np.ndarray) -> np.ndarray:
        h, w, c = img.shape
        return img.reshape(h // b, b, w // b, b, c).mean(axis=(1, 3))
    return float((np.abs(blocks(ours) - blocks(theirs)) / (0.05 + blocks(theirs))).max())


def scene_header(origin: str, target: str, up: str, fov: float = 40.0, res: int = 24,
                 max_depth: int = 8) -> str:
    """A scene's opening: `<scene>`, a `path` integrator and a perspective camera looking
    from ``origin`` at ``target`` on a res x res film (close it with ``</scene>``)."""
    return f"""<scene version="3.0.0">
  <integrator type="path"><integer name="max_depth" value="{max_depth}"/></integrator>
  <sensor type="perspective">
    <float name="fov" value="{fov}"/>
    <transform name="to_world"><lookat origin="{origin}" target="{target}" up="{up}"/>
    </transform>
    <film type="hdrfilm"><integer name="width" value="{res}"/>
      <integer name="height" value="{res}"/></film>
  </sensor>
"""
