"""Mesh attributes, as Mitsuba 3's PLY loader names them, and the checks of the
``mesh_attribute`` textures that read them.

A PLY ``vertex`` or ``face`` element's properties other than positions, normals, uvs and
indices become attributes (Mitsuba 3.9's ``ply.cpp``): consecutive properties
``{prefix}_{x|y|z}``, ``{prefix}_{0|1|2}`` or ``{prefix}_{1|2|3}`` are attribute
``{vertex|face}_{prefix}`` (``{prefix}_{r|g|b}``: ``{vertex|face}_{prefix}_color``), a lone
``{prefix}_x`` (or ``_0``...) a one-component one, and ``r g b`` (or ``red green blue``)
``{vertex|face}_color``.  Attributes have 1 or 3 components; others (2 or 4 components, a
name without a postfix) are skipped, with Mitsuba's warning.  Integer properties are
normalized to [0, 1] and sRGB-decoded, as Mitsuba's struct converter does.
"""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np

PREFIXES = ("vertex_", "face_")
# the postfix sequences of a multi-component attribute; the second names a colour
_POSTFIXES = ("xyzw", "rgba", "0123", "1234")
_RESERVED = {"x", "y", "z", "nx", "ny", "nz", "u", "v", "s", "t", "texture_u", "texture_v",
             "texture_s", "texture_t", "vertex_indices", "vertex_index"}


def _srgb_to_linear(x: np.ndarray) -> np.ndarray:
    return np.where(x <= 0.04045, x / 12.92, np.power((x + 0.055) / 1.055, 2.4))


def _column(values: Any, ptype: str) -> np.ndarray:
    a = np.asarray(values, np.float64).reshape(-1)
    if ptype[0] in "iu":  # integers: normalized and sRGB-decoded
        top = float(np.iinfo(np.dtype(ptype)).max)
        a = _srgb_to_linear(np.clip(a / top, 0.0, 1.0))
    return a


def ply_attributes(kind: str, props: list[tuple[str, str, str | None]], values: dict,
                   where: str) -> dict[str, np.ndarray]:
    """The attributes of one PLY element (``kind``: vertex or face) as (count, 1 or 3)
    float32 arrays, by name (``vertex_color``...)."""
    names = [(n, t) for n, t, item in props if item is None and n not in _RESERVED]
    out: dict[str, np.ndarray] = {}
    groups: list[tuple[str, int, list[tuple[str, str]]]] = []  # (prefix, postfix row, props)
    colour = {"r", "g", "b"} <= {n for n, _ in names} or \
        {"red", "green", "blue"} <= {n for n, _ in names}
    for name, ptype in names:
        if name in ("r", "g", "b", "a", "red", "green", "blue", "alpha"):
            continue
        prefix, sep, post = name.rpartition("_")
        if not sep or len(post) != 1:
            warnings.warn(f"{where}: PLY {kind} property '{name}' has no one-letter postfix "
                          "(such as _x); it is not an attribute (as in Mitsuba 3)", stacklevel=3)
            continue
        if groups and groups[-1][0] == prefix:
            row, members = groups[-1][1], groups[-1][2]
            if len(members) < 4 and post == _POSTFIXES[row][len(members)]:
                members.append((name, ptype))
                continue
        row = next((k for k, seq in enumerate(_POSTFIXES) if seq[0] == post), None)
        if row is None:
            warnings.warn(f"{where}: PLY {kind} property '{name}' cannot start an attribute "
                          f"(postfix '{post}')", stacklevel=3)
            continue
        groups.append((prefix, row, [(name, ptype)]))
    if colour:
        rgb = ("r", "g", "b") if "r" in values else ("red", "green", "blue")
        types = dict(names)
        out[f"{kind}_color"] = np.stack([_column(values[c], types[c]) for c in rgb], 1)
    for prefix, row, members in groups:
        attr = f"{kind}_{prefix}" + ("_color" if row == 1 else "")
        if len(members) not in (1, 3):
            warnings.warn(f"{where}: PLY attribute '{attr}' has {len(members)} components; "
                          "attributes have 1 or 3 (it is skipped, as in Mitsuba 3)",
                          stacklevel=3)
            continue
        out[attr] = np.stack([_column(values[n], t) for n, t in members], 1)
    return {k: np.ascontiguousarray(v, np.float32) for k, v in out.items()}


def attribute_textures(plugin: Any, seen: set[int] | None = None) -> list[Any]:
    """The ``mesh_attribute`` textures a BSDF (or texture) reads, through nested BSDFs and
    textures of textures."""
    seen = set() if seen is None else seen
    if plugin is None or id(plugin) in seen or not hasattr(plugin, "params"):
        return []
    seen.add(id(plugin))
    found = [plugin] if (plugin.category, plugin.type) == ("texture", "mesh_attribute") else []
    for value in [*plugin.params.values(), *getattr(plugin, "children", [])]:
        if getattr(value, "category", None) in ("texture", "bsdf"):
            found += attribute_textures(value, seen)
    return found


def check_attributes(shape: Any, what: str) -> tuple[str, Any] | None:
    """Why the shape's BSDF cannot read its mesh attributes, and the texture that tries
    (None: it can): a mesh_attribute on an analytic shape, or naming an attribute the mesh
    lacks."""
    for tex in attribute_textures(shape.bsdf):
        name = tex.params["name"]
        if shape.analytic is not None:
            return ((f"mesh_attribute '{name}': {what} is not a triangle mesh and has no "
                    "attributes (they come from PLY files)"), tex)
        have = shape.mesh.attributes
        if name not in have:
            listed = ", ".join(sorted(have)) or "none"
            return ((f"mesh_attribute: {what} has no attribute '{name}' (its attributes: "
                    f"{listed})"), tex)
    return None
