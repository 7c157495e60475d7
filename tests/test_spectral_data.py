"""Spectral data and the host spectral math (core/spectral.py, tools/rgb2spec_opt.py).

Checked against independent truth: known colorimetric constants, closed-form integrals of the
wavelength density, the upsampling round trip, a fresh optimizer run, and, where the
``mitsuba`` package is installed, Mitsuba 3's own functions and plugins."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rdsl.core import spectral as sp
from rdsl.tools import rgb2spec_opt as opt

GRID = sp.LAMBDA_MIN + 5.0 * np.arange(sp.CIE_SAMPLES)


def xyz_under(spectrum_on_grid: np.ndarray) -> np.ndarray:
    """Riemann sum over the 5 nm grid of the CIE curves times a spectrum."""
    return (sp.cie_table() * spectrum_on_grid[:, None]).sum(axis=0) * 5.0


def quadrature_lambda() -> np.ndarray:
    return sp.LAMBDA_MIN + (sp.LAMBDA_MAX - sp.LAMBDA_MIN) * opt.quadrature().t


# -- tables and constants -------------------------------------------------------------------

def test_tables_have_mitsubas_grid_and_shape():
    assert sp.cie_table().shape == (95, 3) and sp.cie_table().dtype == np.float64
    assert sp.d65_table().shape == (95,)
    assert sp.d65_table()[40] == 100.0                      # relative to 560 nm
    assert np.argmax(sp.cie_table()[:, 1]) == (555 - 360) // 5  # ybar peaks at 555 nm
    np.testing.assert_array_equal(sp.cie_xyz(GRID), sp.cie_table())
    np.testing.assert_array_equal(sp.d65(GRID), sp.d65_table())


def test_ybar_integrates_to_the_cie_constant():
    # The 5 nm table's integral is PBRT's CIE_Y_integral; Mitsuba normalises by its own
    # 106.7502594 instead, so a unit spectrum has luminance 1.000999 there (and here).
    assert xyz_under(np.ones(95))[1] == pytest.approx(106.856895, rel=2e-6)
    assert sp.CIE_Y_INTEGRAL == 106.7502593994140625
    lam, weight = sp.sample_wavelengths((np.arange(200_000) + 0.5) / 200_000)
    y = np.mean(np.mean(sp.cie_xyz(lam)[..., 1] * weight, axis=-1)) / sp.CIE_Y_INTEGRAL
    assert y == pytest.approx(106.856895 / 106.7502594, rel=2e-4)


def test_d65_has_the_d65_white_point():
    X, Y, Z = xyz_under(sp.d65_table())
    assert X / (X + Y + Z) == pytest.approx(0.3127, abs=1e-4)
    assert Y / (X + Y + Z) == pytest.approx(0.3290, abs=1e-4)
    # D65_NORMALIZATION makes the illuminant's luminance ~1 (Mitsuba: = 106.75 / 10568).
    assert Y * sp.D65_NORMALIZATION / sp.CIE_Y_INTEGRAL == pytest.approx(1.0, abs=1e-4)


def film_expectation(spectrum, n: int = 100_000) -> np.ndarray:
    """What the film converges to for a spectrum: stratified u through the real pipeline."""
    lam, weight = sp.sample_wavelengths((np.arange(n) + 0.5) / n)
    return sp.spectrum_to_srgb(spectrum(lam), lam, weight).mean(axis=0)


def test_film_conversion_of_white_emitters():
    # An <rgb value="1 1 1"/> radiance becomes the normalised D65 spectrum, which the film
    # turns back into white: this is the convention the d65 plugin's scale was chosen for.
    coeffs, scale = sp.illuminant_from_rgb(np.ones(3))
    assert scale == 2.0
    rgb = film_expectation(
        lambda lam: sp.eval_coeffs(coeffs, lam) * scale * sp.d65(lam) * sp.D65_NORMALIZATION)
    np.testing.assert_allclose(rgb, 1.0, atol=1e-3)
    # A unit (equal-energy) spectrum is not white in sRGB: it is XYZ = (1, 1, 1) x 1.001.
    xyz = np.linalg.solve(sp.XYZ_TO_SRGB, film_expectation(np.ones_like))
    np.testing.assert_allclose(xyz, xyz_under(np.ones(95)) / sp.CIE_Y_INTEGRAL, rtol=2e-4)


def test_illuminant_from_rgb_scales_by_twice_the_maximum():
    rgb = np.array([18.387, 13.9873, 6.75357])
    coeffs, scale = sp.illuminant_from_rgb(rgb)
    assert scale == pytest.approx(2 * 18.387)
    np.testing.assert_array_equal(coeffs, sp.rgb_to_coeffs(rgb / scale))
    grey_coeffs, grey_scale = sp.illuminant_from_rgb(np.full(3, 5.0))
    np.testing.assert_array_equal(grey_coeffs, 0.0)   # the constant 0.5, times scale 10
    assert grey_scale == 10.0
    black_coeffs, black_scale = sp.illuminant_from_rgb(np.zeros(3))
    assert black_scale == 0.0 and np.all(np.isfinite(black_coeffs))
    batch_coeffs, batch_scale = sp.illuminant_from_rgb(np.stack([rgb, np.full(3, 5.0)]))
    assert batch_coeffs.shape == (2, 3)
    np.testing.assert_array_equal(batch_scale, [2 * 18.387, 10.0])


# -- wavelength sampling --------------------------------------------------------------------

def test_wavelength_pdf_integrates_to_one():
    lam = np.linspace(sp.LAMBDA_MIN, sp.LAMBDA_MAX, 200_001)
    assert np.trapezoid(sp.wavelength_pdf(lam), lam) == pytest.approx(1.0, abs=1e-6)
    assert sp.wavelength_pdf(359.9) == 0.0 and sp.wavelength_pdf(830.1) == 0.0


def test_sample_wavelengths_range_shift_and_weight():
    u = np.random.default_rng(3).random(10_000)
    lam, weight = sp.sample_wavelengths(u)
    assert lam.shape == weight.shape == (10_000, 4)
    assert lam.min() >= sp.LAMBDA_MIN and lam.max() <= sp.LAMBDA_MAX
    # The four wavelengths come from u, u + 1/4, u + 1/2, u + 3/4 wrapped into [0, 1].
    for i in range(4):
        shifted = (u + i / 4) % 1.0
        np.testing.assert_allclose(lam[:, i], sp.sample_wavelengths(shifted)[0][:, 0],
                                   rtol=1e-12)
    np.testing.assert_allclose(weight, 1.0 / sp.wavelength_pdf(lam), rtol=2e-6)
    # Mitsuba wraps only values above 1, so u = 1/4 maps its last wavelength from exactly 1.
    assert sp.sample_wavelengths(0.25)[0][3] == sp.sample_wavelengths(1.0)[0][0]


def test_sampled_wavelengths_follow_the_pdf():
    n = 400_000
    lam = sp.sample_wavelengths(np.random.default_rng(7).random(n // 4))[0].ravel()
    fine = np.linspace(sp.LAMBDA_MIN, sp.LAMBDA_MAX, 47_001)
    pdf = sp.wavelength_pdf(fine)
    cdf = np.concatenate([[0.0], np.cumsum(0.5 * (pdf[1:] + pdf[:-1]) * np.diff(fine))])
    # Kolmogorov-Smirnov against the analytic density (the 4 shifted samples of one u are
    # each exactly distributed; the statistic uses all of them).
    ordered = np.sort(lam)
    model = np.interp(ordered, fine, cdf)
    empirical = np.arange(1, n + 1) / n
    assert np.max(np.abs(empirical - model)) < 1.63 / np.sqrt(n / 4)   # alpha = 0.01
    # Chi-square over 47 bins of 10 nm.
    edges = np.linspace(sp.LAMBDA_MIN, sp.LAMBDA_MAX, 48)
    counts = np.histogram(lam, edges)[0]
    expected = n * np.diff(np.interp(edges, fine, cdf))
    chi2 = np.sum((counts - expected) ** 2 / expected)
    assert chi2 < 4 * 47   # stratified shifts make this far smaller than a free chi^2(46)


# -- the sigmoid-polynomial model -----------------------------------------------------------

def test_eval_coeffs_stays_in_the_unit_interval():
    rng = np.random.default_rng(11)
    magnitude = 10.0 ** rng.uniform(-5, 300, size=(5000, 3))
    coeffs = magnitude * rng.choice([-1.0, 1.0], size=(5000, 3))
    lam = np.linspace(300.0, 900.0, 61)
    with np.errstate(all="raise"):
        values = sp.eval_coeffs(coeffs, lam)
    assert values.shape == (5000, 61)
    assert np.all((values >= 0.0) & (values <= 1.0))
    special = np.array([[0, 0, np.inf], [0, 0, -np.inf], [0, 0, 0], [np.inf, -np.inf, 0],
                        [np.nan, 0, 0], [1e308, -1e308, 1e308]])
    out = sp.eval_coeffs(special, lam)
    assert np.all((out >= 0.0) & (out <= 1.0))
    np.testing.assert_array_equal(out[:3], [[1.0] * 61, [0.0] * 61, [0.5] * 61])
    assert sp.eval_coeffs(special[:3], 500.0).shape == (3,)


def test_rgb_to_coeffs_edge_inputs():
    lam = np.linspace(400.0, 700.0, 31)
    np.testing.assert_allclose(sp.eval_coeffs(sp.rgb_to_coeffs(np.zeros(3)), lam), 0.0,
                               atol=1e-6)
    np.testing.assert_allclose(sp.eval_coeffs(sp.rgb_to_coeffs(np.ones(3)), lam), 1.0,
                               atol=1e-6)
    np.testing.assert_allclose(sp.eval_coeffs(sp.rgb_to_coeffs(np.full(3, 0.3)), lam), 0.3,
                               atol=1e-12)
    np.testing.assert_array_equal(sp.rgb_to_coeffs([1.5, -0.2, 0.3]),
                                  sp.rgb_to_coeffs([1.0, 0.0, 0.3]))
    np.testing.assert_array_equal(sp.rgb_to_coeffs([np.nan, 0.2, 0.3]),
                                  sp.rgb_to_coeffs([1.0, 0.2, 0.3]))
    np.testing.assert_array_equal(sp.rgb_to_coeffs([7.0, 7.0, 7.0]), [0.0, 0.0, 8192.0])
    batch = np.random.default_rng(5).uniform(-0.5, 1.5, size=(4, 5, 3))
    coeffs = sp.rgb_to_coeffs(batch)
    assert coeffs.shape == (4, 5, 3) and np.all(np.isfinite(coeffs))
    np.testing.assert_array_equal(coeffs[2, 3], sp.rgb_to_coeffs(batch[2, 3]))


def test_upsampling_round_trip_over_the_gamut():
    axis = np.linspace(0.0, 1.0, 16)
    rgb = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), axis=-1).reshape(-1, 3)
    spectra = sp.eval_coeffs(sp.rgb_to_coeffs(rgb), quadrature_lambda())
    error = np.abs(opt.reflectance_rgb(spectra) - rgb)
    assert error.max() < 1e-3, f"max {error.max():.2e} mean {error.mean():.2e}"


def test_committed_table_reproduces_every_cell():
    scale, data = sp._rgb2spec()
    res = scale.shape[0]
    assert res == 64 and data.shape == (3, res, res, res, 3)
    np.testing.assert_array_equal(scale, opt.scale_axis(res))
    m, k, j, i = np.meshgrid(*(np.arange(n) for n in data.shape[:4]), indexing="ij")
    target = np.zeros(data.shape)
    rows = np.arange(3)
    for channel, value in ((m, scale[k]), ((m + 1) % 3, i / (res - 1) * scale[k]),
                           ((m + 2) % 3, j / (res - 1) * scale[k])):
        target[..., :] += (channel[..., None] == rows) * value[..., None]
    worst = 0.0
    for k in range(res):   # one brightness at a time keeps the spectra array small
        spectra = sp.eval_coeffs(data[:, k].reshape(-1, 3), quadrature_lambda())
        rgb = opt.reflectance_rgb(spectra).reshape(target[:, k].shape)
        worst = max(worst, np.abs(rgb - target[:, k]).max())
    assert worst < 2e-4


def test_fresh_fit_matches_the_committed_table():
    # Every 9th sample of the res-64 axes is a sample of the res-8 axes: (8-1) * 9 = 64-1.
    scale, data = opt.optimize(8)
    assert scale.dtype == data.dtype == np.float32 and data.shape == (3, 8, 8, 8, 3)
    committed_scale, committed = sp._rgb2spec()
    np.testing.assert_array_equal(scale, committed_scale[::9])
    lam = quadrature_lambda()
    fresh = sp.eval_coeffs(data.reshape(-1, 3).astype(np.float64), lam)
    stored = sp.eval_coeffs(committed[:, ::9, ::9, ::9].reshape(-1, 3), lam)
    assert np.abs(opt.reflectance_rgb(fresh) - opt.reflectance_rgb(stored)).max() < 1e-4
    # Spectra agree where the colour constrains them (not in the darkest cells, where any
    # near-zero curve fits, nor where the CIE curves vanish).
    visible = (lam >= 420.0) & (lam <= 680.0)
    bright = np.broadcast_to((committed_scale[::9] >= 0.05)[None, :, None, None],
                             (3, 8, 8, 8)).ravel()
    assert np.abs(fresh - stored)[bright][:, visible].max() < 1e-3


def test_optimizer_command_line(tmp_path):
    out = tmp_path / "table.npz"
    assert opt.main(["--res", "4", "--out", str(out)]) == 0
    with np.load(out) as f:
        assert f["scale"].shape == (4,) and f["data"].shape == (3, 4, 4, 4, 3)


# -- tabulated spectra ----------------------------------------------------------------------

IOR = sorted((Path(sp.__file__).resolve().parents[1] / "stdlib" / "data" / "ior").glob("*.spd"))


def read_spd(path: Path) -> tuple[np.ndarray, np.ndarray]:
    rows = [ln.split() for ln in path.read_text().splitlines()
            if ln.strip() and not ln.startswith("#")]
    return np.array([float(r[0]) for r in rows]), np.array([float(r[1]) for r in rows])


def knots_interpolant(w: np.ndarray, v: np.ndarray, lam: np.ndarray) -> np.ndarray:
    """The truth: np.interp of the knots inside them and 360..830 nm, 0 elsewhere."""
    lam = np.asarray(lam, np.float64)
    inside = (lam >= max(w[0], 360.0)) & (lam <= min(w[-1], 830.0))
    return np.where(inside, np.interp(lam, w, v), 0.0)


def probes(w: np.ndarray) -> np.ndarray:
    """float32 wavelengths: on each knot and either side of it, the ends of 360..830 nm, a
    dense sweep beyond them."""
    k = np.asarray(w, np.float32)
    ends = np.float32([359.99997, 360.0, 360.00003, 829.99994, 830.0, 830.00006])
    return np.concatenate([k, np.nextafter(k, np.float32(0)), np.nextafter(k, np.float32(1e4)),
                           ends, np.linspace(350.0, 840.0, 49001, dtype=np.float32)])


def test_tabulated_is_linear_inside_and_zero_outside():
    w, v = [450.0, 550.0, 650.0], [0.3, 0.5, 0.1]
    out = sp.tabulated(w, v, [449.9, 450.0, 500.0, 600.0, 650.0, 650.1])
    np.testing.assert_allclose(out, [0.0, 0.3, 0.4, 0.3, 0.1, 0.0], rtol=1e-12)
    # beyond 360..830 nm, where no wavelength is sampled, it is 0 like the CIE curves
    np.testing.assert_array_equal(sp.tabulated([300.0, 900.0], [1.0, 1.0], [359.0, 831.0]), 0.0)


SPECTRA = [(p.name, *read_spd(p)) for p in IOR] + [
    ("user", np.array([412.3, 433.7, 441.0, 500.2, 600.25, 601.0, 650.0, 777.7]),
     np.array([0.1, 0.9, 0.05, 0.0, 2.5, 0.3, 0.3, 1.2])),
    ("5 nm grid", GRID[10:80], 0.5 + 0.4 * np.sin(GRID[10:80] / 17.0)),
    ("0.5 nm grid", np.arange(380.0, 800.0, 0.5), 1.0 + 0.5 * np.cos(np.arange(840) / 7.0)),
    ("one knot", np.array([500.0]), np.array([0.7])),
    ("beyond 830", np.array([840.0, 900.0]), np.array([1.0, 2.0])),
]


@pytest.mark.parametrize("name,w,v", SPECTRA, ids=[s[0] for s in SPECTRA])
def test_cells_are_exact(name, w, v):
    """Both tables of cells, the specialized build's (fitted to the knots) and the generic
    build's (1 nm, fixed), give the knots' interpolant to float32 rounding wherever no cell
    holds two knots: the named conductors' tables, irregular knots, 5 and 0.5 nm grids."""
    lam = probes(w)
    want = knots_interpolant(w, v, lam)
    outside = (lam < max(w[0], 360.0)) | (lam > min(w[-1], 830.0))
    for cells in (sp.tabulated_cells(w, v), sp.generic_cells(sp.tabulated_slot(w, v))):
        got = sp.eval_cells(cells, lam)
        np.testing.assert_array_equal(got[outside], 0.0)
        err = np.abs(got - want)
        crowded = crowded_cells(cells, w, lam)  # only the generic build's 1 nm cells crowd
        assert np.all(err[~crowded] <= 3e-7 * np.abs(want[~crowded]) + 1e-7 * v.max()), \
            err[~crowded].max()
        # a crowded cell keeps one of its knots: it errs by at most the others' departure
        # from the chord, less than the values' spread over the cell and its neighbours
        for j in (np.unique(cell_index(cells, lam[crowded])) if crowded.any() else []):
            near = (w >= cells.start + (j - 1) * cells.width) & \
                (w <= cells.start + (j + 2) * cells.width)
            in_j = crowded & (cell_index(cells, lam) == j)
            assert err[in_j].max() <= np.ptp(v[near]) + 1e-6, (j, err[in_j].max())
    cells = sp.tabulated_cells(w, v)
    if cells is not None:  # no wider than the spacing of the knots inside its domain
        inner = w[(w > cells.lo) & (w < cells.hi)]
        if inner.size > 1:
            assert cells.width <= np.diff(inner).min()
    crowd = np.diff(w[(w > 360.0) & (w < 830.0)]) if w.size > 1 else np.array([1.0])
    if crowd.size and crowd.min() >= 1.0:  # then no cell of either build crowds
        assert not crowded_cells(sp.generic_cells(sp.tabulated_slot(w, v)), w, lam).any()


def cell_index(cells: sp.Cells, lam: np.ndarray) -> np.ndarray:
    t = (np.asarray(lam, np.float64) - cells.start) / cells.width
    return np.clip(np.floor(t), 0, cells.count - 1).astype(int)


def crowded_cells(cells: sp.Cells | None, w: np.ndarray, lam: np.ndarray) -> np.ndarray:
    """Which probes lie in a cell holding two knots or more strictly inside it."""
    if cells is None:
        return np.zeros(lam.shape, bool)
    edges = cells.start + cells.width * np.arange(cells.count + 1)
    inside = np.searchsorted(w, edges[1:], "left") - np.searchsorted(w, edges[:-1], "right")
    return inside[cell_index(cells, lam)] >= 2


def test_crowded_cells_interpolate_within_a_cell():
    """Knots closer than the cells are wide (0.3 nm, off the cells' grid, for the generic
    build's 1 nm cells; 0.05 nm, past the specialized build's 4096-cell cap): a smooth
    curve's interpolant is then followed within the error of linear interpolation over one
    cell, h^2/8 max|f''| plus that of the knots' own, and is exact at the cells' ends."""
    def g(x: np.ndarray) -> np.ndarray:  # |g''| <= 0.5 / 400
        return 1.0 + 0.5 * np.sin(x / 20.0)

    lam = np.linspace(360.0, 830.0, 200001, dtype=np.float32)
    for step, generic in ((0.3, True), (0.05, False)):
        w = np.arange(300.17, 900.0, step)
        v = g(w)
        c = sp.generic_cells(sp.tabulated_slot(w, v)) if generic else sp.tabulated_cells(w, v)
        assert c.count == (sp.GENERIC_CELLS if generic else sp.CELL_CAP)
        err = np.abs(sp.eval_cells(c, lam) - knots_interpolant(w, v, lam)).max()
        bound = (c.width ** 2 + step ** 2) / 8.0 * 0.5 / 400.0
        assert err <= bound + 1e-6, (step, err, bound)
        ends = np.float32(c.start + c.width * np.arange(c.count + 1))
        np.testing.assert_allclose(sp.eval_cells(c, ends), knots_interpolant(w, v, ends),
                                   rtol=1e-6)


def test_spectrum_to_rgb_reflectance():
    # A unit reflectance under D65 is white; the clamp keeps the result in [0, 1].
    np.testing.assert_allclose(sp.spectrum_to_rgb_reflectance([360.0, 830.0], [1.0, 1.0]),
                               1.0, atol=2e-3)
    rgb = sp.spectrum_to_rgb_reflectance([400.0, 500.0, 600.0, 700.0], [2.0, 3.0, 0.1, 0.9])
    np.testing.assert_array_equal(rgb, [0.0, 1.0, 1.0])
    assert sp.spectrum_to_rgb_emission([400.0, 500.0, 600.0, 700.0],
                                       [2.0, 3.0, 0.1, 0.9]).max() > 1.0


# -- Mitsuba 3 itself -----------------------------------------------------------------------

@pytest.fixture(scope="module")
def mi():
    mitsuba = pytest.importorskip("mitsuba", reason="the mitsuba package is not installed")
    previous = mitsuba.variant()
    try:
        mitsuba.set_variant("scalar_spectral")
    except Exception as e:   # noqa: BLE001 - any failure means no cross-check here
        pytest.skip(f"mitsuba variant scalar_spectral unavailable: {e}")
    yield mitsuba
    if previous is not None:
        mitsuba.set_variant(previous)


COLORS = [(0.2, 0.5, 0.7), (0.9, 0.1, 0.05), (0.05, 0.8, 0.1), (0.02, 0.03, 0.9),
          (1.0, 0.0, 1.0), (0.7, 0.7, 0.2), (0.35, 0.35, 0.35), (1.0, 1.0, 1.0),
          (0.0, 0.0, 0.0), (0.12, 0.95, 0.97)]
PROBE = [360.0, 400.0, 455.5, 500.0, 538.0, 600.0, 650.0, 700.0, 780.0, 830.0]


def mi_eval(mi, texture, lam: list[float]) -> np.ndarray:
    out = []
    for i in range(0, len(lam), 4):
        chunk = (lam[i:i + 4] + [550.0] * 4)[:4]
        si = mi.SurfaceInteraction3f()
        si.wavelengths = mi.Spectrum(chunk)
        out.extend(list(texture.eval(si))[:len(lam[i:i + 4])])
    return np.array(out)


def test_mitsuba_constants(mi):
    assert 1.0 / mi.MI_CIE_Y_NORMALIZATION == pytest.approx(sp.CIE_Y_INTEGRAL, rel=1e-12)
    assert mi.MI_CIE_D65_NORMALIZATION == pytest.approx(sp.D65_NORMALIZATION, rel=1e-12)
    assert (mi.MI_CIE_MIN, mi.MI_CIE_MAX) == (sp.LAMBDA_MIN, sp.LAMBDA_MAX)


def test_mitsuba_wavelength_sampling(mi):
    for u in (0.0, 1e-4, 0.1, 0.3, 0.5, 0.77, 0.999, 1.0):
        lam, weight = mi.sample_rgb_spectrum(u)
        ours_lam, ours_weight = sp.sample_wavelengths(u)
        assert ours_lam[0] == pytest.approx(lam, abs=2e-3)
        assert ours_weight[0] == pytest.approx(weight, rel=1e-5)
        assert sp.wavelength_pdf(lam) == pytest.approx(mi.pdf_rgb_spectrum(lam), rel=1e-5)


def test_mitsuba_cie_and_d65(mi):
    lam = np.concatenate([np.random.default_rng(2).uniform(350.0, 840.0, 200), GRID])
    theirs = np.array([list(mi.cie1931_xyz(float(v))) for v in lam])
    np.testing.assert_allclose(sp.cie_xyz(lam), theirs, rtol=1e-5, atol=1e-9)
    d65 = np.array([mi.cie_d65(float(v)) for v in lam])
    np.testing.assert_allclose(sp.d65(lam) * sp.D65_NORMALIZATION, d65, rtol=1e-5, atol=1e-9)


def test_mitsuba_srgb_reflectance_spectra(mi):
    lam = PROBE
    for rgb in COLORS:
        theirs = mi_eval(mi, mi.load_dict({"type": "srgb", "color": list(rgb)}), lam)
        ours = sp.eval_coeffs(sp.rgb_to_coeffs(np.array(rgb)), np.array(lam))
        np.testing.assert_allclose(ours, theirs, atol=1e-3, err_msg=str(rgb))


def test_mitsuba_rgb_radiance(mi):
    lam = PROBE
    for rgb in ([18.387, 13.9873, 6.75357], [1.0, 1.0, 1.0], [0.3, 2.0, 0.1], [4.0, 4.0, 4.0]):
        # An <rgb> radiance inside an emitter, evaluated by the emitter itself.
        emitter = mi.load_dict({"type": "constant", "radiance": {"type": "rgb", "value": rgb}})
        theirs = mi_eval(mi, emitter, lam)
        coeffs, scale = sp.illuminant_from_rgb(np.array(rgb))
        ours = sp.eval_coeffs(coeffs, np.array(lam)) * scale * sp.d65(np.array(lam)) \
            * sp.D65_NORMALIZATION
        np.testing.assert_allclose(ours, theirs, rtol=1e-3, atol=1e-3 * scale, err_msg=str(rgb))


def test_mitsuba_film_conversion(mi):
    rng = np.random.default_rng(9)
    for _ in range(10):
        lam, weight = sp.sample_wavelengths(rng.random())
        values = rng.uniform(0.0, 3.0, 4)
        theirs = mi.spectrum_to_srgb(mi.Spectrum(values * weight), mi.Spectrum(lam))
        theirs = np.array(list(theirs))
        # Mitsuba sums in float32, so compare relative to the largest channel.
        np.testing.assert_allclose(sp.spectrum_to_srgb(values, lam, weight), theirs,
                                   atol=1e-5 * np.abs(theirs).max())


def test_mitsuba_tabulated_spectra(mi):
    """Mitsuba's `irregular` spectrum is the knots' interpolant: at and beside its knots,
    inside and outside them (gold's eta as `material="Au"` loads it, and four knots)."""
    for lam, values in (read_spd(IOR[[p.name for p in IOR].index("Au.eta.spd")]),
                        ([400.0, 480.0, 560.0, 700.0], [0.2, 0.9, 0.4, 0.7])):
        lam, values = list(map(float, lam)), list(map(float, values))
        irregular = mi.load_dict({"type": "irregular", "wavelengths": ", ".join(map(repr, lam)),
                                  "values": ", ".join(map(repr, values))})
        k = np.float32(lam)
        beside = [np.nextafter(k, np.float32(0)), np.nextafter(k, np.float32(1e4))]
        probe = np.concatenate([k, *beside, GRID, [395.0, 705.0]]).astype(np.float32)
        probe = probe[(probe >= 360.0) & (probe <= 830.0)]
        theirs = mi_eval(mi, irregular, [float(x) for x in probe])
        np.testing.assert_allclose(sp.tabulated(lam, values, probe), theirs, rtol=2e-6,
                                   atol=1e-7)
    for d65, ours in ((True, sp.spectrum_to_rgb_reflectance),
                      (False, sp.spectrum_to_rgb_emission)):
        theirs = mi.spectrum_list_to_srgb(lam, values, bounded=d65, d65=d65)
        np.testing.assert_allclose(ours(lam, values), list(theirs), rtol=1e-5, atol=1e-6)
