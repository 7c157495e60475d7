"""``specialize(scene)``: fit the program to one scene.

Expects: a lowered module (before ``inline``) containing the scene placeholders of
``stdlib/render/scene.rdsl`` (``scene_bsdf_eval`` and friends) and the plugin functions of
every plugin type the scene uses (``diffuse.eval``...).

Guarantees: each placeholder's body is replaced by a dispatch over the plugin types the
scene's instances use (``if id == 0 || id == 2 { roughconductor.eval(...) } else {
diffuse.eval(...) }``): one call per type, whose parameters are constants, or selects of
constants by instance id when instances of a type differ.  ``optimize`` then folds what the
scene fixes (a parameter equal to 0 or 1, a branch on a flag).  Ids must be ones of the
scene's instances (the renderer guarantees it); a placeholder with no instances keeps its
own body.  Plugins the scene does not use are never called, so ``inline`` drops them.
``report`` collects what was specialized, for ``rdsl render --report``.

A plugin method gets the placeholder's arguments after the id, except buffers (plugins
cannot read buffers).  A method that needs them is written as a top-level function
``{plugin}_{method}_buffers`` taking every argument after the id, buffers included, then
the plugin's parameters by name (``bitmap_eval_buffers(si, T, offset, ...)``); when it
exists the dispatch calls it instead of ``{plugin}.{method}``.  A parameter whose value is
a :class:`TextureRef` becomes ``scene_texture_eval(k, ...)``, called with the placeholder's
arguments of the same names (``si``, ``T``), whose own dispatch covers the scene's textures;
since a texture param ``reflectance(si)`` evaluates to the param value, evaluating the
texture at the same ``si`` first is the same thing.  A ``Float`` parameter set by a texture
(a roughness) becomes ``scene_texture_eval_1(k, ...)`` likewise, the texture's one-value
lookup (its plugins' ``eval_1``, Mitsuba's).  In a texture's own dispatch (a texture of a
texture: a checkerboard's colour) it becomes ``scene_texture_eval.texture{k}(k, ...)``, the
dispatch restricted to texture ``k`` (:meth:`Specialize._nested_texture`), so that nesting,
to any depth, is no recursion.  A method in ``OPTIONAL`` (``disperses``; ``eval_1``, which the
loader requires where it is called) may be missing: its instances then give that constant.

A plugin's ``table`` functions (docs/language.md, "Tables") are computed parameters: each
method gets, per table, a hidden ``NAME.table`` parameter, which the dispatch sets to where
the instance's samples are, and the table's read function ``PLUGIN.NAME.read`` becomes the
interpolation (:func:`rdsl.compiler.precompute.build_read`).  Where the instance's
parameters are constants the samples are computed now (:func:`~rdsl.compiler.precompute.
tabulate`) and folded, all the scene's tables in one ``table`` constant; where a parameter
the table takes is read from ``PRM`` they are laid out after the parameters in ``PRM`` and
listed in ``module.attrs["tables"]`` (the manifest's ``tables``) for the runtime to fill at
scene load (runtime/tables.py).

The generic build (``Specialize(scene, fold=False, model=...)``, ``rdsl render
--no-specialize``) keeps the same dispatch over plugin types but reads every parameter the
scene sets from a float buffer ``PRM`` at run time (a :class:`Slot` per value, laid out by
:func:`parameter_slots`); the placeholders, and every function that reaches one, get ``PRM`` as a last argument, the
kernels included.  Its code depends on the scene's plugin types, instances and which
parameters they set, never on the values (a tabulated spectrum's knots included: see
:func:`parameter_slots`), so scenes differing only in values share it.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ...core.color import RGB, ColorModel
from ...core.scene_spec import Instance, SceneSpec, Slot, SpectrumValue, TextureRef
from ..diagnostics import CompileError
from ..ir import (
    BOOL,
    F32,
    I32,
    Block,
    BufferType,
    Builder,
    Function,
    Instr,
    Module,
    Op,
    Param,
    ScalarType,
    SpectrumType,
    Type,
    Value,
    VecType,
)
from . import Pass, register

# placeholder function -> (instance list, plugin method)
PLACEHOLDERS = {
    "scene_bsdf_eval": ("bsdfs", "eval"),
    "scene_bsdf_pdf": ("bsdfs", "pdf"),
    "scene_bsdf_sample": ("bsdfs", "sample"),
    "scene_emitter_eval": ("emitters", "eval"),
    "scene_texture_eval": ("textures", "eval"),
    "scene_texture_eval_1": ("textures", "eval_1"),  # a texture setting a Float parameter
    # the BSDFs nested in combinators (twosided, blendbsdf, mask): stdlib/render/bsdf_leaf.rdsl
    "scene_bsdf_leaf_eval": ("bsdf_leaves", "eval"),
    "scene_bsdf_leaf_pdf": ("bsdf_leaves", "pdf"),
    "scene_bsdf_leaf_sample": ("bsdf_leaves", "sample"),
    # whether the BSDF disperses light (stdlib/dispersion.rdsl): optional, see OPTIONAL
    "scene_bsdf_disperses": ("bsdfs", "disperses"),
    "scene_bsdf_leaf_disperses": ("bsdf_leaves", "disperses"),
    # whether the BSDF has a lobe that emitter sampling can reach (Mitsuba's
    # BSDFFlags::Smooth): optional, plugins without `smooth()` are taken to have one
    "scene_bsdf_smooth": ("bsdfs", "smooth"),
    # whether the BSDF's diffuse reflectance (the aov integrator's albedo) is the same seen
    # from either side (Mitsuba's diffuse overrides eval_diffuse_reflectance so): optional
    "scene_bsdf_albedo_two_sided": ("bsdfs", "albedo_two_sided"),
    # shading-frame perturbations (normalmap, bumpmap: stdlib/bsdf/perturbed.rdsl) and the
    # texture lookups they make
    "scene_bsdf_normal": ("bsdfs", "normal"),
    "scene_texture_eval_3": ("textures", "eval_3"),
    "scene_texture_eval_1_grad": ("textures", "eval_1_grad"),
}
# methods a plugin may lack: its instances then give this constant
OPTIONAL = {"disperses": False, "smooth": True, "normal": 0.0, "eval_3": 0.0, "eval_1_grad": 0.0,
            "albedo_two_sided": False, "eval_1": 0.0}
TEXTURE_PLACEHOLDER = "scene_texture_eval"
TEXTURE_PLACEHOLDER_1 = "scene_texture_eval_1"
EMITTER_KIND_PLACEHOLDER = "scene_has_emitter_kind"  # folded to the scene's emitter kinds
SHAPE_KIND_PLACEHOLDER = "scene_has_shape_kind"  # folded to the scene's shape kinds
ACCEL_PLACEHOLDER = "scene_uses_bvh"  # folded to the scene's choice of ray tracing
PARAM_BUFFER = "PRM"  # the generic build's parameter buffer


class SlotRangeError(CompileError):
    """An integer (``what``: ``<instance>.<param>``) that PRM's floats cannot hold exactly."""

    def __init__(self, what: str, value: int) -> None:
        self.what, self.value = what, value
        super().__init__(f"{what}: {value} is too large for the generic build's parameter "
                         "buffer (its floats hold integers exactly below 2**24)")


def parameter_slots(scene: SceneSpec, model: ColorModel = RGB
                    ) -> tuple[SceneSpec, np.ndarray]:
    """The generic build's scene: every parameter value the scene sets (textures aside)
    becomes a :class:`Slot` into the returned float32 buffer ``PRM``, which holds the values,
    instance after instance (colors and vectors as their components; empty if the scene sets
    no parameter, and then the kernels take no ``PRM``).  In the spectral variants a colour
    is stored as its upsampling coefficients and scale, and a tabulated spectrum as the
    range of its knots and the 470 cells of 1 nm over 360..830 nm of
    ``spectral.tabulated_slot`` (2352 floats), read by ``spec.table``: a layout that does
    not depend on the knots, so the code does not either.  The cells are exact (to float32
    rounding, like the specialized build's cells fitted to the knots) unless a cell
    [n, n + 1) nm holds two knots strictly inside: knots at least 1 nm apart (the named
    conductors' tables: 5.4 nm at least) or every 0.5 nm on the half-nanometres are exact.
    A crowded cell keeps one of its knots and drops the others, erring by what linear
    interpolation without them does within that nanometre.  The other variants store the
    RGB."""
    from ...core import spectral  # numpy only: the upsampling fit and spectrum cells

    values: list[float] = []

    def slot(value: Any, what: str) -> Any:
        if isinstance(value, (TextureRef, Slot)):
            return value
        if isinstance(value, SpectrumValue):
            if not model.spectral:
                value = value.rgb
            elif value.samples is not None:
                out = Slot(len(values), spectral.GENERIC_SLOT, table=True)
                values.extend(float(x) for x in spectral.tabulated_slot(*value.samples))
                return out
            else:
                # the f32 values the specialized build's constants hold: the same fit
                rgb = np.asarray(value.rgb, np.float32).astype(np.float64)
                coeffs, scale = (spectral.illuminant_from_rgb(rgb) if value.illuminant
                                 else (spectral.rgb_to_coeffs(rgb), 1.0))
                out = Slot(len(values), 4, value.illuminant)
                values.extend([*(float(c) for c in coeffs), float(scale)])
                return out
        xs = list(value) if isinstance(value, (tuple, list, np.ndarray)) else [value]
        for x in xs:
            if isinstance(x, (int, np.integer)) and not isinstance(x, bool) and \
                    abs(int(x)) >= 1 << 24:
                raise SlotRangeError(what, int(x))
        out = Slot(len(values), len(xs))
        values.extend(float(x) for x in xs)
        return out

    def instances(kind: str) -> list[Instance]:
        return [Instance(i.plugin, {k: slot(v, f"{i.name or i.plugin}.{k}")
                                    for k, v in i.params.items()}, i.name, list(i.children))
                for i in getattr(scene, kind)]

    # the kinds of emitter and shape are the scene's structure, as its plugin types: no
    # parameter changes them, so the generic build folds them too
    spec = SceneSpec(instances("bsdfs"), instances("emitters"), instances("textures"),
                     instances("bsdf_leaves"), scene.emitter_kinds, scene.shape_kinds,
                     integrators=instances("integrators"), accel=scene.accel)
    return spec, np.asarray(values, np.float32)


def describe(scene: SceneSpec, placeholders: list[str] | None = None) -> list[str]:
    """One line per placeholder: which instances its dispatch covers."""
    out = []
    if placeholders is None and scene.integrators:
        out.append("integrators: " + ", ".join(i.plugin for i in scene.integrators))
    for name in placeholders if placeholders is not None else list(PLACEHOLDERS):
        kind, _ = PLACEHOLDERS[name]
        instances: list[Instance] = getattr(scene, kind)
        used = sorted({i.plugin for i in instances})
        out.append(f"{name}: {len(instances)} instance(s) of {', '.join(used) or 'nothing'}")
    return out


@register
class Specialize(Pass):
    name = "specialize"

    def __init__(self, scene: SceneSpec | None = None, report: list[str] | None = None,
                 fold: bool = True, model: ColorModel = RGB) -> None:
        self.scene = scene or SceneSpec()
        if not fold:  # the parameter buffer holds colours as `model` stores them
            self.scene, _ = parameter_slots(self.scene, model)
        self._prm_len = _slots_end(self.scene)  # where the generic build's tables go in PRM
        self.report = report if report is not None else []
        self._prm: dict[str, Value] = {}  # placeholder -> its PRM argument, once it reads one
        self._tables = _Tables()
        # the texture dispatch functions (placeholders and _nested_texture's): built or not
        self._texture_fns: dict[str, bool] = {}

    def run(self, module: Module) -> None:
        for name, (kind, method) in PLACEHOLDERS.items():
            placeholder = module.functions.get(name)
            if placeholder is None:
                continue
            if kind == "textures":  # a texture's textures: _nested_texture
                self._texture_fns[name] = True
            self._dispatch(module, placeholder, kind, method)
        for name, present in ((EMITTER_KIND_PLACEHOLDER, self.scene.emitter_kinds),
                              (SHAPE_KIND_PLACEHOLDER, self.scene.shape_kinds)):
            kinds = module.functions.get(name)
            if kinds is not None and present is not None:
                kinds.body = _kind_test(kinds, present)
        accel = module.functions.get(ACCEL_PLACEHOLDER)
        if accel is not None:
            accel.body = _constant_body(accel, self.scene.accel == "bvh")
        for fn in list(module.functions.values()):
            self._bind_calls(module, fn, fn.body)
        self._read_tables(module)
        if self._prm:
            for name, prm in self._prm.items():
                if module.functions[name].params[-1].value is not prm:
                    module.functions[name].params.append(Param(prm, uniform=True))
            _thread_buffer(module, PARAM_BUFFER)
        self.report.extend(describe(self.scene, [n for n in PLACEHOLDERS
                                                 if n in module.functions]))

    def _bind_calls(self, module: Module, fn: Function, block: Block) -> None:
        """Give each call of a plugin's function from outside the plugin (``path.sample(...)``
        in the render kernel: a call with a ``bound`` attribute, whose params are the
        defaults) the params of the scene's instance of that plugin."""
        out: list[Instr] = []
        for ins in block.instrs:
            for region in ins.regions:
                self._bind_calls(module, fn, region)
            if ins.op is Op.CALL and "bound" in ins.attrs:
                n = ins.attrs.pop("bound")
                callee = module.functions[ins.attrs["callee"]]
                plugin = callee.attrs.get("plugin", "?")
                inst = next((i for i in self.scene.integrators if i.plugin == plugin),
                            Instance(plugin))
                pre = Builder(Block(), ins.loc)
                ident = pre.const(0, I32)
                defaults = {p.value.name: p.default for p in callee.params}
                k = next((j for j, i in enumerate(self.scene.integrators) if i is inst), None)
                ins.operands[n:] = [
                    self._table_offset(pre, module, p, ident, "integrators", [k], callee)
                    if k is not None and _is_table_slot(module, plugin, p) else
                    self._param_value(pre, p, ident, [inst], [0], defaults.get(p.value.name),
                                      module, fn, {})
                    for p in callee.params[n:]]
                out += pre.block.instrs
            out.append(ins)
        block.instrs = out

    def _dispatch(self, module: Module, placeholder: Function, kind: str, method: str,
                  only: list[int] | None = None) -> None:
        """Dispatch over the plugin *types* of the scene's ``kind`` instances (those of
        index in ``only``, if given); the parameters of one type's instances are selected by
        id, so three diffuse materials cost one diffuse call."""
        instances: list[Instance] = getattr(self.scene, kind)
        if not instances:
            return  # the placeholder's own body stays
        ident, args = placeholder.params[0].value, [p.value for p in placeholder.params[1:]]
        plain = [a for a in args if not isinstance(a.type, BufferType)]
        groups: dict[str, list[int]] = {}
        for k in range(len(instances)) if only is None else only:
            groups.setdefault(instances[k].plugin, []).append(k)
        body = Block()
        tail: Block | None = None  # built from the last group backwards
        for plugin, ids in reversed(list(groups.items())):
            own = module.functions.get(f"{plugin}.{method}")
            callee, lead = module.functions.get(f"{plugin}_{method}_buffers"), args
            if callee is None:
                callee, lead = own, plain
            if callee is None and method not in OPTIONAL:
                raise CompileError(f"plugin `{plugin}` has no function `{method}` "
                                   "(is its file imported?)")
            then = Block()
            tb = Builder(then, placeholder.loc)
            if callee is None:
                tb.yield_(tb.const(OPTIONAL[method], placeholder.ret_types[0]))
            else:
                defaults = {p.value.name: p.default for p in own.params} if own else {}
                textures: dict[tuple[int, bool], Value] = {}
                # an optional method's unused parameters are 0: a texture there may need
                # arguments (si) that its placeholder lacks
                used = ({v for i in callee.walk() for v in i.operands}
                        if method in OPTIONAL else None)
                params = [_constant(tb, p.value.type, False, placeholder.name)
                          if used is not None and p.value not in used else
                          self._table_offset(tb, module, p, ident, kind, ids, own)
                          if _is_table_slot(module, plugin, p) else
                          self._param_value(tb, p, ident, [instances[k] for k in ids], ids,
                                            defaults.get(p.value.name), module, placeholder,
                                            textures)
                          for p in callee.params[len(lead):]]
                call = tb.emit(Op.CALL, lead + params, list(callee.ret_types),
                               {"callee": callee.name})
                tb.yield_(*call.results)
            if tail is None:
                tail = then  # the last type needs no test: ids come from the scene
                continue
            block = Block()
            bb = Builder(block, placeholder.loc)
            cond = None
            for k in ids:
                c = bb.op(Op.EQ, BOOL, ident, bb.const(k, I32))
                cond = c if cond is None else bb.op(Op.OR, BOOL, cond, c)
            res = bb.emit(Op.IF, [cond], list(placeholder.ret_types), regions=[then, tail])
            bb.yield_(*res.results)
            tail = block
        assert tail is not None
        body.instrs = tail.instrs
        last = body.instrs.pop()
        body.instrs.append(Instr(Op.RETURN, last.operands, [], loc=last.loc))
        placeholder.body = body

    def _table_offset(self, b: Builder, module: Module, p: Param, ident: Value, kind: str,
                      ids: list[int], own: Function | None) -> Value:
        """A table's hidden parameter: where the instance's samples are (selected by id)."""
        assert own is not None
        read = module.functions[f"{own.attrs['plugin']}.{p.value.name[:-len('.table')]}.read"]
        instances = getattr(self.scene, kind)
        out: Value | None = None
        for k in reversed(ids):
            at = b.const(self._table(module, read, kind, k, instances[k]), I32)
            out = at if out is None else b.op(
                Op.SELECT, I32, b.op(Op.EQ, BOOL, ident, b.const(k, I32)), at, out)
        assert out is not None
        return out

    def _table(self, module: Module, read: Function, kind: str, k: int, inst: Instance) -> int:
        """The offset of instance ``k``'s samples of the table ``read`` reads: computed now
        (its parameters are constants) or laid out at the end of ``PRM`` for the runtime to
        fill at load (the generic build: a parameter it takes is read from ``PRM``)."""
        from ..precompute import table_params, table_size, tabulate

        opts = read.attrs["table"]
        key = (kind, k, opts["fn"])
        if key not in self._tables.offsets:
            size = table_size(opts)
            names = {p.value.name for p in read.params}
            if not any(isinstance(v, Slot) for n, v in inst.params.items() if n in names):
                values = tabulate(module, opts, table_params(read, inst))
                self._tables.offsets[key] = len(self._tables.values)
                self._tables.values.extend(float(v) for v in values)
            else:
                self._tables.offsets[key] = self._prm_len + self._tables.prm
                module.attrs.setdefault("tables", []).append(
                    {**opts, "kind": kind, "index": k, "offset": self._tables.offsets[key]})
                self._tables.prm += size
        return self._tables.offsets[key]

    def _read_tables(self, module: Module) -> None:
        """The read functions of the tables laid out become lookups (see precompute)."""
        from ..precompute import build_read

        if not self._tables.offsets:
            return
        self.report.append(f"tables: {len(self._tables.offsets)} ({len(self._tables.values)} "
                           f"values computed now, {self._tables.prm} filled at load in "
                           f"{PARAM_BUFFER})")
        for fn in list(module.functions.values()):
            if "table" not in fn.attrs:
                continue
            if not self._tables.prm:
                build_read(fn, None, self._tables.values)
                continue
            if self._tables.values:
                raise CompileError(f"{fn.name}: a build cannot both fold tables and read "
                                   f"them from {PARAM_BUFFER}")
            prm = Value(BufferType(F32), PARAM_BUFFER)
            fn.params.append(Param(prm, uniform=True))
            build_read(fn, prm, None)
            self._prm[fn.name] = prm

    def _param_value(self, b: Builder, p: Param, ident: Value, group: list[Instance],
                     ids: list[int], default: Any, module: Module, placeholder: Function,
                     textures: dict[tuple[int, bool], Value]) -> Value:
        """The parameter's constant (or texture call), or a select over the group's instances
        by id."""
        name = p.value.name or "?"
        default = p.default if p.default is not None else default
        values = []
        for inst in group:
            value = inst.params.get(name, default)
            if value is None:
                raise CompileError(f"{inst.name or inst.plugin}: parameter `{name}` of "
                                   f"`{inst.plugin}` has no value and no default")
            values.append(value)
        what = f"{group[0].plugin}.{name}"

        scalar = p.value.type == F32

        def value_of(value: Any) -> Value:
            if isinstance(value, Slot):
                if placeholder.name not in self._prm:
                    self._prm[placeholder.name] = Value(BufferType(F32), PARAM_BUFFER)
                return _load(b, p.value.type, value, self._prm[placeholder.name], what)
            if not isinstance(value, TextureRef):
                return _constant(b, p.value.type, value, what)
            key = (value.index, scalar)
            if key not in textures:
                textures[key] = self._texture(b, value.index, module, placeholder, what, scalar)
            return textures[key]

        if not (isinstance(p.value.type, SpectrumType) or scalar) and any(
                isinstance(v, TextureRef) for v in values):
            raise CompileError(f"{what}: a texture can only set a `Texture` or `Float` "
                               f"parameter (this one is `{p.value.type}`)")
        out = value_of(values[-1])
        for k, value in zip(reversed(ids[:-1]), reversed(values[:-1])):
            if value == values[-1]:
                continue
            c = b.op(Op.EQ, BOOL, ident, b.const(k, I32))
            out = b.op(Op.SELECT, p.value.type, c, value_of(value), out)
        return out

    def _texture(self, b: Builder, index: int, module: Module, placeholder: Function,
                 what: str, scalar: bool = False) -> Value:
        """``scene_texture_eval(index, ...)`` (``scene_texture_eval_1`` for a ``scalar``)
        with ``placeholder``'s arguments of the same names."""
        name = TEXTURE_PLACEHOLDER_1 if scalar else TEXTURE_PLACEHOLDER
        tex = module.functions.get(name)
        if not 0 <= index < len(self.scene.textures):
            raise CompileError(f"{what}: texture {index} is not one of the scene's "
                               f"{len(self.scene.textures)} texture(s)")
        if tex is None:
            raise CompileError(f"{what}: cannot evaluate a texture here: `{name}` is not "
                               "defined (import render.scene)")
        if placeholder.name in self._texture_fns:  # a texture of a texture
            tex = self._nested_texture(module, tex, index, what)
        ours = {p.value.name: p.value for p in placeholder.params}
        operands = [b.const(index, I32)]
        for p in tex.params[1:]:
            if p.value.name == PARAM_BUFFER:
                continue  # threaded by _thread_buffer
            v = ours.get(p.value.name)
            if v is None or v.type != p.value.type:
                raise CompileError(f"{what}: a texture needs the argument `{p.value.name}: "
                                   f"{p.value.type}`, which `{placeholder.name}` does not have")
            operands.append(v)
        return b.emit(Op.CALL, operands, list(tex.ret_types), {"callee": tex.name}).result

    def _nested_texture(self, module: Module, tex: Function, index: int, what: str
                        ) -> Function:
        """``{tex}.texture{index}``: the texture placeholder ``tex`` dispatching to texture
        ``index`` alone, what a texture whose parameter texture ``index`` sets (a
        checkerboard's colour) calls, rather than ``tex`` itself: the scene's textures nest
        without cycles (the loader rejects ``<ref>`` cycles), so these calls end, and
        ``inline`` sees no recursion."""
        name = f"{tex.name}.texture{index}"
        fn = module.functions.get(name)
        if fn is not None:
            if not self._texture_fns[name]:
                raise CompileError(f"{what}: texture {index} contains itself (a cycle of "
                                   "textures)")
            return fn
        params = [Param(Value(p.value.type, p.value.name), p.uniform, p.default)
                  for p in tex.params]
        fn = Function(name, params, list(tex.ret_types), Block(), tex.loc)
        module.functions[name] = fn
        self._texture_fns[name] = False  # being built
        self._dispatch(module, fn, "textures", PLACEHOLDERS[tex.name][1], only=[index])
        self._texture_fns[name] = True
        return fn


class _Tables:
    """The tables laid out so far: (kind, instance, table function) -> offset; the folded
    values, or the size claimed at the end of ``PRM``."""

    def __init__(self) -> None:
        self.offsets: dict[tuple[str, int, str], int] = {}
        self.values: list[float] = []  # folded
        self.prm = 0  # size laid out at the end of PRM


def _slots_end(scene: SceneSpec) -> int:
    """The size of the generic build's ``PRM`` without tables: the end of its last slot."""
    ends = [v.offset + v.size
            for kind in ("bsdfs", "emitters", "textures", "bsdf_leaves", "integrators")
            for inst in getattr(scene, kind) for v in inst.params.values()
            if isinstance(v, Slot)]
    return max(ends, default=0)


def _is_table_slot(module: Module, plugin: str, p: Param) -> bool:
    name = p.value.name or ""
    return name.endswith(".table") and f"{plugin}.{name[:-len('.table')]}.read" in module.functions


def _constant(b: Builder, t: Type, value: Any, what: str) -> Value:
    """Build ``value`` as IR constants of type ``t`` (before lifting)."""
    if isinstance(t, ScalarType):
        if isinstance(value, (tuple, list)):
            raise CompileError(f"{what}: expected a single value, got {value!r}")
        py = {"f32": float, "i32": int, "u32": int, "u64": int, "bool": bool}[t.name]
        return b.const(py(value), t)
    if isinstance(t, SpectrumType):
        if isinstance(value, SpectrumValue):
            attrs: dict[str, Any] = {"illuminant": True} if value.illuminant else {}
            if value.samples is not None:
                attrs["spectrum"] = [list(value.samples[0]), list(value.samples[1])]
            return b.op(Op.SPEC_RGB, t, *[b.const(float(v), F32) for v in value.rgb], **attrs)
        if isinstance(value, (tuple, list)):
            if len(value) == 1:
                value = value[0]
            elif len(value) == 3:
                return b.op(Op.SPEC_RGB, t, *[b.const(float(v), F32) for v in value])
            else:
                raise CompileError(f"{what}: expected 1 or 3 values, got {len(value)}")
        return b.op(Op.BROADCAST, t, b.const(float(value), F32))
    if isinstance(t, VecType):
        vals = list(value) if isinstance(value, (tuple, list)) else [value] * t.n
        if len(vals) != t.n:
            raise CompileError(f"{what}: expected {t.n} values, got {len(vals)}")
        return b.op(Op.MAKE, t, *[b.const(float(v), F32) for v in vals])
    raise CompileError(f"{what}: parameters of type `{t}` cannot be set from a scene yet")


def _kind_test(fn: Function, kinds: tuple[int, ...]) -> Block:
    """``return kind == k0 || kind == k1 ...`` (false when ``kinds`` is empty)."""
    body = Block()
    b = Builder(body, fn.loc)
    kind = fn.params[0].value
    out = b.const(False, BOOL)
    for k in sorted(set(kinds)):
        out = b.op(Op.OR, BOOL, out, b.op(Op.EQ, BOOL, kind, b.const(int(k), I32)))
    b.emit(Op.RETURN, [out], [])
    return body


def _constant_body(fn: Function, value: bool) -> Block:
    """``return value``."""
    body = Block()
    b = Builder(body, fn.loc)
    b.emit(Op.RETURN, [b.const(value, BOOL)], [])
    return body


def _load(b: Builder, t: Type, slot: Slot, prm: Value, what: str) -> Value:
    """Read a parameter of type ``t`` from ``prm`` at ``slot`` (before lifting)."""
    if slot.table:
        if not isinstance(t, SpectrumType):
            raise CompileError(f"{what}: a tabulated spectrum cannot set a parameter of "
                               f"type `{t}`")
        return b.op(Op.SPEC_TABLE, t, prm, b.const(slot.offset, I32))
    xs = [b.op(Op.LOAD, F32, prm, b.const(slot.offset + k, I32)) for k in range(slot.size)]
    if isinstance(t, ScalarType) and slot.size == 1:
        if t.name == "f32":
            return xs[0]
        if t.name == "bool":
            return b.op(Op.NE, BOOL, xs[0], b.const(0.0, F32))
        return b.op(Op.CAST, t, xs[0])
    if isinstance(t, SpectrumType) and slot.size in (1, 3, 4):
        if slot.size == 1:
            return b.op(Op.BROADCAST, t, xs[0])
        return b.op(Op.SPEC_RGB, t, *xs, **({"illuminant": True} if slot.illuminant else {}))
    if isinstance(t, VecType) and slot.size in (1, t.n):
        return b.op(Op.MAKE, t, *(xs * t.n if slot.size == 1 else xs))
    raise CompileError(f"{what}: {slot.size} value(s) cannot set a parameter of type `{t}`")


def _thread_buffer(module: Module, name: str) -> None:
    """Pass the buffer argument ``name`` down every call chain that reaches a function taking
    it as its last parameter: callers get it as their own last parameter, to a fixpoint."""
    changed = True
    while changed:
        changed = False
        for fn in module.functions.values():
            for ins in fn.walk():
                if ins.op is not Op.CALL:
                    continue
                callee = module.functions.get(ins.attrs["callee"])
                if (callee is None or not callee.params or callee.params[-1].value.name != name
                        or len(ins.operands) == len(callee.params)):
                    continue
                own = fn.params[-1].value if fn.params else None
                if own is None or own.name != name or not isinstance(own.type, BufferType):
                    own = Value(BufferType(F32), name)
                    fn.params.append(Param(own, uniform=True))
                ins.operands.append(own)
                changed = True
