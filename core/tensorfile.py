"""Mitsuba 3's tensor file format (``TensorFile``, src/core/tensor.cpp; ``mi.tensor_io``), and
the polarimetric BRDF tables of the ``measured_polarized`` BSDF stored in it.

A tensor file is little-endian::

    "tensor_file\\0"   12 bytes
    version           2 bytes: 1, 0
    field count       uint32
    per field:        name length (uint16), name (utf-8), rank (uint16), dtype (uint8),
                      offset of its data from the file's start (uint64), shape (rank uint64)
    the fields' data, C order, each at its offset (Mitsuba's writer aligns them to 8 bytes)

The dtype codes are Mitsuba's ``Struct`` types: 1 uint8, 2 int8, 3 uint16, 4 int16, 5 uint32,
6 int32, 7 uint64, 8 int64, 9 float16, 10 float32, 11 float64.

A pBRDF file (Baek et al. 2020, "Image-Based Acquisition and Modeling of Polarimetric
Reflectance", as Mitsuba 3's measured_polarized.cpp reads it) holds the fields ``phi_d``,
``theta_d``, ``theta_h`` (float32, shape (1, n): the grid of each Rusinkiewicz angle, in
radians), ``wvls`` (uint16, (n,): the wavelengths in nm) and ``M`` (float32, (n_phi_d,
n_theta_d, n_theta_h, n_wvls, 4, 4): the Mueller matrix of the BRDF at every grid point).
"""

from __future__ import annotations

import mmap
import os
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

MAGIC = b"tensor_file\0"
DTYPES = {1: np.uint8, 2: np.int8, 3: np.uint16, 4: np.int16, 5: np.uint32, 6: np.int32,
          7: np.uint64, 8: np.int64, 9: np.float16, 10: np.float32, 11: np.float64}
CODES = {np.dtype(t): c for c, t in DTYPES.items()}
ANGLES = ("phi_d", "theta_d", "theta_h")  # M's first three axes, in this order


class TensorFileError(ValueError):
    """A file that is not a valid tensor file, or not the tensors expected; the message
    names the file."""


def read_tensor_file(path: str | Path) -> dict[str, np.ndarray]:
    """Every field of the tensor file at ``path``, by name (read-only arrays)."""
    path = Path(path)
    try:  # mapped, not read: a measured file is hundreds of MB, of which T keeps one copy
        with open(path, "rb") as f:
            data = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) \
                if os.fstat(f.fileno()).st_size else b""
    except OSError as e:
        raise TensorFileError(f"cannot read tensor file '{path}': {e.strerror}") from None
    if len(data) < 18 or data[:12] != MAGIC:
        raise TensorFileError(f"'{path}' is not a Mitsuba tensor file (it does not start with "
                              "the header 'tensor_file')")
    if tuple(data[12:14]) != (1, 0):
        raise TensorFileError(f"'{path}': unknown tensor file version {data[12]}.{data[13]} "
                              "(expected 1.0)")
    (count,) = struct.unpack_from("<I", data, 14)
    pos, fields = 18, {}
    try:
        for _ in range(count):
            (n,) = struct.unpack_from("<H", data, pos)
            name = data[pos + 2:pos + 2 + n].decode("utf-8")
            pos += 2 + n
            rank, code, offset = struct.unpack_from("<HBQ", data, pos)
            pos += 11
            shape = struct.unpack_from(f"<{rank}Q", data, pos)
            pos += 8 * rank
            if code not in DTYPES:
                raise TensorFileError(f"'{path}': field '{name}' has unknown dtype code {code}")
            dtype = np.dtype(DTYPES[code]).newbyteorder("<")
            size = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
            if offset + size > len(data):
                raise TensorFileError(f"'{path}': field '{name}' (shape {tuple(shape)}) runs past "
                                      f"the end of the file: truncated?")
            fields[name] = np.frombuffer(data, dtype, size // dtype.itemsize,
                                         offset).reshape(shape)
    except (struct.error, UnicodeDecodeError):
        raise TensorFileError(f"'{path}': the field table is truncated or corrupt") from None
    return fields


def write_tensor_file(path: str | Path, fields: dict[str, np.ndarray], align: int = 8) -> None:
    """Write ``fields`` as a tensor file (what ``mi.tensor_io.write`` writes)."""
    arrays = {k: np.ascontiguousarray(v) for k, v in fields.items()}
    head = bytearray(MAGIC + bytes((1, 0)) + struct.pack("<I", len(arrays)))
    table_size = sum(2 + len(k.encode()) + 11 + 8 * a.ndim for k, a in arrays.items())
    offset, offsets = len(head) + table_size, []
    for a in arrays.values():
        offset += -offset % align
        offsets.append(offset)
        offset += a.nbytes
    for (name, a), off in zip(arrays.items(), offsets):
        if a.dtype not in CODES:
            raise TypeError(f"field '{name}': dtype {a.dtype} has no tensor file code")
        label = name.encode()
        head += struct.pack("<H", len(label)) + label
        head += struct.pack("<HBQ", a.ndim, CODES[a.dtype], off)
        head += struct.pack(f"<{a.ndim}Q", *a.shape)
    out = bytearray(head)
    for a, off in zip(arrays.values(), offsets):
        out += bytes(off - len(out))
        out += a.astype(a.dtype.newbyteorder("<"), copy=False).tobytes()
    Path(path).write_bytes(bytes(out))


@dataclass(frozen=True)
class PBrdf:
    """A pBRDF table: the angle grids (radians), the wavelengths (nm) and the Mueller
    matrices ``M`` (n_phi_d, n_theta_d, n_theta_h, n_wvls, 4, 4)."""

    phi_d: np.ndarray
    theta_d: np.ndarray
    theta_h: np.ndarray
    wvls: np.ndarray
    M: np.ndarray


def read_pbrdf(path: str | Path) -> PBrdf:
    """The pBRDF table of the tensor file ``path``, its fields checked as Mitsuba 3's
    measured_polarized checks them (and M's last two axes, which Mitsuba leaves unchecked)."""
    f = read_tensor_file(path)
    missing = [k for k in (*ANGLES, "wvls", "M") if k not in f]
    if missing:
        raise TensorFileError(f"'{path}' has no field(s) {', '.join(repr(k) for k in missing)}; "
                              "a pBRDF file holds 'phi_d', 'theta_d', 'theta_h' (float32, shape "
                              "(1, n)), 'wvls' (uint16, (n,)) and 'M' (float32, (n_phi_d, "
                              f"n_theta_d, n_theta_h, n_wvls, 4, 4)); it has: {', '.join(f)}")

    def expect(name: str, dtype: type, rank: int, what: str) -> np.ndarray:
        a = f[name]
        if a.dtype != np.dtype(dtype) or a.ndim != rank:
            raise TensorFileError(f"'{path}': field '{name}' is {a.dtype} of shape {a.shape}; "
                                  f"expected {np.dtype(dtype)} of shape {what}")
        return a

    grids = [expect(k, np.float32, 2, "(1, n)") for k in ANGLES]
    wvls = expect("wvls", np.uint16, 1, "(n,)")
    m = expect("M", np.float32, 6, "(n_phi_d, n_theta_d, n_theta_h, n_wvls, 4, 4)")
    want = (*(g.shape[1] for g in grids), wvls.shape[0], 4, 4)
    if m.shape != want or min(want) < 1:
        raise TensorFileError(f"'{path}': field 'M' has shape {m.shape}; expected (n_phi_d, "
                              f"n_theta_d, n_theta_h, n_wvls, 4, 4) = {want} from the grids")
    return PBrdf(*(np.asarray(g[0], np.float32) for g in grids),
                 np.asarray(wvls, np.float32), np.asarray(m, np.float32))
