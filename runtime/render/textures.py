"""A scene's textures for the kernels: instances for the ``specialize`` pass and one texel
buffer.

A texture that sets a BSDF parameter becomes a :class:`TextureRef` in that BSDF's instance;
the texture itself is an :class:`Instance` of the stdlib plugin (``stdlib/texture/``) or of
a user's texture plugin (its params as declared: runtime/render/declared.py).  The
texels of every bitmap are concatenated into ``T`` (3 float32 per texel, rows top to bottom),
each bitmap's offset, width and height being constants of its instance.  A texture that
sets a colour stores them as the variant stores colours (runtime/render/colors.py); one that
sets a Float parameter (``alpha``...) is a separate instance whose texels stay linear RGB,
which its ``eval_1`` reads (Mitsuba's single-channel lookup: their luminance; a checkerboard's
colours give the one value of Mitsuba's ``srgb`` texture, ``srgb_eval_1``), and one that
sets emitted light (an area emitter's ``radiance``) another, refusing the kinds that cannot
emit yet, whose lookups are reflectance-like colours as Mitsuba's ``texture_d65`` passes a
texture through: spectral builds upsample its colours (clamped to [0, 1], as
``srgb_model_fetch``) without D65, unlike a constant emitted colour.
A ``volume`` texture's voxels are stored as a bitmap's texels, x fastest, then y, then z
(runtime/scene/volumes.py reads them; ``stdlib/texture/volume.rdsl`` looks them up).
Lookups, filtering and wrapping happen in rdsl (``stdlib/texture/bitmap.rdsl``); Python only
decodes the images, as Mitsuba does when it loads them: 8-bit (and 16-bit) PNG and JPEG
images are sRGB-encoded and are linearized unless ``raw`` is set, EXR images are linear.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from ...compiler.diagnostics import CompileError
from ...core.color import RGB, ColorModel
from ...core.scene_spec import Instance, SpectrumValue, TextureRef
from ...core.spectral import srgb_model_mean
from ..plugins import stdlib_names
from ..scene.mesh_attributes import attribute_textures
from ..scene.reads import memoized
from ..scene.volumes import volume_grid
from .colors import encode_texels, spectrum_value
from .declared import declared_instance, needs_eval_1

# numbering of stdlib/texture/bitmap.rdsl (filter_bilinear() ... wrap_clamp())
BITMAP_FILTERS = {"bilinear": 0, "nearest": 1}
BITMAP_WRAPS = {"repeat": 0, "mirror": 1, "clamp": 2}
# what a texture may set: a colour (a reflectance), a Float parameter (its eval_1), or
# emitted light (an area emitter's radiance: stored as a colour, as Mitsuba's texture_d65
# passes a texture through; only the kinds that cannot emit yet are refused)
USAGES = ("colour", "scalar", "emitted")


def srgb_to_linear(x: np.ndarray) -> np.ndarray:
    """The inverse of the sRGB transfer function, for values in [0, 1]."""
    x = np.asarray(x, np.float64)
    return np.where(x <= 0.04045, x / 12.92, np.power((x + 0.055) / 1.055, 2.4))


def _pillow() -> Any:
    try:
        from PIL import Image
    except ImportError:
        raise RuntimeError("reading PNG and JPEG textures needs Pillow "
                           "(pip install 'pillow>=10,<14')") from None
    return Image


def load_bitmap(path: str | Path, raw: bool = False) -> np.ndarray:
    """An image file as linear RGB float32 of shape (H, W, 3), row 0 at the top.  Grey
    images are broadcast to RGB and alpha is dropped.  A scene reload reuses the array of
    an unchanged file (runtime/scene/reads.py): callers must not modify it."""
    return memoized(path, ("bitmap", raw), lambda: _read_bitmap(Path(path), raw))


def _read_bitmap(path: Path, raw: bool) -> np.ndarray:
    suffix = path.suffix.lower()
    if suffix == ".exr":
        from .image import read_exr

        a = read_exr(path)
    elif suffix in (".hdr", ".rgbe", ".pfm"):  # linear, as EXR
        from .float_images import read_pfm, read_rgbe

        a = read_pfm(path) if suffix == ".pfm" else read_rgbe(path)
    else:
        Image = _pillow()
        with Image.open(path) as im:
            if im.mode in ("I;16", "I;16B", "I;16L", "I"):
                a = np.asarray(im, np.float64) / 65535.0
            elif im.mode == "F":  # float samples are linear already
                a, raw = np.asarray(im, np.float64), True
            elif im.mode in ("1", "L", "LA", "La"):
                a = np.asarray(im.convert("L"), np.float64) / 255.0
            else:
                a = np.asarray(im.convert("RGB"), np.float64) / 255.0
        if not raw:
            a = srgb_to_linear(a)
    a = np.asarray(a, np.float32)
    if a.ndim == 2:
        a = a[:, :, None]
    a = a[:, :, :3] if a.shape[2] >= 3 else np.repeat(a[:, :, :1], 3, axis=2)
    return np.ascontiguousarray(a, np.float32)


def _uv_rows(m: Any) -> dict[str, tuple[float, ...]]:
    """``to_uv`` (4x4) as the rows of its 2-D affine part (Mitsuba's ``extract()``)."""
    m = np.asarray(m, np.float64)
    return {"to_u": (m[0, 0], m[0, 1], m[0, 3]), "to_v": (m[1, 0], m[1, 1], m[1, 3])}


class TextureTable:
    """The scene's texture instances and the texel buffer ``T``, filled as BSDFs name
    their textures (one instance per texture object, one copy of each image file)."""

    def __init__(self) -> None:
        self.instances: list[Instance] = []
        # (id(plugin), usage) -> (plugin, index)
        self._ids: dict[tuple[int, str], tuple[Any, int]] = {}
        self._building: set[tuple[int, str]] = set()  # keys of instances being built
        # (path, raw, usage) -> (offset, width, height, mean, scale)
        self._images: dict[tuple[str, bool, str], tuple[int, int, int, Any, float]] = {}
        self._texels: list[tuple[np.ndarray, bool]] = []  # (texels, encoded as a colour)
        self._count = 0
        self._attributes: list[tuple[Instance, Any, str]] = []  # mesh_attribute instances
        self._tables: dict[Any, int] = {}  # key -> index in T of a BSDF's table (floats())
        self._volumes: dict[tuple[int, str], int] = {}  # (id(volume), usage) -> offset
        self.owner: str | None = None  # the name of what references textures now (owned_by)

    @contextlib.contextmanager
    def owned_by(self, name: str) -> Iterator[None]:
        """Textures without an id referenced in this block are named after ``name`` and
        the parameter they set (``<bsdf>.reflectance``), as Mitsuba's ``mi.traverse`` names
        them; a texture nested in one after it (``<bsdf>.reflectance.color0``)."""
        old, self.owner = self.owner, name
        try:
            yield
        finally:
            self.owner = old

    def _name(self, plugin: Any, what: str, nested: bool) -> str:
        """The instance name of texture ``plugin`` setting ``what``: its id; else, nested
        in a texture, ``what`` itself (that texture's name and the colour's key); else the
        owner's name and the parameter (``what`` is ``<plugin type>.<param>``); else, with
        no owner (an emitter plugin's), its type."""
        if plugin.id:
            return plugin.id
        if nested:  # ``what`` is the enclosing texture's name and the colour's key
            return what
        if self.owner and "." in what:
            return f"{self.owner}.{what.split('.', 1)[1]}"
        return plugin.type

    def fill_attributes(self, meshes: list[tuple[int, Any, Any]]) -> None:
        """Store the values of the mesh_attribute textures for ``meshes``, (first triangle,
        mesh, BSDF) each, where their BSDFs read them: a face attribute's value per
        triangle, a vertex attribute's values at each triangle's three corners (the
        kernels interpolate them), over the triangles from the first mesh to the last."""
        for inst, plugin, usage in self._attributes:
            name, face = plugin.params["name"], inst.params["face"]
            users = [(first, m) for first, m, bsdf in meshes
                     if any(t is plugin for t in attribute_textures(bsdf))]
            if not users:
                continue
            lo = min(first for first, _ in users)
            hi = max(first + len(m.faces) for first, m in users)
            per = 1 if face else 3
            values = np.zeros(((hi - lo) * per, 3), np.float32)
            for first, m in users:
                a = np.asarray(m.attributes[name], np.float32)
                a = np.repeat(a, 3, axis=1) if a.shape[1] == 1 else a
                rows = a if face else a[m.faces.astype(np.int64)].reshape(-1, 3)
                values[(first - lo) * per:(first - lo) * per + len(rows)] = rows
            values *= np.float32(plugin.params["scale"])
            inst.params.update(offset=self._count, first=lo, count=hi - lo)
            self._texels.append((values.reshape(-1), usage != "scalar"))
            self._count += len(values)

    def floats(self, key: Any, values: np.ndarray) -> int:
        """The index in ``T`` of raw float32 ``values`` (a BSDF's table), stored once per
        ``key``; padded to whole texels so that later offsets stay in texels."""
        if key not in self._tables:
            v = np.asarray(values, np.float32).reshape(-1)
            v = np.concatenate([v, np.zeros(-len(v) % 3, np.float32)])
            self._tables[key] = 3 * self._count
            self._texels.append((v, False))
            self._count += len(v) // 3
        return self._tables[key]

    def ref(self, plugin: Any, what: str, usage: str = "colour") -> TextureRef:
        """The reference for texture ``plugin`` setting ``what``, a parameter of ``usage``
        (one of :data:`USAGES`): each usage is an instance of its own, with its own texels."""
        assert usage in USAGES, usage
        key = (id(plugin), usage)
        if usage == "scalar":
            needs_eval_1(plugin, what)
        if key in self._building:  # the loader rejects <ref> cycles; this is a safeguard
            raise CompileError(f"{what}: texture `{plugin.id or plugin.type}` contains "
                               "itself (a cycle of textures)", plugin.loc)
        if key not in self._ids:
            # the index is taken before the instance is built: its nested textures (a
            # checkerboard's colours) are appended after it
            k = len(self.instances)
            self._ids[key] = (plugin, k)
            self.instances.append(Instance(plugin.type))
            name = self._name(plugin, what, bool(self._building))
            self._building.add(key)
            try:
                self.instances[k] = self._instance(plugin, what, usage, name)
            finally:
                self._building.discard(key)
        return TextureRef(self._ids[key][1])

    def buffer(self, model: ColorModel = RGB) -> np.ndarray:
        """``T``: every bitmap's texels, those of colour textures as ``model`` stores
        colours (never empty, so the kernels get a valid pointer)."""
        if not self._texels:
            return np.zeros(3, np.float32)
        return np.ascontiguousarray(np.concatenate(
            [encode_texels(t, model) if colour else t for t, colour in self._texels]),
            np.float32)

    def _instance(self, plugin: Any, what: str, usage: str, name: str) -> Instance:
        p = plugin.params
        emitted = usage == "emitted"
        if getattr(plugin, "decl", None) is not None:  # its textures are nested ones
            # a texture's constant colours are reflectances wherever it is used
            return declared_instance(plugin, self, illuminant=False)
        if plugin.type == "mesh_attribute":  # its values: fill_attributes(), once meshes are
            if emitted:
                raise CompileError(f"{what}: a mesh_attribute texture cannot set emitted "
                                   "light yet", plugin.loc)
            inst = Instance(plugin.type, {"offset": 0, "first": 0, "count": 0,
                                          "face": p["name"].startswith("face_")}, name)
            self._attributes.append((inst, plugin, usage))
            return inst
        if plugin.type == "volume":
            if emitted:
                raise CompileError(f"{what}: a volume texture cannot set emitted light yet",
                                   plugin.loc)
            return Instance(plugin.type, self._volume(plugin, usage), name)
        if plugin.type not in ("bitmap", "checkerboard"):
            raise CompileError(f"{what}: texture `{plugin.type}` is not supported by the "
                               f"renderer yet (supported: {', '.join(stdlib_names('texture'))})",
                               plugin.loc)
        params: dict[str, Any] = _uv_rows(p["to_uv"])
        if plugin.type == "checkerboard":
            for c in ("color0", "color1"):
                params.update(self._colour(p[c], f"{name}.{c}", c[-1], usage, plugin.loc))
        else:
            offset, w, h, mean, scale = self._image(p["filename"], bool(p["raw"]), plugin,
                                                    usage)
            params.update(offset=offset, width=w, height=h,
                          average=SpectrumValue(mean, None, False),
                          filter=BITMAP_FILTERS[p["filter_type"]],
                          wrap=BITMAP_WRAPS[p["wrap_mode"]], emitted=False, scale=scale)
        return Instance(plugin.type, params, name)

    def _colour(self, value: Any, what: str, n: str, usage: str, loc: Any
                ) -> dict[str, Any]:
        """A checkerboard's colour ``n`` ("0" or "1"): a constant (its value, and for
        ``eval_1`` its linear sRGB and spectral mean), or a nested texture, evaluated at the
        same surface point as Mitsuba's (its own ``to_uv``, not composed with the outer's):
        a reference for ``eval`` in the colour usages, ``value{n}`` for ``eval_1``."""
        if getattr(value, "category", None) == "texture":
            if usage == "scalar":
                return {f"nested{n}": True, f"value{n}": self.ref(value, what, usage)}
            return {f"color{n}": self.ref(value, what, usage)}
        rgb = getattr(value, "rgb", None)
        if rgb is None:
            got = getattr(value, "category", type(value).__name__)
            raise CompileError(f"{what}: expected a colour (float, rgb or spectrum) or a "
                               f"texture, got {got}", loc)
        return {f"color{n}": spectrum_value(value, what, loc=loc),
                f"rgb{n}": tuple(float(x) for x in rgb),
                f"spectral_mean{n}": float(srgb_model_mean(rgb))}

    def _volume(self, plugin: Any, usage: str) -> dict[str, Any]:
        """A volume texture's params, its voxels stored (once per volume and usage)."""
        vol = plugin.children[0]
        grid, to_world = volume_grid(vol)
        key = (id(vol), usage)
        if key not in self._volumes:
            self._volumes[key] = self._count
            self._texels.append((grid.reshape(-1), usage != "scalar"))
            self._count += grid.shape[0] * grid.shape[1] * grid.shape[2]
        rows = np.linalg.inv(to_world)[:3]
        p = vol.params
        nearest = vol.type == "gridvolume" and p["filter_type"] == "nearest"
        mean = tuple(float(x) for x in grid.reshape(-1, 3).mean(axis=0))
        return {"offset": self._volumes[key], "nx": grid.shape[2], "ny": grid.shape[1],
                "nz": grid.shape[0], "filter": BITMAP_FILTERS["nearest" if nearest else
                                                             "bilinear"],
                "wrap": BITMAP_WRAPS[p["wrap_mode"] if vol.type == "gridvolume" else "clamp"],
                **{f"r{i}": tuple(float(x) for x in rows[i]) for i in range(3)},
                "average": SpectrumValue(mean, None, False),
                "constant": vol.type == "constvolume", "rgb": mean,
                "spectral_mean": float(srgb_model_mean(mean))}

    def _image(self, filename: str, raw: bool, plugin: Any, usage: str
               ) -> tuple[int, int, int, tuple[float, float, float], float]:
        """The image's place in ``T``, its mean and the scale its texels were divided by
        (1: emitted light is stored as a colour, as Mitsuba's bitmap stores it wherever it
        is used; spectral builds clamp its texels to [0, 1] when they fit coefficients)."""
        key = (str(Path(filename).resolve()), raw, "scalar" if usage == "scalar" else "colour")
        if key not in self._images:
            try:
                img = load_bitmap(filename, raw)
            except (OSError, ValueError, SyntaxError) as e:
                raise CompileError(f"bitmap: cannot load '{filename}': {e}",
                                   plugin.loc) from None
            h, w = img.shape[:2]
            mean = tuple(float(x) for x in img.reshape(-1, 3).mean(axis=0))
            self._images[key] = (self._count, w, h, mean, 1.0)
            self._texels.append((img.reshape(-1), usage != "scalar"))
            self._count += w * h
        return self._images[key]
