"""`lift`: one Spectrum source, two color models (mono and rgb), checked against values
computed by hand; and the traits of `if const`."""

from __future__ import annotations

import numpy as np
import pytest
import rdsl
from rdsl.compiler.build import Build
from rdsl.compiler.diagnostics import CompileError
from rdsl.compiler.driver import frontend, pipeline, run_passes
from rdsl.compiler.ir import F32, SpectrumType, VecType

SRC = """
fn tint(x: Float) -> Spectrum {
    let s = Spectrum(0.25, 0.5, 1.0) * x + 0.125;
    var out = s * Spectrum(2.0);
    if const rgb { out = out + mean(s); }
    if const mono { out = out - max_value(s); }
    return out;
}
"""
LUM = np.array([0.212671, 0.715160, 0.072169], np.float32)


def test_rgb():
    x = np.array([0.0, 1.0, 2.0, -4.0], np.float32)
    got = rdsl.jit(SRC, target="scalar", variant="rgb").tint(x)
    s = np.float32([0.25, 0.5, 1.0])[None, :] * x[:, None] + np.float32(0.125)
    want = s * np.float32(2.0) + (s[:, 0] + s[:, 1] + s[:, 2])[:, None] / np.float32(3)
    assert got.shape == (4, 3)
    np.testing.assert_array_equal(got, want.astype(np.float32))


def test_mono_uses_luminance():
    x = np.array([0.0, 1.0, 2.0, -4.0], np.float32)
    got = rdsl.jit(SRC, target="avx2", variant="mono").tint(x)
    lum = np.float32(LUM[0] * np.float32(0.25)) + np.float32(LUM[1] * np.float32(0.5)) \
        + np.float32(LUM[2] * np.float32(1.0))
    s = lum * x + np.float32(0.125)
    assert got.shape == (4,)
    np.testing.assert_allclose(got, s * 2 - s, rtol=1e-6)


@pytest.mark.parametrize("variant,concrete", [("mono", F32), ("rgb", VecType(3))])
def test_no_spectrum_type_survives(variant, concrete):
    m = frontend(SRC)
    run_passes(m, pipeline(Build.of("scalar", variant)), stop_after="lift")
    fn = m.functions["tint"]
    assert fn.ret_types == [concrete]
    for ins in fn.walk():
        assert "trait" not in ins.attrs
        for v in ins.results:
            assert not isinstance(v.type, SpectrumType)
        assert not ins.op.value.startswith("spec.")


def test_unknown_variant():
    with pytest.raises(CompileError, match="unknown variant `cmyk`.*mono, rgb, spectral"):
        rdsl.jit(SRC, target="scalar", variant="cmyk")


def test_mono_polarized_is_mono_times_identity():
    """Colours are unpolarized: u times the identity Mueller matrix, u as in mono."""
    x = np.array([0.0, 1.0, 2.0, -4.0], np.float32)
    mono = rdsl.jit(SRC, target="avx2", variant="mono").tint(x)
    out = rdsl.jit(SRC, target="avx2", variant="mono_polarized").tint(x)  # a dict of entries
    got = np.stack([np.asarray(out[f"m{i}{j}"]) for i in range(4) for j in range(4)], 1)
    got = got.reshape(4, 4, 4)
    np.testing.assert_allclose(got, mono[:, None, None] * np.eye(4)[None], rtol=1e-6)
