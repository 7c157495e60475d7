"""The plugin registry: which ``.rdsl`` file declares the BSDF, texture, emitter or integrator a scene
names with ``type="NAME"``, and that declaration's ``param``s.

A scene's plugin is looked up, in order, in: the scene file's folder, the folders given to
``load_scene(plugins=...)`` / ``rdsl render --plugins DIR`` (or a plugin file given there),
the folders of ``$RDSL_PLUGIN_PATH`` (``os.pathsep``-separated), the files registered with
:func:`register_plugin`, then the stdlib (``stdlib/bsdf``, ``stdlib/texture``,
``stdlib/emitter``, ``stdlib/integrator``).  The first place that declares it wins; a plugin it shadows is named in
a warning, and two files of one folder declaring the same name are an error naming both.

Finding is cheap: the top-level ``*.rdsl`` files of a folder are indexed with a regular
expression over ``bsdf|texture|emitter|integrator NAME {`` lines; only the files a scene uses are
parsed and checked by the compiler (:meth:`PluginDecl.params`), so a syntax error or a
missing interface function is the compiler's diagnostic at its own line.

The render kernel imports a stdlib plugin by its path under ``stdlib/`` (``import
bsdf.diffuse;``) and a user plugin by its file's name (``import velvet;`` for
``velvet.rdsl``), with the plugin's folder among the compiler's search paths
(:func:`kernel_imports`).
"""

from __future__ import annotations

import hashlib
import os
import re
import warnings
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path
from typing import Any

from ..compiler.diagnostics import CompileError
from ..compiler.ir import Loc
from ..compiler.sources import is_path

KINDS = ("bsdf", "texture", "emitter", "integrator")
STDLIB = Path(__file__).resolve().parents[1] / "stdlib"
ENV = "RDSL_PLUGIN_PATH"
# stdlib plugins the renderer instantiates itself, never a scene (a tree of combinators is one
# `mixture`); written as `{name}_{method}_buffers` functions rather than a `bsdf` block, so
# found by their file
INTERNAL = {"mixture": "bsdf/mixture.rdsl", "perturbed": "bsdf/perturbed.rdsl"}
# a declaration's line, `bsdf NAME {`, its brace there or on a later line (Allman style)
_DECL = re.compile(r"^[ \t]*(bsdf|texture|emitter|integrator)[ \t]+([A-Za-z_]\w*)\s*\{",
                   re.MULTILINE)
# the language's keywords (dsl/parser.py): a file named like one cannot be imported
_KEYWORDS = frozenset({"import", "struct", "fn", "param", "let", "var", "if", "else", "const",
                       "for", "in", "while", "break", "continue", "return", "true", "false"})


@dataclass(frozen=True)
class ParamDecl:
    """One ``param`` of a plugin: its rdsl type name, default (a Python value; None: the
    scene must set it) and where it is declared."""

    name: str
    type: str
    default: Any
    loc: Loc

    @property
    def where(self) -> str:
        return f"{self.loc.file}:{self.loc.line}"


@dataclass(eq=False)
class PluginDecl:
    """A plugin declaration found in a file: ``kind name`` at ``path:line``."""

    kind: str
    name: str
    path: Path
    line: int
    stdlib: bool = False
    _checked: Checked | None = field(default=None, repr=False)

    @property
    def where(self) -> str:
        return f"{self.path}:{self.line}"

    @property
    def import_name(self) -> str:
        """How the kernel imports the file (``bsdf.diffuse``, ``velvet``)."""
        if self.stdlib:
            return ".".join(self.path.resolve().relative_to(STDLIB).with_suffix("").parts)
        return self.path.stem

    def params(self) -> dict[str, ParamDecl]:
        """The declared params, in order (the file is parsed and checked on first use)."""
        return self._check()[0]

    def has_fn(self, name: str) -> bool:
        return name in self._check()[1]

    def signature(self, name: str) -> tuple[tuple[Any, ...], Any]:
        """The IR parameter types and result type of the plugin's function ``name``."""
        return self._check()[1][name]

    def _check(self) -> Checked:
        if self._checked is None:
            self._checked = _checked(self.path.resolve(), self.kind, self.name, self.line,
                                     self.path.stat().st_mtime_ns)
        return self._checked


def declared_params(plugin: Any) -> list[ParamDecl]:
    """The ``param``s of a checked plugin (a ``dsl`` checker's plugin), in order."""
    from ..dsl.types import type_name

    return [ParamDecl(s.name, type_name(s.type), d, s.loc)
            for s, d in zip(plugin.params, plugin.defaults)]


Checked = tuple[dict[str, ParamDecl], dict[str, tuple[tuple[Any, ...], Any]]]


@cache
def _checked(path: Path, kind: str, name: str, line: int, mtime: int) -> Checked:
    """The params and functions (parameter and result types) of plugin ``name`` of
    ``path``, which the compiler's frontend checks (its diagnostics point into the file).
    ``mtime`` keys this process's cache, so an edited file is read again; on disk
    (``<cache>/signatures/``) the entry is keyed by the texts of the file and of all it
    imports, so a process rendering a scene whose kernels are cached checks nothing (the
    check was 0.2 s of such a render)."""
    import pickle

    from ..core.cachedir import cache_dir, write_atomically

    entry = cache_dir() / "signatures" / f"{_signature_key(path, kind, name, line)}.pickle"
    try:
        return pickle.loads(entry.read_bytes())
    except Exception:  # noqa: BLE001 - none yet, or a damaged entry: check the file
        pass
    got = _check_file(path, kind, name, line)
    write_atomically(entry, lambda f: pickle.dump(got, f, protocol=pickle.HIGHEST_PROTOCOL))
    return got


def _signature_key(path: Path, kind: str, name: str, line: int) -> str:
    """What a plugin's signature depends on: the compiler, the plugin and the texts (and
    places) of the file and everything it imports."""
    from .. import __version__
    from ..compiler.sources import source_files
    from ..core.cachedir import compiler_fingerprint

    h = hashlib.sha256()
    parts = [__version__, compiler_fingerprint(), kind, name, str(line)]
    for f in source_files(path):
        parts += [str(f), f.read_text(errors="replace")]
    for part in parts:
        b = part.encode()
        h.update(f"{len(b)}:".encode() + b)
    return h.hexdigest()


def _check_file(path: Path, kind: str, name: str, line: int) -> Checked:
    from ..core.gcpause import gc_paused
    from ..dsl import check

    with gc_paused():
        prog = check(path)
    try:
        for pl in prog.plugins:
            if pl.name == name and pl.module.key == str(path):
                fns = {n: (tuple(f.param_types), f.ret) for n, f in pl.fns.items()}
                return {q.name: q for q in declared_params(pl)}, fns
    finally:
        prog.release()  # freed now, not by the cycle collector (see its docstring)
    raise CompileError(f"`{kind} {name}` seems declared here, but the file declares no such "
                       "plugin (is the line inside a comment?)", Loc(str(path), line, 1))


def index_file(path: Path, stdlib: bool = False) -> list[PluginDecl]:
    """The plugin declarations of one file, found by a regular expression (cheap: no
    parsing)."""
    try:
        text = path.read_text(errors="replace")
    except OSError as e:
        raise CompileError(f"cannot read plugin file `{path}`: {e.strerror or e}") from None
    return [PluginDecl(m.group(1), m.group(2), path, text.count("\n", 0, m.start()) + 1, stdlib)
            for m in _DECL.finditer(text)]


def index_folder(folder: Path, stdlib: bool = False) -> dict[tuple[str, str], list[PluginDecl]]:
    """(kind, name) -> the declarations of the folder's top-level ``.rdsl`` files."""
    out: dict[tuple[str, str], list[PluginDecl]] = {}
    for path in sorted(folder.glob("*.rdsl")):
        for d in index_file(path, stdlib):
            out.setdefault((d.kind, d.name), []).append(d)
    return out


@cache
def _stdlib_index() -> dict[tuple[str, str], list[PluginDecl]]:
    out: dict[tuple[str, str], list[PluginDecl]] = {}
    for kind in KINDS:
        for key, decls in index_folder(STDLIB / kind, stdlib=True).items():
            out.setdefault(key, []).extend(decls)
    return out


def stdlib_plugin(kind: str, name: str) -> PluginDecl | None:
    """The stdlib's plugin ``kind name`` (``mixture`` included), or None."""
    decls = _stdlib_index().get((kind, name))
    if not decls and name in INTERNAL and INTERNAL[name].startswith(f"{kind}/"):
        return PluginDecl(kind, name, STDLIB / INTERNAL[name], 1, stdlib=True)
    return decls[0] if decls else None


# files registered with register_plugin, newest first
_REGISTERED: list[Path] = []


def register_plugin(path_or_source: str | os.PathLike) -> list[str]:
    """Make the plugins of a ``.rdsl`` file (a path, or source text) available to every
    scene loaded afterwards in this process, after the scene's folder and plugin folders and
    before the stdlib.  Source text is written to the kernel cache (``plugins/<hash>/``), so
    its diagnostics name that file.  Each plugin is checked now: a mistake in it is a
    :class:`CompileError` here.  Registering a plugin again (an edited file, say) replaces
    the earlier registration of that name.  Returns the names of the file's plugins."""
    if is_path(path_or_source):
        path = Path(path_or_source).resolve()
        if not path.is_file():
            raise CompileError(f"cannot register plugin `{path}`: no such file")
    else:
        path = _write_source(str(path_or_source))
    decls = index_file(path)
    if not decls:
        raise CompileError(f"`{path}` declares no plugin (expected `bsdf NAME {{`, "
                           "`texture NAME {` or `emitter NAME {`)", Loc(str(path), 0, 0))
    for d in decls:
        d.params()
    names = {(d.kind, d.name) for d in decls}
    for other in list(_REGISTERED):
        if other == path or names & {(d.kind, d.name) for d in index_file(other)}:
            _REGISTERED.remove(other)
    _REGISTERED.insert(0, path)
    return [d.name for d in decls]


def _write_source(text: str) -> Path:
    from .cache import cache_dir

    decls = _DECL.search(text)
    if decls is None:
        raise CompileError("the registered source declares no plugin (expected `bsdf NAME {`, "
                           "`texture NAME {` or `emitter NAME {`)")
    # (the key's prefix: a folder of the earlier naming may hold a `frame.rdsl`)
    key = hashlib.sha256(b"named-v2\0" + text.encode()).hexdigest()[:16]
    folder = cache_dir() / "plugins" / key
    # named after the plugin, unless that name is a stdlib module's (`frame`): the file
    # would hide it from its own imports
    stem = decls.group(2)
    path = folder / f"{stem}{'_plugin' if (STDLIB / f'{stem}.rdsl').is_file() else ''}.rdsl"
    try:
        folder.mkdir(parents=True, exist_ok=True)
        if not path.is_file() or path.read_text() != text:
            path.write_text(text)
    except OSError as e:
        raise CompileError(f"cannot write the registered plugin to `{path}`: "
                           f"{e.strerror or e} (set $RDSL_CACHE_DIR)") from None
    return path


def env_folders() -> list[Path]:
    """The folders of ``$RDSL_PLUGIN_PATH``."""
    return [Path(p) for p in os.environ.get(ENV, "").split(os.pathsep) if p]


class PluginRegistry:
    """The plugins one scene may use: its search places, in order, then the stdlib."""

    def __init__(self, places: Sequence[Path] = ()) -> None:
        # each place is a folder or a single plugin file, indexed on first lookup
        self.places = [Path(p) for p in places]
        self._index: dict[Path, dict[tuple[str, str], list[PluginDecl]]] = {}

    @classmethod
    def for_scene(cls, scene: str | os.PathLike | None,
                  plugins: Iterable[str | os.PathLike] = ()) -> PluginRegistry:
        """The search places of a scene file: its folder, ``plugins`` (folders or files),
        ``$RDSL_PLUGIN_PATH``, the registered files (the stdlib is always last)."""
        places = [Path(scene).resolve().parent] if scene is not None else []
        for p in [*plugins, *env_folders()]:
            path = Path(p).expanduser()
            if not path.exists():
                raise CompileError(f"plugin folder `{path}` does not exist")
            places.append(path.resolve())
        places += _REGISTERED
        unique: list[Path] = []
        for p in places:
            if p not in unique:
                unique.append(p)
        return cls(unique)

    def _place(self, place: Path) -> dict[tuple[str, str], list[PluginDecl]]:
        if place not in self._index:
            if place.is_dir():
                self._index[place] = index_folder(place)
            else:
                self._index[place] = {}
                for d in index_file(place):
                    self._index[place].setdefault((d.kind, d.name), []).append(d)
        return self._index[place]

    def candidates(self, kind: str, name: str) -> list[PluginDecl]:
        """Every declaration of ``kind name`` in search order (one per place), the stdlib's
        last; two in one place are an error naming both files."""
        out = []
        for place in self.places:
            decls = self._place(place).get((kind, name), [])
            if len(decls) > 1:
                a, b = decls[0], decls[1]
                raise CompileError(f"two {kind} plugins named `{name}` in `{place}`: {a.where} "
                                   f"and {b.where}; rename or remove one",
                                   Loc(str(b.path), b.line, 1))
            out += decls
        std = stdlib_plugin(kind, name)
        if std is not None:
            out.append(std)
        return out

    def lookup(self, kind: str, name: str, builtin: str | None = None) -> PluginDecl | None:
        """The plugin ``kind name`` the scene means, or None.  A user plugin shadowing
        another (or the stdlib's, or ``builtin``: a stdlib plugin the loader knows without
        a declaration, such as the ``point`` emitter) gets a warning naming both."""
        found = self.candidates(kind, name)
        if not found:
            return None
        first = found[0]
        shadowed = [d.where for d in found[1:]]
        if builtin is not None and not first.stdlib and not any(d.stdlib for d in found):
            shadowed.append(builtin)
        if shadowed and not first.stdlib:
            warnings.warn(f"{first.where}: warning: {kind} plugin `{name}` shadows the one at "
                          f"{', '.join(shadowed)}", stacklevel=3)
        return first

    def user_names(self, kind: str) -> list[str]:
        """The names of the user plugins of ``kind`` in the search places."""
        return sorted({n for p in self.places for (k, n) in self._place(p) if k == kind})


def stdlib_names(kind: str) -> list[str]:
    """The stdlib's plugins of ``kind`` a scene may name (``mixture`` is internal)."""
    return sorted(n for (k, n) in _stdlib_index() if k == kind and n not in INTERNAL)


def kernel_imports(decls: Iterable[PluginDecl], kernel_dir: Path) -> tuple[list[str], list[Path]]:
    """The import names of ``decls`` and the search paths that make them resolve, for a
    kernel compiled as if it were a file of ``kernel_dir`` (the scene's folder).  A user
    plugin's file must be importable by its name, and be the file that name finds."""
    names: list[str] = []
    paths: list[Path] = []
    users = [d for d in decls if not d.stdlib]
    for d in users:
        folder = d.path.resolve().parent
        if folder not in paths and folder != kernel_dir.resolve():
            paths.append(folder)
    for d in decls:
        name = d.import_name
        if not d.stdlib:
            if not name.isidentifier() or name in _KEYWORDS:
                raise CompileError(f"the plugin file `{d.path.name}` cannot be imported: its "
                                   "name (without .rdsl) must be an identifier that is not a "
                                   "keyword; rename the file", Loc(str(d.path), d.line, 1))
            found = next((f / f"{name}.rdsl" for f in [kernel_dir, *paths]
                          if (f / f"{name}.rdsl").is_file()), None)
            if found is None or found.resolve() != d.path.resolve():
                raise CompileError(f"{d.kind} `{d.name}` ({d.where}) cannot be imported as "
                                   f"`{name}`: `{found}` has the same file name and comes "
                                   "first; rename one of the files",
                                   Loc(str(d.path), d.line, 1))
        if name not in names:
            names.append(name)
    return names, paths


# a user plugin param's rdsl type -> the XML values it takes (runtime/scene/schema.py kinds);
# a Float may be a texture (its one-value lookup, eval_1), a texture's own params included
# (textures nest: runtime/render/textures.py)
_PARAM_KINDS = {"Float": "ftex", "Int": "integer", "UInt": "integer", "UInt64": "integer",
                "Bool": "boolean", "Spectrum": "spectrum", "Texture": "color", "Vec3": "vec3"}
UV_ROWS = ("to_u", "to_v")  # a texture's `to_uv` transform, as stdlib/texture/common.rdsl


def declared_spec(decl: PluginDecl) -> Any:
    """The scene schema of a plugin made from its ``param`` declarations: each param by
    name, with the XML values its type takes; one without a default is required.  A texture
    declaring ``to_u``/``to_v`` (Vec3) takes Mitsuba's ``to_uv`` transform instead."""
    from .scene.schema import REQUIRED, Param, PluginSpec

    params = {p.name: Param(_PARAM_KINDS.get(p.type, "unset"),
                            REQUIRED if p.default is None else None, None, p.type, p.where)
              for p in decl.params().values()}
    if decl.kind == "texture" and all(params.get(r, Param("")).rdsl_type == "Vec3"
                                      for r in UV_ROWS):
        rows = [params.pop(r) for r in UV_ROWS]
        params["to_uv"] = Param("transform", None, None, "Vec3 rows to_u, to_v", rows[0].decl)
    # an integrator may wrap one nested integrator (when its `sample` takes `nested`)
    children = {"integrator": (0, 1)} if decl.kind == "integrator" else {}
    return PluginSpec(decl.kind, decl.name, params, children, decl)


def scene_spec(registry: PluginRegistry, category: str, ptype: str) -> Any:
    """The schema of ``<category type="ptype">``: a user plugin's declared one, else
    Mitsuba's (runtime/scene/schema.py) for the stdlib plugins it describes, else a stdlib
    plugin's declared one; None if no plugin has that name."""
    from .scene.schema import spec_for

    schema = spec_for(category, ptype)
    if category not in KINDS:
        return schema
    std = stdlib_plugin(category, ptype)
    builtin = None
    if schema is not None and std is None:  # e.g. the `point` emitter: functions, no plugin
        f = STDLIB / category / f"{ptype}.rdsl"
        builtin = str(f) if f.is_file() else f"the built-in {category} `{ptype}`"
    if (schema is not None and schema.children) or ptype in INTERNAL:
        # a combinator's name cannot be taken (an error, so no warning that it is shadowed)
        user = next((d for d in registry.candidates(category, ptype) if not d.stdlib), None)
        if user is not None:
            raise CompileError(f"`{ptype}` is the name of one of rdsl's built-in {category} "
                               "combinators; rename this plugin", Loc(str(user.path), user.line,
                                                                      1))
    decl = registry.lookup(category, ptype, builtin)
    if decl is not None and not decl.stdlib:
        return declared_spec(decl)
    if schema is not None:
        return schema
    if decl is not None and ptype not in INTERNAL:
        return declared_spec(decl)
    return None
