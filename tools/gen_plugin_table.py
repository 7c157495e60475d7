"""Write the table of Mitsuba 3's plugins against rdsl's into docs/plugins.md.

rdsl's side comes from the code: the loader's schema (runtime/scene/schema.py, Mitsuba's
plugins with their parameters) and the stdlib's plugin files (runtime/plugins.py), so the
table cannot drift; tests/test_plugin_table.py checks that the committed text is what this
script writes.  Mitsuba's side is the list below: the plugins of the `mitsuba` 3.9.1 wheel
(its ``mitsuba/plugins/*.so``) sorted into categories by their documentation, less the
spectra (``d65``, ``srgb``, ``blackbody``...), which rdsl reads as values, not plugins.
Run ``python -m rdsl.tools.gen_plugin_table`` after adding a plugin.
"""

from __future__ import annotations

import sys
from pathlib import Path

from ..runtime.plugins import stdlib_names
from ..runtime.scene.schema import SCHEMA

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "plugins.md"
BEGIN = "<!-- plugin table: python -m rdsl.tools.gen_plugin_table -->"
END = "<!-- end of plugin table -->"

MITSUBA: dict[str, tuple[str, ...]] = {
    "shape": ("bsplinecurve", "cube", "cylinder", "disk", "ellipsoids", "ellipsoidsmesh",
              "instance", "linearcurve", "merge", "obj", "ply", "rectangle", "sdfgrid",
              "serialized", "shapegroup", "sphere"),
    "bsdf": ("blendbsdf", "bumpmap", "conductor", "circular", "dielectric", "diffuse", "hair",
             "mask", "measured", "measured_polarized", "normalmap", "null", "plastic",
             "polarizer", "pplastic", "principled", "principledthin", "retarder",
             "roughconductor", "roughdielectric", "roughplastic", "thindielectric",
             "twosided"),
    "texture": ("bitmap", "checkerboard", "mesh_attribute", "volume"),
    "emitter": ("area", "constant", "directional", "directionalarea", "envmap", "point",
                "projector", "spot", "sunsky", "timed_sunsky"),
    "sensor": ("batch", "distant", "irradiancemeter", "orthographic", "perspective",
               "radiancemeter", "thinlens"),
    "integrator": ("aov", "depth", "direct", "moment", "path", "ptracer", "stokes", "volpath",
                   "volpathmis"),
    "sampler": ("independent", "ldsampler", "multijitter", "orthogonal", "stratified"),
    "film": ("hdrfilm", "specfilm"),
    "rfilter": ("box", "catmullrom", "gaussian", "lanczos", "mitchell", "tent"),
    "medium": ("heterogeneous", "homogeneous"),
    "phase": ("blendphase", "hg", "isotropic", "rayleigh", "sggx", "tabphase"),
    "volume": ("constvolume", "gridvolume"),
}
# rdsl plugins that are not in the schema nor a stdlib file of that name
BUILT_IN = {("bsdf", "twosided"), ("bsdf", "mask"), ("bsdf", "blendbsdf")}


def supported(category: str, name: str) -> bool:
    """Whether a scene's ``<category type="name">`` loads in rdsl."""
    if (category, name) in SCHEMA or (category, name) in BUILT_IN:
        return True
    try:
        return name in stdlib_names(category)
    except (KeyError, ValueError):
        return False


def table() -> str:
    """The Markdown table: each Mitsuba 3 plugin, whether rdsl has it, its parameters."""
    lines = [BEGIN, "", "| category | Mitsuba 3 plugin | rdsl | parameters rdsl reads |",
             "|---|---|---|---|"]
    done = 0
    total = 0
    for category, names in MITSUBA.items():
        for name in names:
            ok = supported(category, name)
            spec = SCHEMA.get((category, name))
            params = ", ".join(f"`{p}`" for p in spec.params) if spec else ""
            if ok and spec is None:
                params = "its `param`s (stdlib/)"
            lines.append(f"| {category} | `{name}` | {'yes' if ok else '—'} | {params} |")
            done += ok
            total += 1
    lines += ["", f"rdsl loads {done} of these {total} plugins.", "", END]
    return "\n".join(lines)


def updated(text: str) -> str:
    """``text`` (docs/plugins.md) with its table replaced, or appended under a heading."""
    if BEGIN in text:
        head, rest = text.split(BEGIN, 1)
        return head + table() + rest.split(END, 1)[1]
    return text.rstrip("\n") + "\n\n## Mitsuba 3's plugins in rdsl\n\n" + table() + "\n"


def main() -> int:
    DOC.write_text(updated(DOC.read_text()))
    print(f"wrote {DOC}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
