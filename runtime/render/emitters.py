"""The scene's emitters packed into the tables the integrator samples them from.

Python only lays out parameters and precomputed tables here; the sampling and evaluation
are rdsl (stdlib/render/lights.rdsl documents the layout of ``EK``, ``E``, ``LC``, ``LT``;
stdlib/emitter/envmap.rdsl the one of ``ENV``).  Emitter ids are the area emitters first,
in shape order (the ids ``scene_emitter_eval`` dispatches on), then the others in scene order.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ...compiler.diagnostics import CompileError
from ...core.color import RGB, ColorModel
from .colors import emission_row, emission_texels

# the emitter table's kinds (lights.rdsl); an area light (stdlib `area` or a user's emitter
# plugin, runtime/plugins.py) is also a scene instance, whose `eval` the integrator calls
KINDS = {"area": 0, "point": 1, "spot": 2, "directional": 3, "constant": 4, "envmap": 5}
ENVIRONMENTS = ("constant", "envmap")
STRIDE = 24  # floats per emitter in E (lights.rdsl: emitter_stride())
LUMINANCE = np.array([0.212671, 0.715160, 0.072169])  # linear sRGB -> Y, as Mitsuba


@dataclass
class EmitterTables:
    """Every emitter of the scene, for stdlib/render/lights.rdsl."""

    LC: np.ndarray   # float32, per emissive triangle: cumulative area within its shape
    LT: np.ndarray   # int32, 2 per emissive triangle: triangle, shape
    EK: np.ndarray   # int32, 4 per emitter: kind, first LC entry, LC entries, 0
    E: np.ndarray    # float32, STRIDE per emitter: parameters by kind
    ENV: np.ndarray  # float32, the environment map's texels and CDFs
    nemitter: int = 0
    env: int = -1    # id of the environment emitter, -1 if none

    def args(self) -> list[np.ndarray]:
        return [self.EK, self.E, self.ENV]


def _color(value: Any, what: str, loc: Any) -> np.ndarray:
    rgb = getattr(value, "rgb", None)
    if rgb is None:
        if isinstance(value, (int, float)):
            return np.full(3, float(value))
        raise CompileError(f"{what}: a texture is not supported here (give an rgb or a "
                           "spectrum)", loc)
    return np.asarray(rgb, np.float64)


def _linear_part(m: np.ndarray, what: str, loc: Any, rigid: bool) -> np.ndarray:
    lin = np.asarray(m, np.float64)[:3, :3]
    if abs(np.linalg.det(lin)) < 1e-12:
        raise CompileError(f"{what}: 'to_world' is singular", loc)
    if rigid and not np.allclose(lin.T @ lin, np.eye(3), atol=1e-4):
        raise CompileError(f"{what}: 'to_world' must be a rotation (no scale or shear)", loc)
    return lin


def emitter_tables(desc: Any, lights: list[tuple[int, int, float]],
                   area_emitters: int,
                   analytic: dict[int, tuple[int, int, float]] | None = None,
                   model: ColorModel = RGB, textures: Any = None) -> EmitterTables:
    """Tables for the scene's emitters.  ``lights`` holds (triangle, shape, area) for every
    triangle of the area-lit shapes, in shape order; ``area_emitters`` counts those shapes.
    An area-lit analytic shape is a single entry (-1, shape, area) of ``lights``, and
    ``analytic[shape]`` = (shape kind, offset of its record in P, area): its EK row is (area,
    offset, 0, kind), and lights.rdsl samples its surface instead of triangles."""
    LC, LT, EK, E = [], [], [], []
    # area emitters: one run of consecutive entries per shape
    start = 0
    while start < len(lights):
        shape = lights[start][1]
        end = start
        while end < len(lights) and lights[end][1] == shape:
            end += 1
        row = np.zeros(STRIDE)
        if analytic and shape in analytic:
            kind, offset, area = analytic[shape]
            EK.append((KINDS["area"], offset, 0, kind))
            row[0] = np.float32(area)
        else:
            areas = np.array([a for _, _, a in lights[start:end]], np.float64)
            cum = np.cumsum(areas)
            first = len(LC)
            LC += list(cum)
            LT += [(t, s) for t, s, _ in lights[start:end]]
            EK.append((KINDS["area"], first, end - start, 0))
            row[0] = np.float32(cum[-1])
        E.append(row)
        start = end
    assert len(EK) == area_emitters, (len(EK), area_emitters)
    env, ENV = -1, np.zeros(1, np.float32)
    for em in desc.emitters:
        if em.type == "area" or getattr(em, "decl", None) is not None:
            continue
        what = f"emitter `{em.type}`" + (f" ({em.id})" if em.id else "")
        if em.type not in KINDS:
            raise CompileError(f"{what} is not supported by the renderer yet (supported: "
                               f"{', '.join(KINDS)})", em.loc)
        if em.type in ENVIRONMENTS:
            if env >= 0:
                raise CompileError(f"{what}: only one environment emitter (constant or "
                                   "envmap) can be specified per scene", em.loc)
            env = len(EK)
        row, table = _emitter_row(em, what, model, textures)
        if table is not None:
            ENV = table
        EK.append((KINDS[em.type], 0, 0, 0))
        E.append(row)
    # buffers are never empty (a kernel argument needs memory), the counts say what is used
    return EmitterTables(
        np.ascontiguousarray(LC or [0.0], np.float32),
        np.ascontiguousarray(np.array(LT or [(0, 0)], np.int32).reshape(-1)),
        np.ascontiguousarray(np.array(EK or [(0, 0, 0, 0)], np.int32).reshape(-1)),
        np.ascontiguousarray(np.concatenate(E or [np.zeros(STRIDE)]), np.float32),
        np.ascontiguousarray(ENV, np.float32), len(EK), env)


def _put_color(row: np.ndarray, value: Any, what: str, loc: Any, model: ColorModel) -> None:
    """An emitted colour at row[0:3] with its scale at row[23] (lights.rdsl load_spectrum)."""
    row[0:3], row[23] = emission_row(_color(value, what, loc), model)


def _emitter_row(em: Any, what: str, model: ColorModel = RGB, textures: Any = None
                 ) -> tuple[np.ndarray, np.ndarray | None]:
    """The E row of one non-area emitter, and its ENV table for an envmap; ``textures``
    (the scene's TextureTable) takes a spot light's projected texture."""
    p, row = em.params, np.zeros(STRIDE)
    if em.type == "point":
        _put_color(row, p["intensity"], f"{what}: 'intensity'", em.loc, model)
        row[3:6] = p["to_world"][:3, 3]
    elif em.type == "spot":
        cutoff, beam = np.radians(p["cutoff_angle"]), np.radians(p["beam_width"])
        if not 0.0 < cutoff <= np.pi:
            raise CompileError(f"{what}: 'cutoff_angle' must be in (0, 180] degrees, got "
                               f"{p['cutoff_angle']}", em.loc)
        if not 0.0 <= beam <= cutoff:
            raise CompileError(f"{what}: 'beam_width' ({p['beam_width']}) must be between 0 "
                               f"and 'cutoff_angle' ({p['cutoff_angle']})", em.loc)
        lin = _linear_part(p["to_world"], what, em.loc, rigid=False)
        _put_color(row, p["intensity"], f"{what}: 'intensity'", em.loc, model)
        row[3:6] = p["to_world"][:3, 3]
        row[6:15] = np.linalg.inv(lin).reshape(-1)
        row[15:19] = (np.cos(cutoff), np.cos(beam), cutoff,
                      1.0 / (cutoff - beam) if cutoff > beam else 3.0e38)
        # a texture plugin is projected (a constant colour is not: Mitsuba's spot uses the
        # texture only when it is spatially varying)
        tex = p.get("texture")
        if getattr(tex, "category", None) == "texture" and textures is not None:
            if cutoff >= np.pi / 2:
                raise CompileError(f"{what}: a projected 'texture' needs a 'cutoff_angle' below "
                                   "90 degrees", em.loc)
            row[19] = textures.ref(tex, f"{what}: 'texture'", "emitted").index + 1
            row[20] = np.tan(cutoff)
    elif em.type == "directional":
        _put_color(row, p["irradiance"], f"{what}: 'irradiance'", em.loc, model)
        row[3:6] = p["direction"]
    elif em.type == "constant":
        _put_color(row, p["radiance"], f"{what}: 'radiance'", em.loc, model)
    else:  # envmap
        if p.get("filter_type", "bilinear") != "bilinear":
            raise CompileError(f"{what}: filter_type '{p['filter_type']}' is not supported "
                               "by the renderer yet (supported: bilinear)", em.loc)
        lin = _linear_part(p["to_world"], what, em.loc, rigid=True)
        image = read_bitmap(p["filename"], what, em.loc)
        table, (w, h) = envmap_tables(image, model)
        row[0:3] = (float(p["scale"]), w, h)
        row[3:12] = lin.reshape(-1)
        row[12:21] = np.linalg.inv(lin).reshape(-1)
        return row, table
    return row, None


def read_bitmap(path: str | Path, what: str = "bitmap", loc: Any = None) -> np.ndarray:
    """An image as linear float (H, W, 3), read like a bitmap texture (EXR as stored, 8-bit
    PNG/JPEG decoded from sRGB, as Mitsuba's Bitmap does); errors name the emitter."""
    from .textures import load_bitmap

    try:
        return load_bitmap(path)
    except RuntimeError as e:  # Pillow missing
        raise CompileError(f"{what}: {e}", loc) from None
    except OSError as e:
        raise CompileError(f"{what}: cannot read `{path}`: {e}", loc) from None


def envmap_tables(image: np.ndarray, model: ColorModel = RGB
                  ) -> tuple[np.ndarray, tuple[int, int]]:
    """ENV for a lat-long image (H, W, 3): texels, then the marginal and conditional CDFs
    of the cells between texel rows and columns (stdlib/emitter/envmap.rdsl).  A texel is
    4 floats, an emitted colour as ``model`` stores it (``emission_texels``); the sampling
    density follows the RGB luminance in every variant."""
    img = np.asarray(image, np.float64)
    if img.shape[0] == 1:  # one row: constant in theta, two rows for the poles
        img = np.concatenate([img, img], axis=0)
    h, w = img.shape[:2]
    if not np.all(np.isfinite(img)) or np.any(img < 0):
        img = np.where(np.isfinite(img), np.maximum(img, 0.0), 0.0)
    lum = np.maximum(img @ LUMINANCE, 0.0)
    corners = lum[:-1] + lum[1:]                             # rows i and i + 1
    cells = 0.25 * (corners + np.roll(corners, -1, axis=1))  # columns j and j + 1 (wrapping)
    theta = np.linspace(0.0, np.pi, h)
    cells *= (np.cos(theta[:-1]) - np.cos(theta[1:]))[:, None]  # solid angle (up to 2 pi / W)
    if not np.any(cells > 0):
        cells = np.ones_like(cells) * (np.cos(theta[:-1]) - np.cos(theta[1:]))[:, None]
    row_sums = cells.sum(axis=1)
    marginal = np.concatenate([[0.0], np.cumsum(row_sums)]) / row_sums.sum()
    marginal[-1] = 1.0
    safe = np.where(row_sums > 0, row_sums, 1.0)[:, None]
    cond = np.concatenate([np.zeros((h - 1, 1)), np.cumsum(cells, axis=1) / safe], axis=1)
    cond[row_sums <= 0] = np.linspace(0.0, 1.0, w + 1)
    cond[:, -1] = 1.0
    texels = emission_texels(img.reshape(-1, 3), model)
    table = np.concatenate([texels.reshape(-1), marginal, cond.reshape(-1)])
    return np.ascontiguousarray(table, np.float32), (w, h)
