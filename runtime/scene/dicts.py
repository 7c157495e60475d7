"""Mitsuba 3's Python scene dictionaries (what ``mi.load_dict`` takes), as scene XML.

A dictionary is written out as the XML it stands for and loaded like any scene file, so it
gets every check, conversion and error message an XML scene gets:

- ``{"type": "scene", KEY: {...}, ...}``: each nested dict with a ``"type"`` is a plugin;
  its category (``bsdf``, ``shape``...) is found from the type, as Mitsuba's plugin
  registry does; a top-level key is the object's ``id`` unless it has an ``"id"``;
- ``{"type": "rgb", "value": [r, g, b]}``, ``{"type": "spectrum", "value": 0.5 or
  [(wavelength, value), ...]}``, ``{"type": "ref", "id": ...}``;
- numbers, booleans and strings; a list of 3 numbers is a point (or vector); a 4x4 array, or
  an object with a ``matrix`` (Mitsuba's ``ScalarTransform4f``, or :class:`Transform4f`),
  is a transform; a relative ``filename`` is resolved against the current folder, as
  Mitsuba does.

A mistake is an error naming the key path (``scene['floor']['bsdf']``): each element of the
XML ends with a comment naming its key, by which :func:`dict_error` turns an error the scene
loader reports at a line of the XML into one at the key.
"""

from __future__ import annotations

import difflib
import os
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any
from xml.sax.saxutils import quoteattr

import numpy as np

from . import transform as xf
from ...compiler.diagnostics import CompileError, Diagnostic, source_line
from .errors import SceneError, scene_error
from .spectrum_plugins import PLUGINS as SPECTRUM_PLUGINS

__all__ = ["Transform4f", "dict_error", "dict_to_xml"]


def _error(message: str) -> Exception:
    """A mistake in the dictionary (it has no file: the message names the key path)."""
    return scene_error(message, None)

_VALUE_TYPES = ("rgb", "spectrum", "ref")
_KEY = re.compile(r"^(?P<xml>.*?)\s*<!-- (?P<key>scene\[.*\]) -->$")


def _keyed(line: str, path: str) -> str:
    """An element's line with the comment naming its key path (``--`` cannot be in one)."""
    return f"{line}  <!-- {path.replace('--', '- -')} -->"


def dict_error(e: CompileError, xml: Path) -> CompileError:
    """``e`` with its diagnostics at lines of ``xml`` (what :func:`dict_to_xml` wrote) moved
    to the dictionary's keys: ``load_dict: scene['a']['bsdf']['alpha']: ...``; the user never
    wrote that file, so a line of it tells them nothing."""
    moved = []
    for d in e.diagnostics:
        line = source_line(d.loc.file, d.loc.line) if d.loc and d.loc.file == str(xml) else None
        m = _KEY.match(line.strip()) if line else None
        if m is None:
            moved.append(d)
            continue
        moved.append(Diagnostic(None, f"load_dict: {m['key']}: {d.message} (written as the "
                                      f"scene XML `{m['xml']}`)", d.severity))
    if all(a is b for a, b in zip(moved, e.diagnostics)):
        return e
    return SceneError(moved)


class _either:
    """A method that works on the class too (``Transform4f.look_at(...)``, Mitsuba's older
    API) and on an instance (``Transform4f().translate(...).scale(...)``, its newer one)."""

    def __init__(self, fn: Any) -> None:
        self.fn = fn

    def __get__(self, obj: Any, cls: type) -> Any:
        me = obj if obj is not None else cls()
        return lambda *a, **k: self.fn(me, *a, **k)


class Transform4f:
    """A 4x4 affine transform, built like Mitsuba's ``ScalarTransform4f``: each call returns
    this transform times the new one, so ``T.translate(t).scale(s)`` scales first, then
    translates, as in Mitsuba."""

    def __init__(self, matrix: Any = None) -> None:
        self.matrix = xf.identity() if matrix is None else np.asarray(matrix, np.float64)

    def _then(self, m: np.ndarray) -> Transform4f:
        return Transform4f(self.matrix @ m)

    @_either
    def translate(self, v: Any) -> Transform4f:
        return self._then(xf.translate(v))

    @_either
    def scale(self, v: Any) -> Transform4f:
        v = [v] * 3 if np.isscalar(v) else v
        return self._then(xf.scale(v))

    @_either
    def rotate(self, axis: Any, angle: float) -> Transform4f:
        return self._then(xf.rotate(axis, angle))

    @_either
    def look_at(self, origin: Any, target: Any, up: Any) -> Transform4f:
        return self._then(xf.look_at(origin, target, up))

    def __matmul__(self, other: Transform4f) -> Transform4f:
        return Transform4f(self.matrix @ np.asarray(getattr(other, "matrix", other)))


def _categories(plugins: Any) -> dict[str, str]:
    """Plugin type -> category: Mitsuba's schema, the stdlib's plugins, the user's."""
    from ..plugins import KINDS, stdlib_names
    from .schema import SCHEMA

    out = {t: c for (c, t) in SCHEMA}
    for kind in KINDS:
        for name in stdlib_names(kind):
            out.setdefault(name, kind)
        if plugins is not None:
            for name in plugins.user_names(kind):
                out.setdefault(name, kind)
    return out


def dict_to_xml(scene: Mapping[str, Any], registry: Any = None) -> str:
    """The scene XML of a Mitsuba 3 scene dictionary."""
    if not isinstance(scene, Mapping):
        raise _error(f"load_dict: expected a dict, got {type(scene).__name__}")
    if scene.get("type") != "scene":
        raise _error("load_dict: the outer dict must have \"type\": \"scene\" (got "
                          f"{scene.get('type')!r})")
    w = _Writer(_categories(registry))
    lines = ['<scene version="3.0.0">']
    for key, value in scene.items():
        if key != "type":
            lines += w.item(key, value, f"scene[{key!r}]", top=True, indent=1)
    lines.append("</scene>")
    return "\n".join(lines) + "\n"


_grid_dir: list[str] = []  # the folder of the .vol files made from `grid` arrays


def _grid_file(value: Any, path: str) -> str:
    """A ``.vol`` file holding the samples ``value`` (Mitsuba's tensor (z, y, x, 1)), which
    the sdfgrid reads as its ``filename``; it lasts as long as the process."""
    import atexit
    import shutil
    import tempfile

    from .sdfgrid import check_grid
    from .volgrid import write_vol

    try:
        grid = check_grid(np.asarray(value, np.float32), f"load_dict: {path}: the grid")
    except (TypeError, ValueError) as e:
        raise _error(str(e) if "load_dict" in str(e) else
                     f"load_dict: {path}: expected an array of numbers, got "
                     f"{type(value).__name__}") from None
    if not _grid_dir:
        _grid_dir.append(tempfile.mkdtemp(prefix="rdsl-sdfgrid-"))
        atexit.register(shutil.rmtree, _grid_dir[0], True)
    fd, name = tempfile.mkstemp(suffix=".vol", dir=_grid_dir[0])
    os.close(fd)
    write_vol(name, grid)
    return name


class _Writer:
    def __init__(self, categories: dict[str, str]) -> None:
        self.categories = categories

    def item(self, key: str, value: Any, path: str, top: bool = False,
             indent: int = 1) -> list[str]:
        if isinstance(value, Mapping):
            return self.mapping(key, value, path, top, indent)
        return [_keyed(line, path) for line in self.plain(key, value, path, indent)]

    def plain(self, key: str, value: Any, path: str, indent: int) -> list[str]:
        """A property that is not a dict: one line."""
        pad = "    " * indent
        if isinstance(value, bool):
            return [f'{pad}<boolean name={quoteattr(key)} value="{str(value).lower()}"/>']
        if isinstance(value, (int, np.integer)):
            return [f'{pad}<integer name={quoteattr(key)} value="{int(value)}"/>']
        if isinstance(value, (float, np.floating)):
            return [f'{pad}<float name={quoteattr(key)} value="{float(value)!r}"/>']
        if key == "grid" and not isinstance(value, (str, os.PathLike)):  # an sdfgrid's samples
            return [f'{pad}<string name="filename" value={quoteattr(_grid_file(value, path))}/>']
        if isinstance(value, (str, os.PathLike)):
            text = str(value)
            if key == "filename" and not Path(text).is_absolute():
                text = str(Path.cwd() / text)
            return [f'{pad}<string name={quoteattr(key)} value={quoteattr(text)}/>']
        matrix = getattr(value, "matrix", value)
        a = np.asarray(matrix, dtype=object if isinstance(matrix, str) else None)
        if a.dtype != object and a.shape == (4, 4):
            nums = " ".join(repr(float(x)) for x in a.astype(np.float64).reshape(-1))
            return [f'{pad}<transform name={quoteattr(key)}><matrix value="{nums}"/>'
                    '</transform>']
        if a.dtype != object and a.shape == (3,):
            x, y, z = (repr(float(v)) for v in a)
            return [f'{pad}<point name={quoteattr(key)} x="{x}" y="{y}" z="{z}"/>']
        raise _error(f"load_dict: {path}: cannot use a {type(value).__name__} "
                          f"({value!r:.60}) as a scene property")

    def mapping(self, key: str, value: Mapping[str, Any], path: str, top: bool,
                indent: int) -> list[str]:
        pad = "    " * indent
        ptype = value.get("type")
        if not isinstance(ptype, str):
            raise _error(f"load_dict: {path}: a nested dict needs a \"type\"")
        if ptype in _VALUE_TYPES:
            return [_keyed(pad + self.value(key, ptype, value, path), path)]
        if ptype in SPECTRUM_PLUGINS and not top:  # {"type": "blackbody", ...}
            return self.spectrum_plugin(key, ptype, value, path, indent)
        category = self.categories.get(ptype)
        if category is None:
            near = difflib.get_close_matches(ptype, list(self.categories), n=3)
            raise _error(f"load_dict: {path}: unknown plugin type {ptype!r}"
                         + (f" (did you mean {', '.join(map(repr, near))}?)" if near else "")
                         + "; user plugins are found in the current folder and in `plugins=`")
        ident = value.get("id", key if top else None)
        attrs = f" type={quoteattr(ptype)}"
        if ident is not None:
            attrs += f" id={quoteattr(str(ident))}"
        if not top and key != category:
            attrs += f" name={quoteattr(key)}"
        lines = [_keyed(f"{pad}<{category}{attrs}>", path)]
        for k, v in value.items():
            if k not in ("type", "id"):
                lines += self.item(k, v, f"{path}[{k!r}]", indent=indent + 1)
        lines.append(f"{pad}</{category}>")
        return lines

    def spectrum_plugin(self, key: str, ptype: str, value: Mapping[str, Any], path: str,
                        indent: int) -> list[str]:
        """One of Mitsuba's spectrum plugins (``<spectrum type=... name=...>``); an srgb
        ``color`` given as 3 numbers is an ``<rgb>``, a list of ``values`` or ``wavelengths``
        the comma-separated string Mitsuba's XML takes."""
        lines = [_keyed(f"{'    ' * indent}<spectrum type={quoteattr(ptype)} "
                        f"name={quoteattr(key)}>", path)]
        for k, v in value.items():
            if k == "type":
                continue
            if k == "color" and not isinstance(v, Mapping):
                v = {"type": "rgb", "value": v}
            elif k in ("values", "wavelengths") and not isinstance(v, str):
                v = ", ".join(repr(float(x)) for x in np.asarray(v, np.float64).reshape(-1))
            lines += self.item(k, v, f"{path}[{k!r}]", indent=indent + 1)
        lines.append(f"{'    ' * indent}</spectrum>")
        return lines

    @staticmethod
    def value(key: str, ptype: str, value: Mapping[str, Any], path: str) -> str:
        name = quoteattr(key)
        if ptype == "ref":
            if "id" not in value:
                raise _error(f"load_dict: {path}: a ref needs an \"id\"")
            return f"<ref name={name} id={quoteattr(str(value['id']))}/>"
        v = value.get("value")
        if ptype == "rgb":
            nums = np.asarray(v, np.float64).reshape(-1)
            if nums.size not in (1, 3):
                raise _error(f"load_dict: {path}: an rgb value has 1 or 3 numbers")
            return f"<rgb name={name} value=\"{', '.join(repr(float(x)) for x in nums)}\"/>"
        if "filename" in value:
            return f"<spectrum name={name} filename={quoteattr(str(value['filename']))}/>"
        if isinstance(v, (int, float)):
            return f'<spectrum name={name} value="{float(v)!r}"/>'
        try:
            pairs = ", ".join(f"{float(wl)!r}:{float(x)!r}" for wl, x in v)
        except (TypeError, ValueError):
            raise _error(f"load_dict: {path}: a spectrum value is a number or "
                              "(wavelength, value) pairs") from None
        return f'<spectrum name={name} value="{pairs}"/>'
