"""Mitsuba 3 XML to a tree of plugin objects, with every element's file and line.

Two steps.  :func:`parse_xml_file` reads XML with expat into :class:`Element` nodes that
remember where they came from (expat reports a malformed file's line and column).
:func:`read_scene` then walks the elements in document order the way Mitsuba does:

- ``<default name value>`` defines ``$name`` unless ``-D name=value`` already did;
  every attribute then has ``$name`` replaced (an undefined ``$name`` is an error);
- ``<include filename>`` splices in the children of another file's ``<scene>``;
- ``<path value>`` adds a directory to search for files (see :meth:`SceneTree.resolve_file`);
- ``<ref id>`` / ``<ref name id>`` stands for the object with that ``id``, declared anywhere
  in the scene: references are resolved once the whole scene is read (:mod:`.refs`);
- property tags become typed :class:`Prop` values, ``<transform>`` a 4x4 matrix.

The result is a :class:`SceneTree` of :class:`ObjectNode`; plugin parameters are checked
later, against the schema, by the loader.
"""

from __future__ import annotations

import math
import re
import warnings
import xml.parsers.expat
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ...compiler.diagnostics import register_source
from ...compiler.ir import Loc
from . import transform as xf
from .errors import file_loc, scene_error
from .reads import first_file, note
from .refs import UNRESOLVED, resolve_refs
from .spectra import (
    Color,
    parse_float,
    parse_numbers,
    parse_rgb,
    parse_spectrum,
    read_spd,
    spectrum_to_srgb,
)
from .spectrum_plugins import spectrum_plugin

OBJECT_TAGS = ("shape", "bsdf", "texture", "emitter", "integrator", "sensor", "film",
               "sampler", "rfilter", "volume")
PROPERTY_TAGS = ("float", "integer", "boolean", "string", "rgb", "spectrum", "point", "vector",
                 "transform")
OTHER_TAGS = ("ref", "include", "default", "path")
UNSUPPORTED_OBJECTS = ("medium", "phase")
TRANSFORM_OPS = {
    "translate": ("x", "y", "z", "value"),
    "rotate": ("x", "y", "z", "angle", "value"),
    "scale": ("x", "y", "z", "value"),
    "matrix": ("value",),
    "lookat": ("origin", "target", "up"),
}
_ATTRS = {
    **{t: ("type", "id", "name") for t in OBJECT_TAGS},
    "float": ("name", "value"), "integer": ("name", "value"), "boolean": ("name", "value"),
    "string": ("name", "value"), "rgb": ("name", "value"), "spectrum": ("name", "value",
                                                                        "filename"),
    "point": ("name", "value", "x", "y", "z"), "vector": ("name", "value", "x", "y", "z"),
    "transform": ("name",), "ref": ("id", "name"), "include": ("filename",),
    "default": ("name", "value"), "path": ("value",),
}
_PARAM = re.compile(r"\$([A-Za-z_][A-Za-z0-9_]*)")


# ---------------------------------------------------------------------------------------
# Step 1: XML with locations

@dataclass
class Element:
    """One XML element and where it starts."""

    tag: str
    attrs: dict[str, str]
    children: list[Element]
    loc: Loc


def parse_xml_file(path: Path, loc: Loc | None = None) -> Element:
    """Parse ``path`` with expat; malformed XML is a :class:`SceneError` at its line."""
    path = Path(path)
    note(path)
    try:
        data = path.read_bytes()
    except OSError as e:
        raise scene_error(f"cannot read scene file '{path}': {e.strerror}",
                          loc or file_loc(str(path))) from None
    fname = str(path)
    register_source(fname, data.decode("utf-8", errors="replace"))
    parser = xml.parsers.expat.ParserCreate()
    stack: list[Element] = []
    roots: list[Element] = []

    def start(tag: str, attrs: dict[str, str]) -> None:
        el = Element(tag, dict(attrs), [],
                     Loc(fname, parser.CurrentLineNumber, parser.CurrentColumnNumber + 1))
        (stack[-1].children if stack else roots).append(el)
        stack.append(el)

    def end(tag: str) -> None:
        stack.pop()

    parser.StartElementHandler = start
    parser.EndElementHandler = end
    try:
        parser.Parse(data, True)
    except xml.parsers.expat.ExpatError as e:
        msg = xml.parsers.expat.ErrorString(e.code)
        raise scene_error(f"malformed XML: {msg}", Loc(fname, e.lineno, e.offset + 1)) from None
    return roots[0]


# ---------------------------------------------------------------------------------------
# Step 2: the object tree

@dataclass
class Prop:
    """A property of an object: ``kind`` is the XML tag (``float``, ``rgb``, ...)."""

    kind: str
    value: Any
    loc: Loc


@dataclass
class Child:
    """A nested object, or a reference to one (``name`` is ``None`` when not given)."""

    name: str | None
    node: ObjectNode
    loc: Loc
    is_ref: bool = False


@dataclass
class ObjectNode:
    """``<shape type="...">`` and friends: a plugin to instantiate."""

    category: str
    type: str
    id: str | None
    loc: Loc
    base_dir: Path
    props: dict[str, Prop] = field(default_factory=dict)
    children: list[Child] = field(default_factory=list)


@dataclass
class SceneTree:
    """The parsed scene: its root object, where to look for files, and the $parameters.

    ``search_paths``: the ``<path>`` folders of the main file, the latest first (Mitsuba
    prepends each to its file resolver); ``include_paths``: those of included files."""

    root: ObjectNode
    path: Path
    search_paths: list[Path]
    params: dict[str, str]
    unused_defines: list[str]
    ids: dict[str, ObjectNode]
    include_paths: list[Path] = field(default_factory=list)

    def resolve_file(self, name: str, base_dir: Path, what: str, loc: Loc) -> Path:
        """Find a plugin's file (mesh, bitmap, envmap) as Mitsuba 3's file resolver does, or
        raise naming it and the line.

        Mitsuba looks in the main file's ``<path>`` folders, then the main scene's folder,
        whichever file names it: a relative name in an included file is relative to the
        main scene, not to the included file.  Where Mitsuba finds nothing, rdsl also looks
        in the folders of included files' ``<path>`` elements (Mitsuba 3 forgets those when
        the include ends) and then in ``base_dir``, the folder of the file that names it, so
        it finds the same file as Mitsuba whenever Mitsuba finds one."""
        p = Path(name)
        candidates = [p] if p.is_absolute() else [
            *(d / p for d in self.search_paths), self.path.parent / p,
            *(d / p for d in self.include_paths), base_dir / p]
        found = first_file(candidates)
        if found is not None:
            return found
        looked = ", ".join(dict.fromkeys(str(c.parent) for c in candidates))
        raise scene_error(f"{what} file '{name}' not found (looked in: {looked})", loc)


def parse_defines(defines: list[str]) -> dict[str, str]:
    """``["spp=16", "res=128"]`` (the CLI's ``-D`` options) to a dict."""
    out = {}
    for d in defines:
        name, sep, value = d.partition("=")
        if not sep or not name.strip():
            raise scene_error(f"-D expects name=value, got {d!r}", None)
        out[name.strip()] = value
    return out


class _Reader:
    def __init__(self, path: Path, defines: dict[str, str]) -> None:
        self.path = path
        self.params = {k: str(v) for k, v in defines.items()}
        self.cli_names = set(self.params)
        self.used: set[str] = set()
        self.ids: dict[str, ObjectNode] = {}
        self.search_paths: list[Path] = []   # the main file's <path>s, the latest first
        self.include_paths: list[Path] = []  # the <path>s of included files
        self.include_stack: list[Path] = []
        self.refs: list[Child] = []          # every <ref>, resolved once all is read

    def candidates(self, name: str, el: Element) -> list[Path]:
        """Where a file named while reading ``el`` may be (an include, a spectrum file, a
        ``<path>`` folder): Mitsuba's resolver while it parses, which holds the folder of the
        file being read as well as the main scene's."""
        p = Path(name)
        if p.is_absolute():
            return [p]
        dirs = [*self.search_paths, Path(el.loc.file).parent, self.path.parent,
                *self.include_paths]
        return [d / p for d in dict.fromkeys(dirs)]

    # -- attributes --------------------------------------------------------------------
    def attrs(self, el: Element) -> dict[str, str]:
        allowed = _ATTRS.get(el.tag, ())
        for a in el.attrs:
            if a not in allowed:
                raise scene_error(f"<{el.tag}>: unexpected attribute '{a}'; accepted: "
                                  f"{', '.join(allowed) or 'none'}", el.loc)
        return {a: self.substitute(v, el) for a, v in el.attrs.items()}

    def substitute(self, text: str, el: Element) -> str:
        def repl(m: re.Match) -> str:
            name = m.group(1)
            if name not in self.params:
                known = ", ".join(sorted(self.params)) or "none"
                raise scene_error(f"<{el.tag}>: undefined parameter '${name}'; define it with "
                                  f"<default name=\"{name}\" value=\"...\"/> or -D "
                                  f"{name}=... (defined: {known})", el.loc)
            self.used.add(name)
            return self.params[name]
        return _PARAM.sub(repl, text) if "$" in text else text

    @staticmethod
    def need(el: Element, attrs: dict[str, str], key: str) -> str:
        if key not in attrs:
            raise scene_error(f"<{el.tag}>: missing required attribute '{key}'", el.loc)
        return attrs[key]

    # -- the scene ---------------------------------------------------------------------
    def read_root(self, root: Element, path: Path) -> ObjectNode:
        if root.tag != "scene":
            raise scene_error(f"the root element must be <scene>, not <{root.tag}>", root.loc)
        attrs = {a: v for a, v in root.attrs.items()}
        for a in attrs:
            if a != "version":
                raise scene_error(f"<scene>: unexpected attribute '{a}'; accepted: version",
                                  root.loc)
        version = attrs.get("version")
        if version is None:
            raise scene_error("<scene>: missing the 'version' attribute (write "
                              "<scene version=\"3.0.0\">)", root.loc)
        m = re.fullmatch(r"\s*(\d+)(\.\d+)*\s*", version)
        if not m:
            raise scene_error(f"<scene>: cannot parse version '{version}'", root.loc)
        if not 2 <= int(m.group(1)) <= 3:
            raise scene_error(f"<scene>: version {version} is not supported; rdsl reads the "
                              "Mitsuba 3 format (version 2.x or 3.x)", root.loc)
        return ObjectNode("scene", "scene", None, root.loc, path.parent)

    def read_children(self, parent: ObjectNode, el: Element) -> None:
        for c in el.children:
            self.read_child(parent, c)

    def read_child(self, parent: ObjectNode, el: Element) -> None:
        tag = el.tag
        if tag == "default":
            a = self.attrs(el)
            name, value = self.need(el, a, "name"), self.need(el, a, "value")
            self.params.setdefault(name, value)
        elif tag == "path":
            if parent.category != "scene":
                raise scene_error("<path> may only appear directly inside <scene>", el.loc)
            a = self.attrs(el)
            cands = self.candidates(self.need(el, a, "value"), el)
            d = next((c for c in cands if c.is_dir()), None)
            if d is None:
                raise scene_error(f"<path>: directory '{a['value']}' not found (looked in: "
                                  f"{', '.join(str(c.parent) for c in cands)})", el.loc)
            if len(self.include_stack) == 1:
                self.search_paths.insert(0, d)
            else:
                self.include_paths.append(d)
        elif tag == "include":
            if parent.category != "scene":
                raise scene_error("<include> may only appear directly inside <scene>", el.loc)
            self.read_include(parent, el)
        elif tag == "ref":
            a = self.attrs(el)
            ident = self.need(el, a, "id")
            # a placeholder until the whole scene is read: the object may come later
            ref = ObjectNode(UNRESOLVED, UNRESOLVED, ident, el.loc, Path(el.loc.file).parent)
            child = Child(a.get("name"), ref, el.loc, True)
            self.add_child(parent, child)
            self.refs.append(child)
        elif tag in OBJECT_TAGS:
            node = self.read_object(el, parent)
            self.add_child(parent, Child(el.attrs.get("name") and self.substitute(
                el.attrs["name"], el), node, el.loc))
        elif tag == "spectrum" and "type" in el.attrs:
            self.read_spectrum_plugin(parent, el)
        elif tag in PROPERTY_TAGS:
            a = self.attrs(el)
            name = self.need(el, a, "name")
            if parent.category == "scene":
                raise scene_error(f"<{tag} name=\"{name}\">: a property must be inside an "
                                  "object, not directly inside <scene>", el.loc)
            self.check_unique(parent, name, el.loc)
            parent.props[name] = Prop(tag, self.read_value(el, a), el.loc)
        elif tag in UNSUPPORTED_OBJECTS:
            raise scene_error(f"<{tag}> is not supported by rdsl (no participating media); "
                              f"supported objects: {', '.join(OBJECT_TAGS)}", el.loc)
        elif tag == "scene":
            raise scene_error("<scene> may only be the root element", el.loc)
        else:
            raise scene_error(f"unknown element <{tag}>; accepted: "
                              f"{', '.join(OBJECT_TAGS + PROPERTY_TAGS + OTHER_TAGS)}", el.loc)

    def read_spectrum_plugin(self, parent: ObjectNode, el: Element) -> None:
        """``<spectrum type="..." name="...">`` with nested properties: one of Mitsuba's
        spectrum plugins, read as a ``<spectrum>`` property of ``parent``."""
        for key in el.attrs:
            if key not in ("type", "name"):
                raise scene_error(f"<spectrum type=...>: unexpected attribute '{key}'; "
                                  "accepted: type, name", el.loc)
        a = {k: self.substitute(v, el) for k, v in el.attrs.items()}
        name = self.need(el, a, "name")
        if parent.category == "scene":
            raise scene_error(f"<spectrum name=\"{name}\">: a property must be inside an "
                              "object, not directly inside <scene>", el.loc)
        props: dict[str, tuple[str, Any, Loc]] = {}
        for c in el.children:
            if c.tag not in PROPERTY_TAGS or c.tag == "transform":
                raise scene_error(f"<{c.tag}> cannot appear inside <spectrum type=...>; "
                                  "give its parameters as <float>, <string> or <rgb>", c.loc)
            ca = self.attrs(c)
            props[self.need(c, ca, "name")] = (c.tag, self.read_value(c, ca), c.loc)
        self.check_unique(parent, name, el.loc)
        parent.props[name] = Prop("spectrum", spectrum_plugin(a["type"], props, el.loc), el.loc)

    def check_unique(self, parent: ObjectNode, name: str, loc: Loc) -> None:
        clash = name in parent.props or any(c.name == name for c in parent.children)
        if clash:
            raise scene_error(f"parameter '{name}' of {parent.category} '{parent.type}' is "
                              "given more than once", loc)

    def add_child(self, parent: ObjectNode, child: Child) -> None:
        if child.name is not None:
            self.check_unique(parent, child.name, child.loc)
        parent.children.append(child)

    def read_object(self, el: Element, parent: ObjectNode) -> ObjectNode:
        a = self.attrs(el)
        ptype = self.need(el, a, "type")
        ident = a.get("id")
        node = ObjectNode(el.tag, ptype, ident, el.loc, Path(el.loc.file).parent)
        self.read_children(node, el)
        if ident is not None:
            if ident in self.ids:
                prev = self.ids[ident].loc
                raise scene_error(f"duplicate id '{ident}' (first declared at {prev})", el.loc)
            self.ids[ident] = node
        return node

    def read_include(self, parent: ObjectNode, el: Element) -> None:
        a = self.attrs(el)
        name = self.need(el, a, "filename")
        cands = self.candidates(name, el)
        target = first_file(cands)
        if target is None:
            raise scene_error(f"<include>: file '{name}' not found (looked in: "
                              f"{', '.join(str(c.parent) for c in cands)})", el.loc)
        target = target.resolve()
        if target in self.include_stack:
            raise scene_error(f"<include>: '{name}' includes itself (cycle through "
                              f"{' -> '.join(p.name for p in self.include_stack)})", el.loc)
        self.include_stack.append(target)
        root = parse_xml_file(target, el.loc)
        self.read_root(root, target)
        self.read_children(parent, root)
        self.include_stack.pop()

    # -- property values ---------------------------------------------------------------
    def read_value(self, el: Element, a: dict[str, str]) -> Any:
        tag, name = el.tag, a["name"]
        what = f"<{tag} name=\"{name}\">"
        if tag == "transform":
            return self.read_transform(el)
        if el.children:
            raise scene_error(f"{what} cannot have child elements", el.children[0].loc)
        if tag == "spectrum" and "filename" in a:
            if "value" in a:
                raise scene_error(f"{what}: give either 'value' or 'filename', not both", el.loc)
            path = first_file(self.candidates(a["filename"], el))
            if path is None:
                raise scene_error(f"{what}: spectrum file '{a['filename']}' not found", el.loc)
            wl, vals = read_spd(path, el.loc)
            return Color(spectrum_to_srgb(wl, vals, False), tuple(wl), tuple(vals))
        if tag in ("point", "vector"):
            return self.read_vector(el, a, what)
        value = self.need(el, a, "value")
        if tag == "float":
            try:
                return _warn_above_one(name, parse_float(value, what, el.loc), el.loc)
            except ValueError:
                raise scene_error(f"{what}: cannot parse '{value}' as a float", el.loc) from None
        if tag == "integer":
            try:
                n = int(value.strip())
            except ValueError:
                raise scene_error(f"{what}: cannot parse '{value}' as an integer",
                                  el.loc) from None
            if not -(1 << 31) <= n < 1 << 31:  # Mitsuba's properties hold 32-bit integers
                raise scene_error(f"{what}: {n} is out of range for an integer (from "
                                  f"{-(1 << 31)} to {(1 << 31) - 1}, as in Mitsuba)", el.loc)
            return n
        if tag == "boolean":
            v = value.strip().lower()
            if v not in ("true", "false"):
                raise scene_error(f"{what}: expected 'true' or 'false', got '{value}'", el.loc)
            return v == "true"
        if tag == "string":
            return value
        if tag in ("rgb", "spectrum") and _negative(value):
            # an angle (Mitsuba takes polarizer angles as spectra); a color rejects it later
            return Color.gray(parse_float(value, what, el.loc))
        if tag == "rgb":
            return _warn_above_one(name, parse_rgb(value, el.loc), el.loc)
        return _warn_above_one(name, parse_spectrum(value, el.loc, bounded=False), el.loc)

    def read_vector(self, el: Element, a: dict[str, str], what: str) -> np.ndarray:
        if "value" in a:
            if any(k in a for k in "xyz"):
                raise scene_error(f"{what}: give either 'value' or x/y/z, not both", el.loc)
            vals = parse_numbers(a["value"], what, el.loc)
            if len(vals) == 1:
                vals *= 3
            if len(vals) != 3:
                raise scene_error(f"{what}: expected 3 values, got {len(vals)}", el.loc)
            return np.array(vals)
        if not any(k in a for k in "xyz"):
            raise scene_error(f"{what}: give 'value' or x/y/z attributes", el.loc)
        return np.array([self.number(el, a, k, 0.0) for k in "xyz"])

    @staticmethod
    def number(el: Element, a: dict[str, str], key: str, default: float) -> float:
        if key not in a:
            return default
        try:
            return parse_float(a[key], f"<{el.tag}>: attribute {key}", el.loc)
        except ValueError:
            raise scene_error(f"<{el.tag}>: attribute {key}=\"{a[key]}\" is not a number",
                              el.loc) from None

    def read_transform(self, el: Element) -> np.ndarray:
        m = xf.identity()
        for op in el.children:
            if op.tag not in TRANSFORM_OPS:
                raise scene_error(f"<transform>: unknown operation <{op.tag}>; accepted: "
                                  f"{', '.join(TRANSFORM_OPS)}", op.loc)
            allowed = TRANSFORM_OPS[op.tag]
            for k in op.attrs:
                if k not in allowed:
                    raise scene_error(f"<{op.tag}>: unexpected attribute '{k}'; accepted: "
                                      f"{', '.join(allowed)}", op.loc)
            a = {k: self.substitute(v, op) for k, v in op.attrs.items()}
            t = self.transform_op(op, a)
            if not np.isfinite(t).all():  # an inf or nan number (a too large one overflows
                # float32 later, at the shape: meshes.py)
                raise scene_error(f"<{op.tag}>: a number is not finite", op.loc)
            m = t @ m
        return m

    def vec3(self, op: Element, a: dict[str, str], default: float) -> np.ndarray:
        if "value" in a:
            if any(k in a for k in "xyz"):
                raise scene_error(f"<{op.tag}>: give either 'value' or x/y/z, not both", op.loc)
            vals = parse_numbers(a["value"], f"<{op.tag}>", op.loc)
            if op.tag == "scale" and len(vals) == 1:
                vals *= 3
            if len(vals) != 3:
                raise scene_error(f"<{op.tag}>: 'value' needs 3 numbers, got {len(vals)}",
                                  op.loc)
            return np.array(vals)
        return np.array([self.number(op, a, k, default) for k in "xyz"])

    def transform_op(self, op: Element, a: dict[str, str]) -> np.ndarray:
        if op.tag == "translate":
            return xf.translate(self.vec3(op, a, 0.0))
        if op.tag == "scale":
            return xf.scale(self.vec3(op, a, 1.0))
        if op.tag == "rotate":
            axis = self.vec3(op, a, 0.0)
            if "angle" not in a:
                raise scene_error("<rotate>: missing the 'angle' attribute (degrees)", op.loc)
            if not np.any(axis):
                raise scene_error("<rotate>: the rotation axis is zero; give x, y and/or z",
                                  op.loc)
            angle = self.number(op, a, "angle", 0.0)
            if not math.isfinite(angle):
                raise scene_error(f"<rotate>: the angle must be finite, got {angle:g}", op.loc)
            return xf.rotate(axis, angle)
        if op.tag == "matrix":
            vals = parse_numbers(self.need(op, a, "value"), "<matrix>", op.loc)
            try:
                return xf.from_values(vals)
            except ValueError as e:
                raise scene_error(f"<matrix>: {e}", op.loc) from None
        pts = {}
        for k in ("origin", "target", "up"):
            if k in a:
                v = parse_numbers(a[k], f"<lookat {k}>", op.loc)
                if len(v) != 3:
                    raise scene_error(f"<lookat>: '{k}' needs 3 numbers, got {len(v)}", op.loc)
                pts[k] = v
            elif k != "up":
                raise scene_error(f"<lookat>: missing the '{k}' attribute", op.loc)
        try:
            return xf.look_at(pts["origin"], pts["target"], pts.get("up"))
        except ValueError as e:
            raise scene_error(f"<lookat>: {e}", op.loc) from None


def _warn_above_one(name: str, value: Any, loc: Loc) -> Any:
    """``value``, with a warning at its line when it is a reflectance or transmittance above 1
    (it makes light: Mitsuba renders it, as rdsl does, but it is rarely what was meant)."""
    if name.endswith(("reflectance", "transmittance")):
        vals = (value,) if isinstance(value, float) else (value.values or value.rgb)
        if max(vals) > 1.0:
            warnings.warn(f"{loc.file}:{loc.line}: {name} {max(vals):g} is above 1: the "
                          "surface gives back more light than it receives", stacklevel=2)
    return value


def _negative(text: str) -> bool:
    """Whether ``text`` is one finite negative number."""
    try:
        v = float(text)
    except ValueError:
        return False
    return math.isfinite(v) and v < 0


def read_scene(path: str | Path, defines: dict[str, Any] | None = None) -> SceneTree:
    """Parse a Mitsuba 3 scene file into a :class:`SceneTree`."""
    path = Path(path)
    if path.is_dir():
        raise scene_error(f"'{path}' is a folder; expected a Mitsuba 3 XML scene file",
                          file_loc(str(path)))
    if not path.is_file():
        raise scene_error(f"scene file '{path}' not found", file_loc(str(path)))
    r = _Reader(path, defines or {})
    root_el = parse_xml_file(path)
    r.include_stack.append(path.resolve())
    root = r.read_root(root_el, path)
    r.read_children(root, root_el)
    resolve_refs(r.refs, r.ids, root)
    unused = sorted(r.cli_names - r.used)
    return SceneTree(root, path, r.search_paths, r.params, unused, r.ids, r.include_paths)
