"""A user plugin's scene values as ``specialize`` takes them: each XML property the loader
checked against the plugin's ``param`` declarations (runtime/plugins.py) becomes the value of
the param of the same name, with no Mitsuba conversions.

By the param's rdsl type: ``Float``, ``Int``, ``Bool`` numbers stay numbers; a ``Spectrum``
or ``Texture`` colour becomes a :class:`SpectrumValue` (an illuminant on an emitter, or on a
texture that sets emitted light); a texture on a ``Texture`` param is a reference to the
scene's texture, and on a ``Float`` param a reference to its one-value lookup (``eval_1``);
a ``Vec3`` is a tuple.  A texture's ``to_uv`` transform sets its ``to_u``/``to_v`` rows.  A
param the scene leaves out is not passed: ``specialize`` takes its declared default.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ...compiler.diagnostics import CompileError
from ...core.scene_spec import Instance
from ..plugins import UV_ROWS
from .colors import spectrum_value


def _where(plugin: Any) -> str:
    return (f"{plugin.category} `{plugin.type}`" + (f" (id '{plugin.id}')" if plugin.id else "")
            + f" (declared at {plugin.decl.where})")


def declared_params(plugin: Any, textures: Any = None, illuminant: bool = False
                    ) -> dict[str, Any]:
    """The instance parameters of ``plugin`` (a loader Plugin with a ``decl``)."""
    decls = plugin.decl.params()
    out: dict[str, Any] = {}
    for name, value in plugin.params.items():
        if value is None:
            continue
        if name == "to_uv":  # Mitsuba's 2-D affine part, as rows (textures.py's _uv_rows)
            m = np.asarray(value, np.float64)
            for row, key in zip((0, 1), UV_ROWS):
                out[key] = (float(m[row, 0]), float(m[row, 1]), float(m[row, 3]))
            continue
        rdsl_type = decls[name].type
        what = f"{plugin.type}.{name}"
        if getattr(value, "category", None) == "texture":
            if textures is None:
                article = "an" if plugin.category[0] in "aeiou" else "a"
                raise CompileError(f"{_where(plugin)}: a texture cannot set `{name}` here "
                                   f"({article} {plugin.category}'s params take constant "
                                   "colours, not textures)",
                                   getattr(value, "loc", None) or plugin.loc)
            usage = ("scalar" if rdsl_type == "Float" else "emitted" if illuminant
                     else "colour")
            out[name] = textures.ref(value, what, usage)
        elif getattr(value, "rgb", None) is not None:
            out[name] = spectrum_value(value, what, illuminant=illuminant, loc=plugin.loc)
        elif isinstance(value, np.ndarray):
            out[name] = tuple(float(x) for x in value.reshape(-1))
        elif isinstance(value, bool) or rdsl_type == "Bool":
            out[name] = bool(value)
        elif rdsl_type in ("Int", "UInt", "UInt64"):
            out[name] = int(value)
        elif isinstance(value, (int, float)):
            out[name] = float(value)
        else:
            raise CompileError(f"{_where(plugin)}: cannot pass `{name}` = {value!r} to the "
                               "plugin", plugin.loc)
    return out


def declared_instance(plugin: Any, textures: Any = None, illuminant: bool = False) -> Instance:
    """The instance of a user plugin (a BSDF, an emitter or a texture)."""
    return Instance(plugin.type, declared_params(plugin, textures, illuminant),
                    plugin.id or plugin.type)


def needs_eval_1(plugin: Any, what: str) -> None:
    """A texture that sets a Float parameter is read through its ``eval_1``: a user texture
    must declare one."""
    decl = getattr(plugin, "decl", None)
    if decl is not None and not decl.has_fn("eval_1"):
        raise CompileError(f"{what}: texture `{plugin.type}` ({decl.where}) has no "
                           "`fn eval_1(si: Surface) -> Float`, the one-value lookup a texture "
                           "setting a Float parameter needs", plugin.loc)
