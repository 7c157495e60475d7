"""Per-scene setup of the `Film` struct of ``stdlib/render/film.rdsl``, and ``develop``.

The per-sample work (filter weights, the gather) is in the stdlib; this module only turns the
loader's ``hdrfilm``/``rfilter`` into uniforms, sizes the buffers and divides at the end.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["FILTERS", "PIXEL_FORMATS", "border_size", "colour_image", "develop", "film_format",
           "film_uniforms", "filter_radius", "new_accumulator"]

# rfilter type -> the kind id of film.rdsl (filter_box ... filter_lanczos); Mitsuba's
# catmullrom is its mitchell with B = 0, C = 1/2
FILTERS = {"box": 0, "tent": 1, "gaussian": 2, "mitchell": 3, "catmullrom": 3, "lanczos": 4}


# hdrfilm's pixel_format -> (the colour it writes, whether it writes alpha); the colour's
# channels as the EXR names them
PIXEL_FORMATS = {"rgb": ("rgb", False), "rgba": ("rgb", True), "xyz": ("xyz", False),
                 "xyza": ("xyz", True), "luminance": ("luminance", False),
                 "luminance_alpha": ("luminance", True)}
COLOUR_CHANNELS = {"rgb": ["R", "G", "B"], "xyz": ["X", "Y", "Z"], "luminance": ["Y"]}
# Mitsuba's srgb_to_xyz (linear sRGB primaries, D65 white); its second row is `luminance`
SRGB_TO_XYZ = np.array([[0.412453, 0.357580, 0.180423],
                        [0.212671, 0.715160, 0.072169],
                        [0.019334, 0.119193, 0.950227]])


def film_format(film: Any, mono: bool = False) -> tuple[str, bool]:
    """(colour, alpha) of the film's ``pixel_format``.  As Mitsuba's, a mono variant's film
    writes luminance, with alpha only for ``luminance_alpha`` (it warns and drops the alpha
    of ``rgba`` and ``xyza``)."""
    colour, alpha = PIXEL_FORMATS[film.params.get("pixel_format", "rgb")]
    if mono:
        return "luminance", alpha and colour == "luminance"
    return colour, alpha


def _filter_params(rfilter: Any) -> tuple[float, float]:
    """film.rdsl's (param, param2) of a filter: see filter_eval there."""
    p = rfilter.params
    if rfilter.type == "gaussian":
        return float(p.get("stddev", 0.5)), 0.0
    if rfilter.type == "tent":
        return float(p.get("radius", 1.0)), 0.0
    if rfilter.type == "mitchell":
        return float(p.get("B", 1.0 / 3.0)), float(p.get("C", 1.0 / 3.0))
    if rfilter.type == "catmullrom":
        return 0.0, 0.5
    if rfilter.type == "lanczos":
        return float(p.get("lobes", 3)), 0.0
    return 0.5, 0.0


def _radius(kind: int, param: float) -> float:
    """film.rdsl's filter_radius."""
    return {0: 0.5, 1: param, 3: 2.0, 4: param}.get(kind, 4.0 * param)


def filter_radius(rfilter: Any) -> float:
    """The filter's support radius in pixels (Mitsuba's ``ReconstructionFilter::radius``)."""
    return _radius(FILTERS[rfilter.type], _filter_params(rfilter)[0])


def border_size(rfilter: Any) -> int:
    """Mitsuba's ``border_size``: ceil(radius - 1/2), the margin `sample_border` renders."""
    return 0 if rfilter.type == "box" else math.ceil(filter_radius(rfilter) - 0.5)


def film_uniforms(film: Any, spp: int, channels: int = 3) -> dict[str, Any]:
    """The `Film` field values for a loaded ``hdrfilm`` and ``spp`` samples per grid pixel.

    The sample grid is the crop window, grown by ``border_size`` on each side when the film
    has ``sample_border`` (as Mitsuba renders it); the renderer must lay its samples out on
    that grid: see the buffer layouts in ``film.rdsl``."""
    p = film.params
    rf = p["rfilter"]
    if rf.type not in FILTERS:
        raise ValueError(f"unsupported reconstruction filter `{rf.type}`")
    cx, cy, cw, ch = (int(p[k]) for k in ("crop_offset_x", "crop_offset_y",
                                          "crop_width", "crop_height"))
    b = border_size(rf) if p.get("sample_border") else 0
    return {"crop_x": cx, "crop_y": cy, "crop_w": cw, "crop_h": ch,
            "grid_x": cx - b, "grid_y": cy - b, "grid_w": cw + 2 * b, "grid_h": ch + 2 * b,
            "spp": int(spp), "channels": int(channels),
            "filter": FILTERS[rf.type], "filter_param": _filter_params(rf)[0],
            "filter_param2": _filter_params(rf)[1]}


def new_accumulator(film: dict[str, Any]) -> np.ndarray:
    """A zeroed accumulator for ``film_uniforms``' film: (crop_w * crop_h * (C + 1),) float32."""
    return np.zeros(film["crop_w"] * film["crop_h"] * (film["channels"] + 1), np.float32)


def develop(acc: np.ndarray, film: dict[str, Any]) -> np.ndarray:
    """Divide the weighted sums by the weights: a (crop_h, crop_w, C) float32 image.

    Pixels with zero weight stay 0 (Mitsuba divides by 1 there)."""
    c = film["channels"]
    a = np.asarray(acc, np.float32).reshape(film["crop_h"], film["crop_w"], c + 1)
    w = a[..., c:]
    return (a[..., :c] / np.where(w == 0, np.float32(1), w)).astype(np.float32)


def colour_image(img: np.ndarray, colour: str) -> np.ndarray:
    """A developed image's R, G, B (its first three channels) in the film's ``colour``:
    kept (rgb), as CIE XYZ (Mitsuba's ``srgb_to_xyz``) or as their luminance Y (its Y row),
    the other channels after them, as Mitsuba's film develops them.  The filter is linear,
    so this equals the filtered colour of the samples."""
    if colour == "rgb":
        return img
    rows = SRGB_TO_XYZ if colour == "xyz" else SRGB_TO_XYZ[1:2]
    c = sum(img[..., k, None] * rows[:, k].astype(np.float32) for k in range(3))
    return np.concatenate([c, img[..., 3:]], -1).astype(np.float32)


def film_reach(film: dict[str, Any]) -> int:
    """Columns (rows) a sample reaches on each side of its cell (as `film_reach` in rdsl)."""
    radius = _radius(film["filter"], film["filter_param"])
    return int(np.ceil(np.float32(radius) + np.float32(0.5))) - 1


FILM_SPP = 2  # samples per cell a film gather takes at once (below)


def gather_in_groups(kernel: Any, pixels: np.ndarray, spp: int, ns: int, S: np.ndarray,
                     acc: np.ndarray, threads: int | None) -> None:
    """Run a film gather (``film_pass``, ``film_weight_pass``: ``film_accumulate_separable``)
    over a batch of ``spp`` samples per cell, ``ns`` in all, in groups of ``FILM_SPP``
    samples per cell: each call reads the same planes of ``S`` at a group's offset.  A
    pass over every pixel then touches a few MB instead of the batch's 7-10 (13 planes of
    2^17 samples at 128 x 128): on a 2-core Zen 4, 8 spp at once took 4-7 ms, the same in
    groups of 2 2.6-3.9 ms.  The gather goes on from the sums in ``acc`` tap by tap, so the
    groups give the same bits as one call.  A film accumulated on a device (OpenCL's
    resident ``acc``) takes the batch whole."""
    cells = ns // max(spp, 1)
    if not (isinstance(S, np.ndarray) and isinstance(acc, np.ndarray)) or cells * spp != ns:
        kernel(pixels, np.array([spp, ns], np.int32), S, acc, threads=threads)
        return
    for s0 in range(0, spp, FILM_SPP):
        m = min(FILM_SPP, spp - s0)
        kernel(pixels, np.array([m, ns], np.int32), S[s0 * cells:], acc, threads=threads)
