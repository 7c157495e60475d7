"""The test suite's side of the plugin harness (rdsl.runtime.testkit.harness: one plugin in
any variant through the scene dispatch, ``Harness("diffuse", "spectral")``).

:class:`SceneBsdfs` does the same for the BSDFs of a scene file's shapes, combinators
(``twosided``, ``blendbsdf``, ``mask``) included, flattened as the renderer flattens them
(runtime/render/bsdfs.py) and compiled into one module: ``SceneBsdfs(path, variant)[k]`` is
shape k's BSDF, a :class:`Harness` whose parameters are the scene's.  :func:`colour_at` is
an independent numpy model of a colour parameter per variant.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import rdsl
from rdsl.core import spectral as S
from rdsl.core.color import VARIANTS  # noqa: F401 (for the tests)
from rdsl.core.scene_spec import SceneSpec, SpectrumValue
from rdsl.runtime.plugins import stdlib_plugin
from rdsl.runtime.render.bsdfs import bsdf_instance, split_leaves
from rdsl.runtime.scene.loader import load_scene_description
from rdsl.runtime.testkit.harness import SOURCE, Declaration, Harness

STDLIB = Path(rdsl.__file__).resolve().parent / "stdlib"
IOR_DIR = STDLIB / "data" / "ior"
LUMINANCE = np.array([0.212671, 0.715160, 0.072169])  # CIE Y of the linear sRGB primaries
f32 = np.float32


class SceneBsdfs:
    """The BSDFs of the shapes of scene file ``path`` in ``variant``, compiled into one module
    with their parameters folded (see the module docstring); ``self[k]`` is shape k's."""

    def __init__(self, path: str | Path, variant: str, target: str = "host") -> None:
        desc = load_scene_description(path)
        bsdfs, leaves = split_leaves([bsdf_instance(shape.bsdf) for shape in desc.shapes])
        imports = sorted({stdlib_plugin("bsdf", i.plugin).import_name for i in [*bsdfs, *leaves]})
        self.variant, self.target = variant, target
        self.module = rdsl.jit(SOURCE.format(imports="".join(f"import {m};\n" for m in imports)),
                               target=target, variant=variant,
                               scene=SceneSpec(bsdfs=bsdfs, bsdf_leaves=leaves))
        self.count = len(bsdfs)

    def __getitem__(self, k: int) -> Harness:
        if not 0 <= k < self.count:
            raise IndexError(k)
        return _SceneBsdf(self, k)


class _SceneBsdf(Harness):
    """Shape k's BSDF of a :class:`SceneBsdfs`: its parameters are the scene's."""

    def __init__(self, owner: SceneBsdfs, k: int) -> None:
        # the scene's own dispatch: no plugin declaration of its own to read params from
        decl = Declaration("bsdf", "mixture", STDLIB / "bsdf" / "mixture.rdsl", 0, (), ())
        super().__init__(variant=owner.variant, target=owner.target, decl=decl)
        self.owner, self.ident = owner, k

    def module(self, params: dict[str, Any]) -> tuple[Any, np.ndarray]:
        if params:
            raise TypeError(f"a scene's BSDF takes the scene's parameters, not {sorted(params)}")
        return self.owner.module, np.zeros(1, f32)


# ---------------------------------------------------------------------- colours per variant

def ior_table(name: str) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """A tabulated spectrum of stdlib/data/ior (wavelengths in nm, values)."""
    rows = [ln.split() for ln in (IOR_DIR / name).read_text().splitlines()
            if ln.strip() and not ln.startswith("#")]
    return tuple(float(r[0]) for r in rows), tuple(float(r[1]) for r in rows)


def colour_at(variant: str, value: Any, wavelengths: np.ndarray | None) -> np.ndarray:
    """What a colour parameter is per row and channel in `variant` (an independent numpy
    model): RGB, its luminance (mono), or its spectrum at the rows' wavelengths."""
    if isinstance(value, SpectrumValue) and value.samples is not None and wavelengths is not None:
        return S.tabulated(*value.samples, wavelengths)  # the knots' interpolant
    rgb = np.asarray(value.rgb if isinstance(value, SpectrumValue) else value, np.float64)
    if variant.startswith("mono"):
        return np.atleast_1d(rgb @ LUMINANCE)[None, :]
    if wavelengths is None:
        return rgb[None, :]
    return S.eval_coeffs(S.rgb_to_coeffs(rgb), wavelengths)
