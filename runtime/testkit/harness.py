"""One plugin (a BSDF, an emitter or a texture) in any variant, called the way the renderer
calls it.

:class:`Harness` compiles a small kernel per plugin and variant that sets the sample's
wavelengths (``sample_wavelengths(ul)``: a no-op outside spectral variants) and then calls
``scene_bsdf_sample`` / ``_eval`` / ``_pdf`` (``scene_emitter_eval``, ``scene_texture_eval``)
of a one-plugin scene, in the generic build (``specialize`` with the parameter values read
from ``PRM`` at run time: one compile serves every value).  It looks like the plugin's own
module: ``h["dielectric.sample"](si, u1, u2, int_ior=1.33)``, with Python values for the
parameters:

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
* :meth:`Harness.disperses` is the BSDF's ``disperses()`` (false when it has none), and
  :meth:`Harness.smooth` its ``smooth()`` (true when it has none).

The plugin is a stdlib one by name (``Harness("diffuse")``) or any ``.rdsl`` file's
(:func:`declarations` lists a file's plugins; ``Harness(decl=...)``).  The file is imported
by its name from a harness that sits, for its imports, in the file's folder.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np

from ...compiler.diagnostics import CompileError
from ...compiler.ir import Loc
from ...compiler.passes.specialize import parameter_slots
from ..tables import fill_tables
from ...core.color import MODELS
from ...core.scene_spec import Instance, SceneSpec, SpectrumValue
from ..plugins import ParamDecl, declared_params

STDLIB = Path(__file__).resolve().parents[2] / "stdlib"
KINDS = ("bsdf", "emitter", "texture")  # the plugin kinds the test kit knows
f32 = np.float32
_GOLDEN = 0.6180339887498949

_PRELUDE = """import render.scene;
import spectral;
{imports}
"""
_BSDF = """
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
fn h_smooth(id: Int, ul: Float, T: [Float]) -> Bool {{ return scene_bsdf_smooth(id, T); }}
"""
_EMITTER = """
fn h_emitter_eval(id: Int, si: Surface, ul: Float, T: [Float]) -> Spectrum {{
    let w = sample_wavelengths(ul);
    return scene_emitter_eval(id, si, T);
}}
"""
_TEXTURE = """
fn h_texture_eval(id: Int, si: Surface, ul: Float, T: [Float]) -> Spectrum {{
    let w = sample_wavelengths(ul);
    return scene_texture_eval(id, si, T);
}}
"""
_TEXTURE_1 = """
fn h_texture_eval_1(id: Int, si: Surface, ul: Float, T: [Float]) -> Float {{
    let w = sample_wavelengths(ul);
    return scene_texture_eval_1(id, si, T);
}}
"""
_WAVELENGTHS = """
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
# the scene dispatch of BSDFs: the test suite's SceneBsdfs compiles it for a scene's BSDFs
SOURCE = _PRELUDE + _BSDF + _WAVELENGTHS


@dataclass(frozen=True)
class Declaration:
    """A plugin declared in a file: ``kind NAME { ... }``."""

    kind: str
    name: str
    path: Path
    line: int
    params: tuple[ParamDecl, ...]
    methods: tuple[str, ...]

    @property
    def where(self) -> str:
        return f"{self.path}:{self.line}"


def declarations(path: str | Path) -> list[Declaration]:
    """The plugins declared in the file ``path`` (not those of its imports), checked by the
    frontend: a syntax or type error is a :class:`CompileError` at its line."""
    from ...dsl import check

    path = Path(path)
    program = check(path)
    main = str(path.resolve())
    out = []
    for pl in program.plugins:
        if pl.module.key != main:
            continue
        params = tuple(declared_params(pl))
        out.append(Declaration(pl.kind, pl.name, path, pl.decl.loc.line, params,
                               tuple(pl.fns)))
    return out


@cache
def stdlib_declaration(name: str, kind: str = "bsdf") -> Declaration:
    """The stdlib plugin ``name`` (stdlib/KIND/NAME.rdsl)."""
    found = [d for d in declarations(STDLIB / kind / f"{name}.rdsl") if d.name == name]
    if not found:
        raise KeyError(f"no {kind} `{name}` in the stdlib")
    return found[0]


def default_ul(n: int) -> np.ndarray:
    """The wavelength sample of row i: a golden-ratio sequence (low discrepancy)."""
    return ((0.5 + _GOLDEN * np.arange(n)) % 1.0).astype(f32)


def _harness_source(decl: Declaration) -> tuple[str, str]:
    """The harness's text and the file name it is compiled under (in the plugin's folder,
    so that ``import STEM;`` finds the plugin and the kernel cache hashes the file)."""
    stem = decl.path.stem
    if not stem.isidentifier():
        raise CompileError(f"`rdsl test-plugin` imports the file as a module, so its name "
                           f"must be an identifier (letters, digits and `_`, not starting "
                           f"with a digit), e.g. `{_identifier(stem)}.rdsl`",
                           Loc(str(decl.path), 0, 0))
    body = {"bsdf": _BSDF, "emitter": _EMITTER,
            "texture": _TEXTURE + (_TEXTURE_1 if "eval_1" in decl.methods else "")}[decl.kind]
    text = (_PRELUDE + body + _WAVELENGTHS).format(imports=f"import {stem};")
    return text, str(decl.path.resolve().parent / "rdsl-test-plugin-harness.rdsl")


def _identifier(stem: str) -> str:
    s = "".join(c if c.isalnum() or c == "_" else "_" for c in stem)
    return s if s and not s[0].isdigit() else f"p_{s}"


class Harness:
    """A plugin in ``variant`` through the scene dispatch (see the module docstring): a
    stdlib BSDF by ``name``, or the plugin ``decl`` of any file."""

    ident = 0  # the scene's plugin that the kernels call

    def __init__(self, name: str | None = None, variant: str = "rgb", target: str = "host",
                 decl: Declaration | None = None) -> None:
        self.decl = decl if decl is not None else stdlib_declaration(str(name))
        self.name, self.variant, self.target = self.decl.name, variant, target
        self.model = MODELS[variant]
        self.polarized, self.spectral = self.model.polarized, self.model.spectral
        self._mods: dict[str, Any] = {}
        # the scene's texel buffer `T` the kernels get (a table a BSDF reads from it)
        self.T = np.zeros(1, f32)

    # -- compilation ---------------------------------------------------------------------
    def _params(self, params: dict[str, Any]) -> dict[str, Any]:
        declared = {p.name: p for p in self.decl.params}
        unknown = set(params) - set(declared)
        if unknown:
            raise TypeError(f"{self.name} has no parameter(s) {sorted(unknown)}")
        out = {}
        for k, p in declared.items():
            v = params.get(k, p.default)
            if v is None:
                raise CompileError(f"param `{k}` of {self.decl.kind} `{self.name}` has no "
                                   f"default; give it a value (`-p {k}=VALUE`)", p.loc)
            if p.type in ("Spectrum", "Texture") and isinstance(v, (tuple, list, np.ndarray)):
                v = SpectrumValue(tuple(float(x) for x in v))
            out[k] = v
        return out

    def module(self, params: dict[str, Any]) -> tuple[Any, np.ndarray]:
        """The compiled module for these parameters' layout, and their ``PRM`` buffer."""
        from ..api import jit

        inst = [Instance(self.name, self._params(params))]
        kind = {"bsdf": "bsdfs", "emitter": "emitters", "texture": "textures"}[self.decl.kind]
        spec, prm = parameter_slots(SceneSpec(**{kind: inst}), self.model)
        key = repr(spec)
        text, filename = _harness_source(self.decl)
        if key not in self._mods:
            self._mods[key] = jit(text, target=self.target, variant=self.variant, scene=spec,
                                  filename=filename)
        mod = self._mods[key]
        prm = fill_tables(mod, SceneSpec(**{kind: inst}), prm, text, filename)
        return mod, np.asarray(prm if len(prm) else np.zeros(1), f32)

    def _call(self, kernel: str, n: int, args: list, ul: Any, params: dict) -> Any:
        mod, prm = self.module(params)
        k = mod[kernel]
        ul = default_ul(n) if ul is None else np.broadcast_to(np.asarray(ul, f32), (n,))
        extra = [prm] if any(p["name"] == "PRM" for p in k.info["params"]) else []
        return k(np.full(n, self.ident, np.int32), *args, np.ascontiguousarray(ul),
                 np.ascontiguousarray(self.T, f32), *extra)

    # -- the plugin's interface ----------------------------------------------------------
    def _split(self, value: Any) -> tuple[np.ndarray, np.ndarray | None]:
        """(intensity, full Mueller matrix or None) of a colour result."""
        if not isinstance(value, dict):
            return np.asarray(value), None
        m = np.stack([np.stack([np.asarray(value[f"m{i}{j}"]) for j in range(4)], 1)
                      for i in range(4)], 1)
        return m[:, 0, 0], m

    def sample(self, si: dict, u1: np.ndarray, u2: np.ndarray, ul: Any = None,
               **params: Any) -> dict[str, np.ndarray]:
        """The BSDF's sample(): wo, pdf, eta, weight (the intensity), delta (and mueller)."""
        bs = self._call("h_sample", len(u1), [si, u1, u2], ul, params)
        out = {k: np.asarray(v) for k, v in bs.items() if k != "weight"}
        out["weight"], m = self._split(bs["weight"])
        if m is not None:
            out["mueller"] = m
        return out

    def eval(self, si: dict, wo: np.ndarray, ul: Any = None, mueller: bool = False,
             **params: Any) -> np.ndarray:
        """The BSDF's eval() (times the cosine), the intensity or the Mueller matrix."""
        value, m = self._split(self._call("h_eval", len(wo), [si, wo], ul, params))
        if mueller:
            return m if m is not None else value.reshape(len(wo), 1, 1, *value.shape[1:])
        return value

    def pdf(self, si: dict, wo: np.ndarray, ul: Any = None, **params: Any) -> np.ndarray:
        """The BSDF's pdf() of the sampled direction wo (solid angle)."""
        return np.asarray(self._call("h_pdf", len(wo), [si, wo], ul, params))

    def disperses(self, **params: Any) -> bool:
        """Whether the integrator follows the hero wavelength alone after this BSDF."""
        return bool(np.asarray(self._call("h_disperses", 1, [], None, params))[0])

    def smooth(self, **params: Any) -> bool:
        """Whether the BSDF has a non-delta lobe (the integrators sample emitters there)."""
        return bool(np.asarray(self._call("h_smooth", 1, [], None, params))[0])

    def emitted(self, si: dict, ul: Any = None, **params: Any) -> np.ndarray:
        """An emitter's eval(): the radiance leaving towards si.wi (the intensity)."""
        return self._split(self._call("h_emitter_eval", len(si["wi"]), [si], ul, params))[0]

    def texture(self, si: dict, ul: Any = None, one: bool = False,
                **params: Any) -> np.ndarray:
        """A texture's eval() at si (its colour's intensity), or its eval_1() with ``one``."""
        kernel = "h_texture_eval_1" if one else "h_texture_eval"
        return self._split(self._call(kernel, len(si["uv"]), [si], ul, params))[0]

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
