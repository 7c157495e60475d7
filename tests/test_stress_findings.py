"""What ``rdsl stress`` found in the stdlib BSDFs, each at the inputs where it failed, against
an independent truth (a numerical integral of the Fresnel equations, or Mitsuba 3)."""

from __future__ import annotations

import numpy as np
import pytest
from rdsl.runtime.testkit.common import surface, tile
from rdsl.runtime.testkit.harness import Harness


def fresnel(c: np.ndarray, eta: float) -> np.ndarray:
    """Unpolarized dielectric Fresnel reflectance at cos theta_i = c (float64)."""
    ct2 = 1 - (1 - c * c) / eta**2
    ct = np.sqrt(np.maximum(ct2, 0))
    rs, rp = (c - eta * ct) / (c + eta * ct), (eta * c - ct) / (eta * c + ct)
    return np.where(ct2 > 0, 0.5 * (rs * rs + rp * rp), 1.0)


def diffuse_fresnel(eta: float) -> float:
    """2 * integral of F(mu, eta) mu dmu by 2000-point Gauss-Legendre."""
    x, w = np.polynomial.legendre.leggauss(2000)
    mu = 0.5 * (x + 1)
    return float(np.sum(0.5 * w * 2 * mu * fresnel(mu, eta)))


@pytest.mark.parametrize("int_ior", [2.5, 3.85, 4.0, 5.0])
def test_plastic_diffuse_lobe_at_high_ior(int_ior):
    """`plastic` went negative at int_ior >= 3.85 (Mitsuba 3's too: -27.05 at 3.85, -0.33 at
    4): the fit for the internal diffuse Fresnel reflectance exceeded 1 there. Against the
    lobe with the exact integral, rho (1 - F_i)(1 - F_o) / (1 - Fdr_int) / eta^2 cos / pi."""
    eta = int_ior / 1.000277
    cos_o = np.array([0.8, 0.3, 1e-3])
    wo = np.stack([np.sqrt(1 - cos_o**2), 0 * cos_o, cos_o], 1).astype(np.float32)
    got = np.asarray(Harness("plastic", "mono").eval(
        surface(tile(np.array([0, 0, 1], np.float32), 3)), wo, int_ior=int_ior), np.float64)
    rho = 0.5
    want = (rho / (1 - diffuse_fresnel(1 / eta)) / eta**2 * (1 - fresnel(np.ones(1), eta))
            * (1 - fresnel(cos_o, eta)) * cos_o / np.pi)
    assert np.allclose(got.reshape(-1), want, rtol=5e-3), (got, want)
