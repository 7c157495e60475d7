"""Mitsuba 3's ``measured_polarized`` BSDF (stdlib/bsdf/measured_polarized.rdsl): its table
in the scene's texel buffer ``T`` and its instance.

The loader has read and checked the file (core/tensorfile.py, runtime/scene/finish.py).  The
table goes into ``T`` once per file, as the plugin reads it: the grids of phi_d, theta_d and
theta_h (radians), the wavelengths (nm), then the Mueller matrices in the file's order; the
instance holds where it starts and the grid sizes.  Outside spectral variants the table is
read at one wavelength, which the scene must give (``wavelength``), as Mitsuba requires.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ...compiler.diagnostics import CompileError
from ...core.color import ColorModel
from ...core.scene_spec import Instance

NAME = "measured_polarized"


def measured_instance(plugin: Any, textures: Any) -> Instance:
    """The instance of a ``measured_polarized`` BSDF, its table appended to ``T``."""
    p = plugin.params
    if textures is None:
        raise CompileError(f"bsdf `{NAME}`: the texel buffer is not available here",
                           plugin.loc)
    t = p["table"]
    values = np.concatenate([t.phi_d, t.theta_d, t.theta_h, t.wvls, t.M.reshape(-1)])
    offset = textures.floats(("pbrdf", p["filename"]), values)
    return Instance(NAME, {"offset": offset, "n_phi": len(t.phi_d), "n_td": len(t.theta_d),
                           "n_th": len(t.theta_h), "n_wl": len(t.wvls),
                           "wavelength": float(p["wavelength"]),
                           "alpha_sample": float(p["alpha_sample"])},
                    plugin.id or plugin.type)


def check_measured_variant(plugins: Any, model: ColorModel) -> None:
    """Mitsuba's rule: outside spectral variants a ``measured_polarized`` BSDF is read at
    one wavelength, its ``wavelength``, which must then be given."""
    if model.spectral:
        return
    for plugin in plugins:
        if (plugin.type == NAME and getattr(plugin, "decl", None) is None
                and float(plugin.params["wavelength"]) < 0.0):
            raise CompileError(f"bsdf `{NAME}` ('{plugin.params['filename']}'): the "
                               f"`{model.name}` variant has no wavelengths, so give the one "
                               "to render in nm (<float name=\"wavelength\" value=\"550\"/>), "
                               "as Mitsuba 3 requires, or render a spectral variant",
                               plugin.loc)
