"""Write a synthetic polarimetric BRDF (pBRDF) as a Mitsuba 3 tensor file, the format of the
measured pBRDFs of Baek et al. 2020 that Mitsuba's (and rdsl's) `measured_polarized` reads.

The measured files cannot be downloaded here, so the tests use this one.  It is physically
plausible and smooth in every angle: a GGX microfacet lobe whose Mueller matrix is the
Fresnel reflection of a weakly absorbing interface (eta + i k varying with the wavelength) at
the difference angle theta_d, in the s/p basis, plus a depolarizing diffuse term that varies
with phi_d, plus small smooth entries in the otherwise zero places, so that every entry of a
lookup and of its frame rotation is exercised.  The theta_h grid is denser near 0 (not
uniform), as a specular lobe wants, so lookups must search their interval.

    python -m rdsl.tools.gen_pbrdf out.pbsdf [--nan]

``--nan`` marks the lookups with theta_d above 85 degrees invalid (NaN), as the measured
files mark configurations they did not observe.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from ..core.tensorfile import write_tensor_file

WAVELENGTHS = (450, 500, 550, 600, 650)


def _fresnel_mueller(cos_i: np.ndarray, eta: complex) -> np.ndarray:
    """The Mueller matrix (..., 4, 4) of a reflection at incidence cos_i on an interface
    of complex relative IOR eta, in the s/p basis."""
    ci = cos_i.astype(np.complex128)
    ct = np.sqrt(1 - (1 - ci * ci) / (eta * eta))
    a_s = (ci - eta * ct) / (ci + eta * ct)
    a_p = (eta * ci - ct) / (eta * ci + ct)
    r_s, r_p = abs(a_s) ** 2, abs(a_p) ** 2
    v = a_p * np.conj(a_s)
    m = np.zeros(cos_i.shape + (4, 4))
    m[..., 0, 0] = m[..., 1, 1] = 0.5 * (r_s + r_p)
    m[..., 0, 1] = m[..., 1, 0] = 0.5 * (r_s - r_p)
    m[..., 2, 2] = m[..., 3, 3] = v.real
    m[..., 2, 3], m[..., 3, 2] = -v.imag, v.imag
    return m


def synthetic_pbrdf(n_phi: int = 13, n_theta_d: int = 10, n_theta_h: int = 12,
                    alpha: float = 0.25, nan_above: float | None = None,
                    reciprocal: bool = False) -> dict[str, np.ndarray]:
    """The fields of a pBRDF tensor file (``phi_d``, ``theta_d``, ``theta_h``, ``wvls``,
    ``M``), ``nan_above`` (degrees of theta_d) marking larger angles invalid.  Swapping wi
    and wo turns phi_d by pi: the diffuse term varies as cos(phi_d), which tells the two
    apart, unless ``reciprocal`` (cos(2 phi_d): M[0][0] symmetric, as a physical pBRDF's)."""
    phi = np.linspace(-np.pi, np.pi, n_phi)
    td = np.linspace(0.0, np.pi / 2, n_theta_d)
    th = np.pi / 2 * np.linspace(0.0, 1.0, n_theta_h) ** 2
    wl = np.array(WAVELENGTHS, np.float64)
    P, TD, TH, WL = np.meshgrid(phi, td, th, wl, indexing="ij")
    x = (WL - 550.0) / 100.0
    eta = (1.6 - 0.15 * x) + 1j * (0.4 + 0.2 * x)
    a2 = alpha * alpha
    c2 = np.cos(TH) ** 2
    d = a2 / (np.pi * (c2 * (a2 - 1) + 1) ** 2)  # GGX
    spec = _fresnel_mueller(np.cos(TD), eta) * (d / 4)[..., None, None]
    lobe = np.cos(2 * P if reciprocal else P)
    rho = (0.25 + 0.1 * x) * (1 + 0.3 * lobe) * np.cos(TD) ** 0.5 / np.pi
    m = spec.copy()
    m[..., 0, 0] += rho
    # small smooth entries where the Fresnel matrix has zeros
    wiggle = 0.01 * rho * np.sin(TD) * (1 + np.sin(P + TH))
    for k, (i, j) in enumerate([(0, 2), (0, 3), (1, 2), (1, 3), (2, 0), (2, 1), (3, 0),
                                (3, 1)]):
        m[..., i, j] += wiggle * (1 + 0.1 * k) * (-1) ** k
    if nan_above is not None:
        m[TD > np.radians(nan_above)] = np.nan
    return {"phi_d": phi[None].astype(np.float32), "theta_d": td[None].astype(np.float32),
            "theta_h": th[None].astype(np.float32), "wvls": wl.astype(np.uint16),
            "M": m.astype(np.float32)}


def write(path: str | Path, **kwargs: object) -> Path:
    """Write :func:`synthetic_pbrdf` (its keyword arguments) to ``path``."""
    write_tensor_file(path, synthetic_pbrdf(**kwargs))  # type: ignore[arg-type]
    return Path(path)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("--nan", action="store_true", help="mark theta_d > 85 degrees invalid")
    a = ap.parse_args(argv)
    write(a.out, nan_above=85.0 if a.nan else None)
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
