"""A scene's parameters by name, and forward-mode derivatives of its image.

``scene.params`` maps names to numpy arrays, named as Mitsuba 3's ``mi.traverse`` names
them: ``red.reflectance.value`` (a BSDF's ``reflectance``, the BSDF's id first),
``light.emitter.radiance.value`` (the area emitter of the shape ``light``),
``path.max_depth``, and ``<id>.data`` for the texels of a bitmap texture (an (H, W, 3)
array of linear RGB, in the ``rgb`` and ``mono`` variants).  An object without an id is
named after its owner (``<shape>.bsdf``, ``<bsdf>.reflectance``: flatten.py, textures.py).
The names without the trailing ``.value`` are accepted too.  Texels live in the texel
buffer ``T``, which every build reads at run time: assigning them changes the next render
without compiling.  Reading gives the value the scene has; assigning one switches the
scene to the generic build (parameters read at run time from its buffer ``PRM``:
docs/renderer.md), once, so the next render uses it without compiling again.

``scene.render_forward(name, spp=, seed=, tangent=)`` returns the image and its derivative
along ``tangent`` in the parameter's space (all ones by default: the derivative with
respect to a grey change of a colour).  It renders with a build whose kernel also carries
the tangents of every value (``ad_forward``, compiler/passes/ad_forward.py): the tangent
buffer ``dPRM`` holds ``tangent`` in the parameter's slots and zeros elsewhere, and the film
accumulates ``derivative(value)`` as extra channels.  The derivative is that of Mitsuba 3's
``prb`` estimator (docs/ad.md, "The estimator"): for a colour, the derivative of the same
Monte Carlo estimate (same seed); it ignores the discontinuities of visibility, as
Mitsuba 3 does without reparameterization.

Colours are stored as RGB in the ``mono`` and ``rgb`` variants.  The spectral variants store
a colour as what the kernel reads: three sigmoid-polynomial coefficients (Jakob & Hanika,
whose spectrum is ``sigmoid(c0 l^2 + c1 l + c2)`` at wavelength ``l`` in nm) and a scale, so
a colour parameter there holds those 4 values and its derivatives are with respect to them,
as Mitsuba 3's spectral ``value`` holds the coefficients.  Bitmap texels are parameters in
``mono`` and ``rgb`` only (the spectral variants store coefficients per texel).
"""

from __future__ import annotations

from collections.abc import Iterator, MutableMapping
from dataclasses import dataclass
from functools import cache
from typing import TYPE_CHECKING, Any

import numpy as np

from ...compiler.build import Build
from ...compiler.diagnostics import CompileError
from ...compiler.ir import ScalarType
from ...core.color import ColorModel
from ...core.scene_spec import Instance, SceneSpec, Slot
from ..plugins import INTERNAL, stdlib_plugin
from .bsdfs import plugin_params
from .integrators import integer_settings, integrator_instances
from .prebuild import speculate

if TYPE_CHECKING:
    from .renderer import Scene

__all__ = ["SceneParams", "gradient", "param_slots", "render_forward"]

KINDS = ("bsdfs", "bsdf_leaves", "emitters", "textures", "integrators")


def param_slots(spec: SceneSpec) -> dict[str, Slot]:
    """Parameter name -> its slot of ``PRM``, for a generic build's scene (whose values are
    :class:`Slot`s)."""
    out: dict[str, Slot] = {}
    for kind in KINDS:
        for inst in getattr(spec, kind):
            if inst.plugin in INTERNAL:  # a combinator tree's own numbers (its leaves are
                continue  # named by their path: runtime/render/bsdfs.py)
            hidden = layout_params(inst.plugin) if kind == "textures" else frozenset()
            for key, value in inst.params.items():
                if isinstance(value, Slot) and key not in hidden:
                    out[f"{inst.name or inst.plugin}.{mitsuba_key(key, inst.params)}"] = value
    return out


@cache
def layout_params(texture: str) -> frozenset[str]:
    """A stdlib texture's Int and Bool params: where its texels lie and how they are read
    (a bitmap's offset, size, filter and wrap mode, a flag), which the generic build reads
    from ``PRM`` like the rest but which are not the scene's values to assign (an offset
    past the texel buffer would read outside it) or differentiate: not in ``scene.params``."""
    if stdlib_plugin("texture", texture) is None:
        return frozenset()
    return frozenset(name for name, rdsl_type in plugin_params(texture, "texture").items()
                     if rdsl_type in ("Int", "Bool"))


def mitsuba_key(key: str, params: dict[str, Any]) -> str:
    """Mitsuba's name of a plugin parameter: an anisotropic roughness's ``alpha`` (the XML's
    ``alpha_u``) is ``alpha_u``."""
    return "alpha_u" if key == "alpha" and "alpha_v" in params else key


@dataclass(frozen=True)
class Texels:
    """A bitmap's texels in ``T``: each copy's first float and the scale it is stored
    divided by (a texture that sets a colour and a Float parameter has two copies)."""

    copies: tuple[tuple[int, float], ...]
    shape: tuple[int, int, int]

    @property
    def size(self) -> int:
        return self.shape[0] * self.shape[1] * self.shape[2]


def texel_params(textures: list[Instance], model: ColorModel) -> dict[str, Texels]:
    """``<name>.data`` -> the texels of each bitmap texture named by its id or its owner (a
    BSDF's, an area light's; not an emitter plugin's own, named ``bitmap``; colours are
    stored as linear RGB in ``mono`` and ``rgb``; the spectral variants store
    coefficients: none)."""
    out: dict[str, tuple[list[tuple[int, float]], tuple[int, int, int]]] = {}
    if model.spectral:
        return {}
    for t in textures:
        if t.plugin != "bitmap" or t.name in (None, "bitmap"):
            continue
        p = t.params
        copies, _ = out.setdefault(f"{t.name}.data", ([], (p["height"], p["width"], 3)))
        copies.append((3 * p["offset"], float(p.get("scale", 1.0))))
    return {k: Texels(tuple(c), s) for k, (c, s) in out.items()}


def integrator_names(scene: Scene) -> list[str]:
    """What ``scene.params`` names the scene's integrators by (``path`` in
    ``path.max_depth``): their integer settings, which have no derivative."""
    return [i.name or i.plugin for i in integrator_instances(scene.desc.integrator)]


def _key(slots: dict[str, Slot], name: str) -> str:
    """The slot key of parameter ``name`` (Mitsuba's trailing ``.value`` may be left out)."""
    return name[:-len(".value")] if name.endswith(".value") and name not in slots else name


def _lookup(slots: dict[str, Slot], name: str) -> tuple[str, Slot]:
    key = _key(slots, name)
    if key not in slots:
        valid = ", ".join(n if n.startswith(("path.", "direct.")) or n.endswith(".data")
                          else f"{n}.value" for n in slots)
        raise CompileError(f"the scene has no parameter `{name}` (its parameters: "
                           f"{valid or 'none'})")
    return key, slots[key]


def _numbers(name: str, value: Any) -> np.ndarray:
    """``value`` as float32, or a ValueError naming the parameter (not numpy's)."""
    try:
        return np.asarray(value, np.float32)
    except (TypeError, ValueError):
        raise ValueError(f"`{name}`: expected a number or an array of numbers, got "
                         f"{value!r}") from None


class SceneParams(MutableMapping):
    """The scene's parameters by name (see the module's documentation)."""

    def __init__(self, scene: Scene) -> None:
        self.scene = scene
        spec = scene.scene_spec_for_params()
        generic, self.values = scene.parameter_slots(spec)
        self.slots = param_slots(generic)
        self.texels = texel_params(scene.buffers.textures, scene.build.model)
        self.slots.update(self.texels)  # for _lookup's names; read and set below
        self.assigned: list[str] = []  # the names assigned, first first (prebuild.py)

    def __getitem__(self, name: str) -> np.ndarray:
        key, slot = _lookup(self.slots, name)
        if key in self.texels:
            off, scale = self.texels[key].copies[0]
            flat = self.scene.buffers.T[off:off + slot.size] * np.float32(scale)
            return flat.reshape(self.texels[key].shape)
        buf = self.scene.prm if self.scene._prm_set else self.values
        return np.array(buf[slot.offset:slot.offset + slot.size])

    def __setitem__(self, name: str, value: Any) -> None:
        key, slot = _lookup(self.slots, name)
        if key in self.texels:
            self._set_texels(name, self.texels[key], value)
            self._assigned(name)
            return
        v = _numbers(name, value).reshape(-1)
        if key in integer_settings(self.scene.desc.integrator) and \
                not np.all(np.isfinite(v) & (v == np.round(v))):
            raise ValueError(f"`{name}` is a whole-number setting of the integrator; got "
                             f"{value!r}")
        if v.size not in (1, slot.size):
            hint = " (a colour in the spectral variants: 3 sigmoid-polynomial coefficients " \
                "and a scale)" if self.scene.build.model.spectral and slot.size == 4 else ""
            raise ValueError(f"`{name}` holds {slot.size} value(s){hint}; got an array of "
                             f"{v.size}")
        self.scene.use_generic()
        self._assigned(name)  # before the generic kernels compile: the two overlap
        _check_tables(self.scene, name)
        self.scene.prm[slot.offset:slot.offset + slot.size] = v

    def _assigned(self, name: str) -> None:
        """Remember ``name``; a new one starts the adjoint kernel's build (prebuild.py)."""
        if name not in self.assigned:
            self.assigned.append(name)
            speculate(self.scene, self.assigned)

    def _set_texels(self, name: str, texels: Texels, value: Any) -> None:
        v = _numbers(name, value)
        if v.shape != texels.shape and v.size not in (1, texels.size):
            raise ValueError(f"`{name}` holds texels of shape {texels.shape}; got an array "
                             f"of shape {v.shape}")
        flat = np.broadcast_to(v.reshape(-1), texels.size)
        T = self.scene.buffers.T
        for off, scale in texels.copies:  # in place: every build reads T at run time
            T[off:off + texels.size] = flat / np.float32(scale)

    def __contains__(self, name: object) -> bool:
        return isinstance(name, str) and _key(self.slots, name) in self.slots

    def __delitem__(self, name: str) -> None:
        raise TypeError("scene parameters cannot be deleted")

    def __iter__(self) -> Iterator[str]:
        return iter(self.slots)

    def __len__(self) -> int:
        return len(self.slots)


def _check_tables(scene: Scene, name: str) -> None:
    """A parameter that a plugin's precomputed table reads (roughplastic's ``alpha``) cannot
    change at run time yet: the table holds the loaded value's samples."""
    from ..tables import _lowered

    key, _ = _lookup(scene.params.slots, name)
    owner, param = key.rsplit(".", 1)
    param = "alpha" if param == "alpha_u" else param  # mitsuba_key's name
    mod = scene.compile(quick=True)  # only its manifest is read: the quick tier will do
    entries = (mod.manifest or {}).get("tables") or []
    if not entries:
        return
    module = _lowered(scene.kernel_src, str(scene.path.with_suffix(".rdsl")),
                      tuple(str(p) for p in scene.search_paths))
    for e in entries:
        inst = getattr(scene.scene_spec, e["kind"])[e["index"]]
        read = module.functions[e["fn"] + ".read"]
        scalars = {p.value.name for p in read.params if isinstance(p.value.type, ScalarType)}
        if (inst.name or inst.plugin) == owner and param in scalars:  # tables read numbers
            raise CompileError(f"`{name}` is read by the precomputed table `{e['fn']}` of "
                               f"`{owner}`, computed when the scene loaded; changing it at "
                               "run time is not supported yet: load the scene with the new "
                               "value (a -D default or the XML)")


def ad_twin(scene: Scene, ad: str, eliminate: int = 0, tape: int = 0,
            seeds: tuple[int | str, ...] | None = None, covers: bool = False) -> Scene:
    """The scene's twin for differentiation mode ``ad``: same description and buffers, a
    generic build with tangents ("forward": its film also takes the derivative of the
    radiance) or adjoints ("reverse": runtime/render/backward.py; ``eliminate``: the
    threshold of graph elimination, 0 for none; ``tape``: bounces checkpointed per lane,
    0 to recompute them all; ``seeds``: the parameters differentiated, None for all, see
    :func:`adjoint_seeds`; ``covers``: no code for iterations beyond the tape,
    ``Build.tape_covers``)."""
    attr = f"_{ad}" + (f"_e{eliminate}" if eliminate else "") + (f"_t{tape}" if tape else "") \
        + (f"_s{hash(seeds)}" if seeds is not None else "") + ("_c" if covers else "")
    twin = getattr(scene, attr, None)
    if twin is None or twin.desc is not scene.desc:
        from .renderer import Scene as SceneClass

        twin = SceneClass.__new__(SceneClass)
        twin.__dict__.update(scene.__dict__)
        twin.build = Build(scene.build.target, scene.build.model, ad, eliminate, tape, seeds,
                           covers)
        twin.specialize, twin.derivative, twin._prm_set = False, ad == "forward", True
        twin._tier_up = None  # the scene's own background build, not the twin's
        twin._speculating = twin._speculated = None  # likewise (prebuild.py)
        twin._reset_kernels()
        twin._forward = twin._reverse = None
        setattr(scene, attr, twin)
    return twin


def seeds_of(scene: Scene, names: list[str]) -> tuple[int | str, ...] | None:
    """``Build.seeds`` of an adjoint kernel for the parameters ``names`` of ``scene``."""
    return adjoint_seeds({n: _lookup(scene.params.slots, n)[1] for n in names})


def adjoint_seeds(chosen: dict[str, Slot | Texels]) -> tuple[int | str, ...] | None:
    """The loads an adjoint kernel for the parameters ``chosen`` differentiates
    (``Build.seeds``): their elements of ``PRM``, and ``"T"`` if texels are among them; None
    (every load) if one is a tabulated spectrum, which is read at computed elements."""
    elements: set[int] = set()
    for slot in chosen.values():
        if isinstance(slot, Texels):
            continue
        if slot.table:
            return None
        elements.update(range(slot.offset, slot.offset + slot.size))
    texels = any(isinstance(slot, Texels) for slot in chosen.values())
    return (*sorted(elements), *(("T",) if texels else ()))


def render_forward(scene: Scene, name: str, spp: int | None = None, seed: int | None = None,
                   tangent: Any = None, threads: int | None = None
                   ) -> tuple[np.ndarray, np.ndarray]:
    """The image and its derivative with respect to parameter ``name`` along ``tangent``."""
    params = scene.params  # validates the name before anything compiles
    key, slot = _lookup(params.slots, name)
    if key in params.texels:
        raise CompileError(f"`{name}`: forward derivatives with respect to texels are not "
                           "offered (one render per texel); use scene.backward")
    t = np.ones(slot.size, np.float32) if tangent is None else \
        np.asarray(tangent, np.float32).reshape(-1)
    if t.size not in (1, slot.size):
        raise ValueError(f"the tangent of `{name}` has {slot.size} value(s); got {t.size}")
    twin = ad_twin(scene, "forward")
    mod = twin.compile(quick=twin.quick_fits(spp))
    twin.prm = twin.with_tables(np.array(scene.prm if scene._prm_set else params.values), mod)
    twin.tangents = np.zeros_like(twin.prm)
    twin.tangents[slot.offset:slot.offset + slot.size] = t
    img = twin.render(spp=spp, seed=seed, threads=threads)
    c = 1 if scene.build.model.mono else 3  # the derivative's channels come last
    return img[..., :-c], img[..., -c:]


def gradient(scene: Scene, names: list[str], loss_grad: np.ndarray, spp: int | None = None,
             seed: int | None = None) -> dict[str, np.ndarray]:
    """The gradient of a loss with respect to parameters ``names``, given the loss's
    gradient with respect to the image (``loss_grad``, shaped like ``render()``'s colour
    channels): by forward mode, one derivative render per parameter component, each
    contracted with ``loss_grad``.  Exact for few parameters (colours, a roughness); reverse
    mode, which costs one render for all of them, is not written yet."""
    out: dict[str, np.ndarray] = {}
    for name in names:
        _, slot = _lookup(scene.params.slots, name)
        g = np.zeros(slot.size, np.float64)
        for k in range(slot.size):
            tangent = np.zeros(slot.size, np.float32)
            tangent[k] = 1.0
            _, d_img = render_forward(scene, name, spp, seed, tangent)
            if d_img.shape != np.shape(loss_grad):
                raise ValueError(f"the loss gradient has shape {np.shape(loss_grad)}; the "
                                 f"image's colour channels are {d_img.shape}")
            g[k] = float(np.sum(d_img.astype(np.float64) * loss_grad))
        out[name] = g.astype(np.float32)
    return out
