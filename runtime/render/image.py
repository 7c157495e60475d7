"""Images in and out: OpenEXR (float32, through the ``OpenEXR`` package), 8-bit sRGB PNG
(written here with zlib and struct, no imaging library), and the RMSE used against references.

Images are numpy arrays of shape (H, W, C) (or (H, W) for one channel), row 0 at the top.
"""

from __future__ import annotations

import os
import struct
import zlib
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["read_exr", "read_exr_channels", "rmse", "srgb_encode", "write_exr", "write_image",
           "write_png", "write_render"]

_BASE_NAMES = {1: ("Y",), 3: ("R", "G", "B"), 4: ("R", "G", "B", "A")}
_ORDER = {"R": 0, "G": 1, "B": 2, "A": 3, "Y": 0}


def _openexr() -> Any:
    try:
        import OpenEXR
    except ImportError:
        raise RuntimeError("reading and writing .exr files needs the OpenEXR package "
                           "(pip install 'openexr>=3.2,<4')") from None
    return OpenEXR


def _as_hwc(img: Any, what: str) -> np.ndarray:
    a = np.asarray(img)
    if a.ndim == 2:
        a = a[:, :, None]
    if a.ndim != 3 or a.shape[0] == 0 or a.shape[1] == 0:
        raise ValueError(f"{what}: expected an (H, W) or (H, W, C) image, got shape {a.shape}")
    return a


def _channel_names(prefix: str, c: int) -> list[str]:
    if c in _BASE_NAMES and not (prefix and c == 1):
        names = list(_BASE_NAMES[c])
    elif c == 1:
        return [prefix]
    else:
        names = [str(i) for i in range(c)]
    return [f"{prefix}.{n}" if prefix else n for n in names]


def write_exr(path: str | Path, img: Any, extra: dict[str, Any] | None = None,
              with_base: bool = True) -> None:
    """Write ``img`` ((H, W, 3) RGB, (H, W, 4) RGBA or (H, W) luminance) as float32 OpenEXR.

    ``extra`` adds more layers, name -> (H, W) or (H, W, C) array: a 2-D array becomes one
    channel ``name``, a 3- or 4-channel one ``name.R``, ``name.G``, ``name.B`` (``name.A``),
    any other ``name.0``, ``name.1``, ... (AOVs, Stokes components).  ``with_base=False``
    writes only the layers (``img`` gives the size)."""
    exr = _openexr()
    base = _as_hwc(img, "write_exr")
    h, w = base.shape[:2]
    channels: dict[str, np.ndarray] = {}
    layers = [("", base)] * with_base + [(k, _as_hwc(v, f"write_exr (layer {k!r})"))
                             for k, v in (extra or {}).items()]
    for prefix, a in layers:
        if a.shape[:2] != (h, w):
            raise ValueError(f"write_exr: layer {prefix!r} has size {a.shape[:2]}, "
                             f"expected {(h, w)}")
        for i, name in enumerate(_channel_names(prefix, a.shape[2])):
            if name in channels:
                raise ValueError(f"write_exr: duplicate channel name {name!r}")
            channels[name] = np.ascontiguousarray(a[:, :, i], dtype=np.float32)
    header = {"compression": exr.ZIP_COMPRESSION, "type": exr.scanlineimage}
    with exr.File(header, channels) as f:
        f.write(str(path))


def read_exr_channels(path: str | Path) -> dict[str, np.ndarray]:
    """Every channel of an OpenEXR file as an (H, W) float32 array, by channel name."""
    exr = _openexr()
    try:
        f = exr.File(str(path), separate_channels=True)
    except (RuntimeError, OSError, ValueError) as e:
        raise OSError(f"cannot read OpenEXR file `{path}`: {e}") from None
    with f:
        return {name: np.asarray(ch.pixels, dtype=np.float32)
                for name, ch in f.channels().items()}


def read_exr(path: str | Path) -> np.ndarray:
    """The base layer of an OpenEXR file as (H, W, C) float32: R, G, B (and A), or Y.

    A file with no base channels gives all its channels in name order."""
    chans = read_exr_channels(path)
    base = sorted((n for n in chans if n in _ORDER), key=lambda n: _ORDER[n])
    names = base if base else sorted(chans)
    return np.stack([chans[n] for n in names], axis=-1)


def srgb_encode(x: np.ndarray) -> np.ndarray:
    """The sRGB OETF of linear values clamped to [0, 1] (NaN -> 0)."""
    x = np.clip(np.nan_to_num(np.asarray(x, np.float64), nan=0.0), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def _png_chunk(kind: bytes, data: bytes) -> bytes:
    return (struct.pack(">I", len(data)) + kind + data
            + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF))


def write_png(path: str | Path, img: Any, exposure: float = 0.0) -> None:
    """Write a linear image as an 8-bit sRGB PNG: scale by 2^exposure, clamp, sRGB, round.

    (H, W) or (H, W, 1) is grey, (H, W, 3) RGB, (H, W, 4) RGBA (alpha kept linear)."""
    a = _as_hwc(img, "write_png").astype(np.float64)
    h, w, c = a.shape
    if c not in (1, 3, 4):
        raise ValueError(f"write_png: expected 1, 3 or 4 channels, got {c}")
    color = srgb_encode(a[:, :, :min(c, 3)] * 2.0 ** exposure)
    if c == 4:
        alpha = np.clip(np.nan_to_num(a[:, :, 3:], nan=0.0), 0.0, 1.0)
        color = np.concatenate([color, alpha], axis=2)
    px = np.round(color * 255.0).astype(np.uint8)
    rows = np.concatenate([np.zeros((h, 1), np.uint8), px.reshape(h, w * c)], axis=1)
    color_type = {1: 0, 3: 2, 4: 6}[c]
    ihdr = struct.pack(">IIBBBBB", w, h, 8, color_type, 0, 0, 0)
    data = (b"\x89PNG\r\n\x1a\n" + _png_chunk(b"IHDR", ihdr)
            + _png_chunk(b"IDAT", zlib.compress(rows.tobytes(), 6)) + _png_chunk(b"IEND", b""))
    Path(path).write_bytes(data)


def write_image(path: str | Path, img: Any, **kwargs: Any) -> None:
    """Write ``img`` as OpenEXR or PNG, by the extension of ``path``."""
    suffix = Path(path).suffix.lower()
    if suffix == ".exr":
        write_exr(path, img, **kwargs)
    elif suffix == ".png":
        write_png(path, img, **kwargs)
    else:
        raise ValueError(f"cannot write `{path}`: use a .exr or .png file name")


def write_render(exr: Path, img: np.ndarray, channel_names: list[str]) -> Path:
    """Write a render as ``exr``, each channel under its name in ``channel_names`` (the
    colour: R, G, B, X, Y, Z or Y; A; the AOVs), and a tonemapped PNG of its colour (grey
    Y for XYZ or luminance) beside it, which it returns.  Each file is written under a
    temporary name in its folder and renamed over the old one, so a viewer that reloads
    the image never reads half of it."""
    png = exr.with_suffix(".png")
    layers = {n: img[..., i] for i, n in enumerate(channel_names)}
    rgb = channel_names[:3] == ["R", "G", "B"]
    first = 0 if rgb else channel_names.index("Y")
    _replace(exr, lambda tmp: write_exr(tmp, img, extra=layers, with_base=False))
    _replace(png, lambda tmp: write_png(tmp, img[..., first:first + (3 if rgb else 1)]))
    return png


def _replace(path: Path, write: Any) -> None:
    """``write(tmp)`` to a temporary file beside ``path``, then rename it to ``path``."""
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp{path.suffix}")
    try:
        write(tmp)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def rmse(a: Any, b: Any) -> float:
    """Root-mean-square difference of two images of the same shape (in float64)."""
    x, y = np.asarray(a, np.float64), np.asarray(b, np.float64)
    if x.shape != y.shape:
        raise ValueError(f"rmse: shapes differ: {x.shape} and {y.shape}")
    return float(np.sqrt(np.mean((x - y) ** 2)))
