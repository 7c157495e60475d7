"""One stdlib BSDF plugin in any variant, called the way the renderer calls it.

:class:`Harness` compiles a small kernel per plugin and variant that sets the sample's
wavelengths (``sample_wavelengths(ul)``: a no-op outside spectral variants) and then calls
``scene_bsdf_sample`` / ``_eval`` / ``_pdf`` of a one-BSDF scene, in the generic build
(``specialize`` with the parameter values read from ``PRM`` at run time: one compile serves
every value).  It looks like the plugin's own module: ``h["dielectric.sample"](si, u1, u2,
int_ior=1.33)``, with Python values for the parameters:

* numbers stay numbers (a flat spectrum for colour parameters), an RGB triple is a colour
  (:class:`SpectrumValue`: upsampled at the wavelengths in spectral variants, luminance in
  mono), and a :class:`SpectrumValue` with a table is that spectrum (spectral variants);
* the wavelengths of row i come from ``ul[i]`` (keyword ``ul``; by default a fixed sequence
  over the rows, so that a sample() and an eval() of the same rows share their wavelengths);
  :meth:`Harness.wavelengths` returns them (n, 4), or None outside spectral variants;
* colour results are the intensity, (n,) in mono, (n, 3) rgb, (n, 4) spectral, the entry
  [0][0] of the Mueller matrix in polarized variants; a sample() result then also holds
  ``mueller`` (n, 4, 4) or (n, 4, 4, 4) (row, column, wavelength), and eval() gives it with
  ``mueller=True``;
* :meth:`Harness.disperses` is the BSDF's ``disperses()`` (false when it has none): the path
  integrator then multiplies its throughput by (4, 0, 0, 0) once (stdlib/dispersion.rdsl).

:class:`SceneBsdfs` does the same for the BSDFs of a scene file's shapes, combinators
(``twosided``, ``blendbsdf``, ``mask``) included, flattened as the renderer flattens them
(runtime/render/bsdfs.py) and compiled into one module: ``SceneBsdfs(path, variant)[k]`` is
shape k's BSDF, a :class:`Harness` whose parameters are the scene's.
"""

from __future__ import annotations

import re
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
import rdsl
from rdsl.compiler.passes.specialize import parameter_slots
from rdsl.core import spectral as S
from rdsl.core.color import MODELS, VARIANTS  # noqa: F401 (VARIANTS: for the tests)
from rdsl.core.scene_spec import Instance, SceneSpec, SpectrumValue
from rdsl.runtime.plugins import stdlib_plugin
from rdsl.runtime.render.bsdfs import bsdf_instance, split_leaves
from rdsl.runtime.scene.loader import load_scene_description

STDLIB = Path(rdsl.__file__).resolve().parent / "stdlib"
IOR_DIR = STDLIB / "data" / "ior"
LUMINANCE = np.array([0.212671, 0.715160, 0.072169])  # CIE Y of the linear sRGB primaries
f32 = np.float32
_GOLDEN = 0.6180339887498949

SOURCE = """import render.scene;
import spectral;
{imports}

fn h_sample(id: Int, si: Surface, u1: Float, u2: Vec2, ul: Float, T: [Float]) -> BsdfSample {{
    let w = sample_wavelengths(ul);
    return scene_bsdf_sample(id, si, u1, u2, T);
}}
fn h_eval(id: Int, si: Surface, wo: Vec3, ul: Float, T: [Float]) -> Spectrum {{
    let w = sample_wavelengths(ul);
    return scene_bsdf_eval(id, si, wo, T);
}}
fn h_pdf(id: Int, si: Surface, wo: Vec3, ul: Float, T: [Float]) -> Float {{
    let w = sample_wavelengths(ul);
    return scene_bsdf_pdf(id, si, wo, T);
}}
fn h_disperses(id: Int, ul: Float, T: [Float]) -> Bool {{
    let w = sample_wavelengths(ul);
    return scene_bsdf_disperses(id, T);
}}
fn entry(s: Spectrum, e: Spectrum) -> Float {{ return mean(unpolarized(s * e)) * 4.0; }}
fn h_wavelengths(ul: Float) -> Vec4 {{
    let w = sample_wavelengths(ul);
    var out = Vec4(0.0);
    if const spectral {{
        let l = wavelengths();
        out = Vec4(entry(l, Spectrum(1.0, 0.0, 0.0, 0.0)), entry(l, Spectrum(0.0, 1.0, 0.0, 0.0)),
                   entry(l, Spectrum(0.0, 0.0, 1.0, 0.0)), entry(l, Spectrum(0.0, 0.0, 0.0, 1.0)));
    }}
    return out;
}}
"""


@cache
def plugin_defaults(name: str, path: Path | None = None) -> dict[str, tuple[str, Any]]:
    """The plugin's params: name -> (type, default), read from its source (the stdlib's, or
    the user plugin file ``path``)."""
    src = (path or STDLIB / "bsdf" / f"{name}.rdsl").read_text()
    out: dict[str, tuple[str, Any]] = {}
    for pname, ptype, default in re.findall(r"^\s*param\s+(\w+)\s*:\s*(\w+)\s*=\s*([^;]+);",
                                            src, re.MULTILINE):
        d = default.strip()
        value: Any = d == "true" if d in ("true", "false") else (
            int(d) if ptype == "Int" else float(d))
        out[pname] = (ptype, value)
    return out


def default_ul(n: int) -> np.ndarray:
    """The wavelength sample of row i: a golden-ratio sequence (low discrepancy)."""
    return ((0.5 + _GOLDEN * np.arange(n)) % 1.0).astype(f32)


class Harness:
    """Plugin ``name`` in ``variant`` through the scene dispatch (see the module docstring)."""

    ident = 0  # the scene's BSDF that the kernels call

    def __init__(self, name: str, variant: str = "rgb", target: str = "host",
                 path: str | Path | None = None) -> None:
        """``path``: the file of a user plugin ``name`` (default: the stdlib's plugin)."""
        self.name, self.variant, self.target = name, variant, target
        self.path = Path(path).resolve() if path is not None else None
        self.model = MODELS[variant]
        self.polarized, self.spectral = self.model.polarized, self.model.spectral
        self._mods: dict[str, Any] = {}

    # -- compilation ---------------------------------------------------------------------
    def _params(self, params: dict[str, Any]) -> dict[str, Any]:
        defaults = plugin_defaults(self.name, self.path)
        unknown = set(params) - set(defaults)
        if unknown:
            raise TypeError(f"{self.name} has no parameter(s) {sorted(unknown)}")
        out = {}
        for k, (ptype, default) in defaults.items():
            v = params.get(k, default)
            if ptype in ("Spectrum", "Texture") and isinstance(v, (tuple, list, np.ndarray)):
                v = SpectrumValue(tuple(float(x) for x in v))
            out[k] = v
        return out

    def module(self, params: dict[str, Any]) -> tuple[Any, np.ndarray]:
        """The compiled module for these parameters' layout, and their ``PRM`` buffer."""
        scene = SceneSpec(bsdfs=[Instance(self.name, self._params(params))])
        spec, prm = parameter_slots(scene, self.model)
        key = repr(spec)
        if key not in self._mods:
            module = f"bsdf.{self.name}" if self.path is None else self.path.stem
            paths = [] if self.path is None else [self.path.parent]
            self._mods[key] = rdsl.jit(SOURCE.format(imports=f"import {module};"),
                                       target=self.target, variant=self.variant, scene=spec,
                                       search_paths=paths)
        return self._mods[key], np.asarray(prm if len(prm) else np.zeros(1), f32)

    def _call(self, kernel: str, n: int, args: list, ul: Any, params: dict) -> Any:
        mod, prm = self.module(params)
        k = mod[kernel]
        ul = default_ul(n) if ul is None else np.broadcast_to(np.asarray(ul, f32), (n,))
        extra = [prm] if any(p["name"] == "PRM" for p in k.info["params"]) else []
        return k(np.full(n, self.ident, np.int32), *args, np.ascontiguousarray(ul),
                 np.zeros(1, f32),
                 *extra)

    # -- the plugin's interface ----------------------------------------------------------
    def _split(self, value: Any, n: int) -> tuple[np.ndarray, np.ndarray | None]:
        """(intensity, full Mueller matrix or None) of a colour result."""
        if not isinstance(value, dict):
            return np.asarray(value), None
        m = np.stack([np.stack([np.asarray(value[f"m{i}{j}"]) for j in range(4)], 1)
                      for i in range(4)], 1)
        return m[:, 0, 0], m

    def sample(self, si: dict, u1: np.ndarray, u2: np.ndarray, ul: Any = None,
               **params: Any) -> dict[str, np.ndarray]:
        n = len(u1)
        bs = self._call("h_sample", n, [si, u1, u2], ul, params)
        out = {k: np.asarray(v) for k, v in bs.items() if k != "weight"}
        out["weight"], m = self._split(bs["weight"], n)
        if m is not None:
            out["mueller"] = m
        return out

    def eval(self, si: dict, wo: np.ndarray, ul: Any = None, mueller: bool = False,
             **params: Any) -> np.ndarray:
        value, m = self._split(self._call("h_eval", len(wo), [si, wo], ul, params), len(wo))
        if mueller:
            return m if m is not None else value.reshape(len(wo), 1, 1, *value.shape[1:])
        return value

    def pdf(self, si: dict, wo: np.ndarray, ul: Any = None, **params: Any) -> np.ndarray:
        return np.asarray(self._call("h_pdf", len(wo), [si, wo], ul, params))

    def disperses(self, **params: Any) -> bool:
        """Whether the integrator follows the hero wavelength alone after this BSDF."""
        return bool(np.asarray(self._call("h_disperses", 1, [], None, params))[0])

    def wavelengths(self, n: int, ul: Any = None) -> np.ndarray | None:
        """The wavelengths (nm) of n rows, (n, 4); None outside spectral variants."""
        if not self.spectral:
            return None
        mod = next(iter(self._mods.values()), None) or self.module({})[0]
        ul = default_ul(n) if ul is None else np.broadcast_to(np.asarray(ul, f32), (n,))
        return np.asarray(mod["h_wavelengths"](np.ascontiguousarray(ul)))

    def __getitem__(self, key: str):
        plugin, _, method = key.partition(".")
        if plugin != self.name or method not in ("sample", "eval", "pdf"):
            raise KeyError(key)
        return getattr(self, method)


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
        super().__init__("mixture", owner.variant, owner.target)
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
