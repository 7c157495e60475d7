"""A compat *sheet*: one scene holding a grid of cases, one object per tile, rendered by rdsl
and by Mitsuba 3 and compared tile by tile against a high-spp Mitsuba reference.

A sheet compiles one rdsl kernel (the generic build, whose kernel depends on the scene's
structure, not its values) and is loaded once by Mitsuba, so a few dozen cases cost a few
compiles.  Each tile's error is the RMSE over its pixels; the noise-aware test compares
rdsl's RMSE to the reference with Mitsuba's own RMSE at the same spp (a bias shows as an
RMSE that stays above Mitsuba's, noise alone gives about the same)."""

from __future__ import annotations

import math
import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
REFS = HERE / "refs"
ASSETS = HERE / "assets"
TILE = 24          # pixels per tile side
SPP = 32           # rdsl's and Mitsuba's spp in the test
REF_SPP = 4096     # the reference's
DISTANCE = 12.0    # camera to the tiles' plane
TRIM = 0.02        # the fraction of largest squared errors a tile's RMSE leaves out


@dataclass(frozen=True)
class Case:
    """One tile: ``xml`` is a ``<bsdf>`` (put on the sheet's object) unless ``shape`` is
    false, when it is the tile's whole object with ``{T}`` for its ``to_world`` (a unit
    object placed in its tile; ``{X}``, ``{Y}`` its centre).  ``xfail``: the reason, with
    measured numbers, it differs."""

    name: str
    xml: str
    shape: bool = False
    xfail: str = ""
    strict: bool = True  # false: the test's spp cannot decide the case (the reason says why)


@dataclass(frozen=True)
class Sheet:
    """A scene of ``cases`` on a grid of ``cols`` columns.  ``obj``: the object a
    ``<bsdf>`` case is put on (``{T}`` its transform, ``{bsdf}`` the case).  ``extra``:
    scene-level XML before the tiles (shared ``id``s, includes), ``after`` after them (forward
    references); ``lights`` replaces the default lights; ``files``: other files written next
    to the scene (relative path -> text, or ``$ASSETS/NAME`` for a copy of that asset)."""

    name: str
    cases: tuple[Case, ...]
    variant: str = "rgb"
    cols: int = 4
    obj: str = '<shape type="sphere">{T}{bsdf}</shape>'
    extra: str = ""
    after: str = ""
    files: dict[str, str] = field(default_factory=dict)
    integrator: str = '<integrator type="path"><integer name="max_depth" value="6"/></integrator>'
    lights: str | None = None
    sensor: str = ""
    rfilter: str = '<rfilter type="box"/>'
    backdrop: bool = True
    spp: int = SPP
    film: str = ""  # more of the film's XML (pixel_format, ...)
    crop: tuple[int, int, int, int] | None = None  # the film's crop window: x, y, width, height
    channels: tuple[int, ...] = (0, 1, 2)  # the image's channels compared (AOVs: by index)

    @property
    def rows(self) -> int:
        return math.ceil(len(self.cases) / self.cols)

    @property
    def cols_used(self) -> int:
        return min(self.cols, len(self.cases))

    def center(self, i: int) -> tuple[float, float]:
        r, c = divmod(i, self.cols)
        return c - (self.cols_used - 1) / 2, (self.rows - 1) / 2 - r

    def tile(self, img: np.ndarray, i: int) -> np.ndarray:
        """Tile ``i`` of the sheet's image, or with a crop window its part in the window."""
        r, c = divmod(i, self.cols)
        x, y = self.crop[:2] if self.crop else (0, 0)
        return img[max(r * TILE - y, 0):max((r + 1) * TILE - y, 0),
                   max(c * TILE - x, 0):max((c + 1) * TILE - x, 0)]

    def pick(self, img: np.ndarray) -> np.ndarray:
        """The channels the sheet compares, of a rendered image (H, W, C)."""
        img = np.asarray(img, np.float64)
        img = img.reshape(*img.shape[:2], -1)
        if self.channels == (0, 1, 2):  # the colour: R, G, B, or Y alone (mono, luminance)
            return img[..., :3]
        return img[..., list(self.channels)]


LIGHTS = """
  <shape type="sphere"><transform name="to_world"><scale value="1.2"/>
    <translate x="{lx}" y="{ly}" z="4"/></transform>
    <emitter type="area"><rgb name="radiance" value="3, 3, 3"/></emitter></shape>
  <emitter type="constant"><rgb name="radiance" value="0.4, 0.4, 0.4"/></emitter>"""

BACKDROP = """
  <shape type="rectangle">
    <transform name="to_world"><scale x="{sx}" y="{sy}"/><translate z="-1.5"/></transform>
    <bsdf type="diffuse"><texture type="checkerboard" name="reflectance">
      <rgb name="color0" value="0.15, 0.15, 0.2"/><rgb name="color1" value="0.6, 0.55, 0.5"/>
      <transform name="to_uv"><scale x="{cx}" y="{cy}"/></transform></texture></bsdf>
  </shape>"""


def unit_transform(x: float, y: float, scale: float = 0.4) -> str:
    return (f'<transform name="to_world"><scale value="{scale}"/>'
            f'<translate x="{x:g}" y="{y:g}"/></transform>')


def scene_xml(sheet: Sheet) -> str:
    """The sheet's scene file: a perspective camera whose view is exactly the grid."""
    cols, rows = sheet.cols_used, sheet.rows
    fov = math.degrees(2 * math.atan(cols / 2 / DISTANCE))
    tiles = []
    for i, case in enumerate(sheet.cases):
        x, y = sheet.center(i)
        t = unit_transform(x, y)
        xml = case.xml if case.shape else sheet.obj.replace("{bsdf}", case.xml)
        tiles.append(xml.replace("{T}", t).replace("{X}", f"{x:g}").replace("{Y}", f"{y:g}"))
    lights = sheet.lights if sheet.lights is not None else LIGHTS.format(
        lx=cols / 2 + 0.5, ly=rows / 2 + 1)
    backdrop = BACKDROP.format(sx=cols, sy=rows, cx=2 * cols, cy=2 * rows) \
        if sheet.backdrop else ""
    body = "\n  ".join(tiles)
    crop = "".join(f'<integer name="{k}" value="{v}"/>' for k, v in zip(
        ("crop_offset_x", "crop_offset_y", "crop_width", "crop_height"), sheet.crop or ()))
    film = (f'<film type="hdrfilm"><integer name="width" value="{cols * TILE}"/>'
            f'<integer name="height" value="{rows * TILE}"/>{crop}{sheet.film}'
            f'{sheet.rfilter}</film>')
    sensor = (sheet.sensor or f"""<sensor type="perspective"><float name="fov" value="{fov:.6f}"/>
    <string name="fov_axis" value="x"/>
    <transform name="to_world"><lookat origin="0, 0, {DISTANCE}" target="0, 0, 0" up="0, 1, 0"/>
    </transform>{{film}}</sensor>""").replace("{film}", film)
    return f"""<scene version="3.0.0">
  {sheet.integrator}
  {sensor}
  {sheet.extra}
  {body}
  {sheet.after}
  {lights}
  {backdrop}
</scene>
"""


def write(sheet: Sheet, folder: Path) -> Path:
    """The sheet's scene (``scene.xml``: every sheet has that name, so that sheets of one
    structure share a kernel) and its files, under ``folder``; asset paths are the
    ``$ASSETS`` folder."""
    folder.mkdir(parents=True, exist_ok=True)
    for rel, text in sheet.files.items():
        (folder / rel).parent.mkdir(parents=True, exist_ok=True)
        if text.startswith("$ASSETS/") and "\n" not in text:  # a copy of an asset
            shutil.copyfile(ASSETS / text.split("/", 1)[1], folder / rel)
        else:
            (folder / rel).write_text(text.replace("$ASSETS", str(ASSETS)))
    path = folder / "scene.xml"
    path.write_text(scene_xml(sheet).replace("$ASSETS", str(ASSETS)))
    return path


def mitsuba_variant(variant: str, live: bool) -> str:
    """The Mitsuba variant of an rdsl one: scalar for the live render; for a reference the
    LLVM one where libLLVM is present."""
    if not live and os.environ.get("DRJIT_LIBLLVM_PATH"):
        return f"llvm_ad_{variant}"
    try:  # the mitsuba wheel builds mono variants as LLVM ones only (they need libLLVM)
        import mitsuba as mi
        if f"scalar_{variant}" not in mi.variants() and f"llvm_ad_{variant}" in mi.variants():
            return f"llvm_ad_{variant}"
    except ImportError:
        pass
    return f"scalar_{variant}"


def mitsuba_render(path: Path, variant: str, spp: int, seed: int) -> np.ndarray:
    import mitsuba as mi

    mi.set_variant(variant)
    img = mi.render(mi.load_file(str(path)), spp=spp, seed=seed)
    return np.array(img, np.float64)  # every channel: a sheet picks its own


def specialized() -> bool:
    """``RDSL_COMPAT_SPECIALIZE=1``: the specialized build (one kernel per sheet's values)
    rather than the generic one (one kernel per structure: fewer compiles)."""
    return os.environ.get("RDSL_COMPAT_SPECIALIZE", "") not in ("", "0")


def rdsl_render(path: Path, variant: str, spp: int, seed: int) -> np.ndarray:
    from rdsl.runtime.render.renderer import load_scene

    scene = load_scene(path, variant=variant, specialize=specialized())
    return np.asarray(scene.render(spp=spp, seed=seed), np.float64)[..., :3]


def rmse(img: np.ndarray, ref: np.ndarray, trim: float = TRIM) -> float:
    """The RMSE of ``img`` against ``ref`` over all but the largest ``trim`` fraction of
    squared errors (a rare firefly moves an RMSE of a few hundred pixels more than a bias
    does; a bias over more than that fraction of the tile still shows)."""
    e = np.sort(((np.asarray(img, np.float64) - ref) ** 2).ravel())
    return float(np.sqrt(e[:max(1, int(len(e) * (1 - trim)))].mean()))


def ref_path(sheet: Sheet) -> Path:
    return REFS / f"{sheet.name}.exr"


# ------------------------------------------------------------------------------ measuring
RATIO = 1.25       # rdsl's RMSE may be this many times Mitsuba's
SEEDS = (1, 2, 3)  # the medians are over these seeds
_TMP: list[Path] = []


def noise_table() -> dict:
    import json

    return json.loads((REFS / "noise.json").read_text())


def _mitsuba_live(path: Path, sh: Sheet) -> list[np.ndarray] | None:
    try:
        import mitsuba as mi
        mi.set_variant(mitsuba_variant(sh.variant, True))
    except (ImportError, AttributeError, ValueError, RuntimeError):
        return None
    scene = mi.load_file(str(path))
    return [sh.pick(mi.render(scene, spp=sh.spp, seed=100 + s)) for s in SEEDS]


def rdsl_images(sh: Sheet) -> list[np.ndarray]:
    """rdsl's renders of the sheet at its spp, one per seed of SEEDS, its channels picked;
    sheets of one scene (the AOVs of one render) render it once."""
    import tempfile

    from rdsl.runtime.render.integrators import integrator_plan
    from rdsl.runtime.render.renderer import load_scene

    if not _TMP:
        _TMP.append(Path(tempfile.mkdtemp(prefix="rdsl-compat-")))
    path = write(sh, _TMP[0] / sh.name)
    key = (path.read_text(), sh.variant, sh.spp)
    if key not in _RENDERS:
        scene = load_scene(path, variant=sh.variant, specialize=specialized())
        # laid out as mi.render's image: without an aov's copy of its nested integrator's
        # image, which Mitsuba's film writes to its EXR but leaves out of that tensor
        nested = integrator_plan(scene.desc.integrator).nested_image
        keep = [i for i, n in enumerate(scene.channel_names)
                if nested is None or not n.startswith(f"{nested}.")]
        _RENDERS[key] = [scene.render(spp=sh.spp, seed=s)[..., keep] for s in SEEDS]
    return [sh.pick(m) for m in _RENDERS[key]]


def measure(sheets: list[Sheet] | Sheet | str, live: bool = True
            ) -> dict[str, tuple[float, float, str]]:
    """Per case of the sheet: (rdsl's RMSE, Mitsuba's, where Mitsuba's comes from: 'live'
    or 'noise.json'), medians over SEEDS; raises what loading the sheet raises.  Cached."""
    from rdsl.runtime.render.image import read_exr

    sh = sheets if isinstance(sheets, Sheet) else None
    if sh is None:
        from _suite import BY_NAME
        sh = BY_NAME[sheets]
    if (sh.name, live) in _MEASURED:
        return _MEASURED[sh.name, live]
    ref = read_exr(ref_path(sh)).astype(np.float64)
    mine = rdsl_images(sh)
    path = write(sh, _TMP[0] / sh.name)
    theirs = _mitsuba_live(path, sh) if live else None
    out = {}
    for i, c in enumerate(sh.cases):
        r = sh.tile(ref, i)
        ours = float(np.median([rmse(sh.tile(m, i), r) for m in mine]))
        if theirs is not None:
            out[c.name] = (ours, float(np.median([rmse(sh.tile(m, i), r) for m in theirs])),
                           "live")
        else:
            out[c.name] = (ours, noise_table()[sh.name]["rmse"][c.name], "noise.json")
    _MEASURED[sh.name, live] = out
    return out


_MEASURED: dict[tuple[str, bool], dict[str, tuple[float, float, str]]] = {}
_RENDERS: dict[tuple[str, str, int], list[np.ndarray]] = {}
