"""Readers for the two high-dynamic-range image formats Mitsuba 3's Bitmap reads besides
OpenEXR, which Pillow does not: Radiance RGBE (``.hdr``, ``.rgbe``; flat or run-length
encoded scanlines) and the Portable Float Map (``.pfm``, colour ``PF`` or grey ``Pf``).
Both hold linear values; each reader gives float32 (H, W, 3) or (H, W), row 0 at the top."""

from __future__ import annotations

from pathlib import Path

import numpy as np


class ImageFormatError(ValueError):
    """A file that is not a well-formed image of the format its name says."""


def read_rgbe(path: Path) -> np.ndarray:
    """A Radiance RGBE file (``#?RADIANCE`` or ``#?RGBE`` header, ``-Y H +X W`` size)."""
    data = Path(path).read_bytes()
    if not data.startswith(b"#?"):
        raise ImageFormatError("not an RGBE file (no '#?' header)")
    end = data.find(b"\n\n")
    if end < 0:
        raise ImageFormatError("RGBE header does not end")
    header = data[:end].decode("latin-1")
    if "FORMAT=" in header and "32-bit_rle_rgbe" not in header:
        raise ImageFormatError("only the 32-bit_rle_rgbe format is supported")
    nl = data.find(b"\n", end + 2)
    size = data[end + 2:nl].decode("latin-1").split()
    if len(size) != 4 or size[0] != "-Y" or size[2] != "+X":
        raise ImageFormatError(f"unsupported RGBE orientation {' '.join(size)!r}")
    h, w = int(size[1]), int(size[3])
    raw = np.frombuffer(data, np.uint8, offset=nl + 1)
    pix = _rgbe_scanlines(raw, w, h)
    e = pix[..., 3].astype(np.int32)
    scale = np.where(e == 0, 0.0, np.ldexp(1.0, e - 136))
    return (pix[..., :3] * scale[..., None]).astype(np.float32)


def _rgbe_scanlines(raw: np.ndarray, w: int, h: int) -> np.ndarray:
    """(h, w, 4) bytes of the pixel data, flat or with new-style run-length scanlines."""
    if not (8 <= w < 32768) or len(raw) < 4 or raw[0] != 2 or raw[1] != 2 or raw[2] & 0x80:
        if raw.size < w * h * 4:
            raise ImageFormatError("RGBE pixel data is truncated")
        return raw[:w * h * 4].reshape(h, w, 4)
    out = np.empty((h, w, 4), np.uint8)
    pos = 0
    for y in range(h):
        if pos + 4 > raw.size or raw[pos] != 2 or raw[pos + 1] != 2:
            raise ImageFormatError(f"RGBE scanline {y} is not run-length encoded")
        pos += 4
        for c in range(4):
            x = 0
            while x < w:
                if pos >= raw.size:
                    raise ImageFormatError("RGBE pixel data is truncated")
                n = int(raw[pos])
                pos += 1
                if n > 128:  # a run of one byte
                    n -= 128
                    out[y, x:x + n, c] = raw[pos]
                    pos += 1
                else:        # n literal bytes
                    out[y, x:x + n, c] = raw[pos:pos + n]
                    pos += n
                x += n
                if x > w:
                    raise ImageFormatError(f"RGBE scanline {y} overruns its width")
    return out


def read_pfm(path: Path) -> np.ndarray:
    """A Portable Float Map: ``PF`` (RGB) or ``Pf`` (grey), rows stored bottom to top, the
    sign of the scale giving the byte order (negative: little-endian)."""
    data = Path(path).read_bytes()
    fields, pos = [], 0
    while len(fields) < 4:
        while pos < len(data) and data[pos:pos + 1].isspace():
            pos += 1
        start = pos
        while pos < len(data) and not data[pos:pos + 1].isspace():
            pos += 1
        if start == pos:
            raise ImageFormatError("PFM header is truncated")
        fields.append(data[start:pos].decode("latin-1"))
    pos += 1
    kind, (w, h, scale) = fields[0], (int(fields[1]), int(fields[2]), float(fields[3]))
    if kind not in ("PF", "Pf"):
        raise ImageFormatError(f"not a PFM file (magic {kind!r})")
    ch = 3 if kind == "PF" else 1
    a = np.frombuffer(data, "<f4" if scale < 0 else ">f4", count=w * h * ch, offset=pos)
    if a.size != w * h * ch:
        raise ImageFormatError("PFM pixel data is truncated")
    a = a.reshape(h, w, ch)[::-1]
    return np.ascontiguousarray(a[..., 0] if ch == 1 else a, np.float32)
