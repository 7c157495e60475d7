"""``rdsl bench``: time against error on the Cornell box at 16x16.  The RMSE is taken
against a reference rendered at 16x the largest spp (by rdsl, or by Mitsuba 3 itself with
``--vs mitsuba``); it must fall as spp grows.  Bad input: one line, status 1, no traceback."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from _scenes import CBOX

ROOT = Path(__file__).resolve().parents[1]
SMALL = ["-D", "res=16"]


def rdsl(*args: str, tmp: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, MPLBACKEND="Agg")
    return subprocess.run([sys.executable, "-m", "rdsl.cli", "bench", *args], cwd=tmp,
                          capture_output=True, text=True, env=env, timeout=300)


def table(out: str) -> dict[tuple[str, str, str], dict[int, tuple[float, float]]]:
    """(renderer, target, variant) -> spp -> (seconds, RMSE), from the printed table."""
    lines = out.splitlines()
    head = next(i for i, line in enumerate(lines) if line.split()[:1] == ["renderer"])
    rows: dict = {}
    for line in lines[head + 1:]:
        f = line.split()
        if len(f) != 6:
            break
        rows.setdefault(tuple(f[:3]), {})[int(f[3])] = (float(f[4]), float(f[5]))
    return rows


def test_rmse_falls_with_spp_and_the_plot_is_written(tmp_path: Path) -> None:
    plot = tmp_path / "sub" / "plot.png"
    r = rdsl(str(CBOX), *SMALL, "--spp", "1,4", "-o", str(plot), tmp=tmp_path)
    assert r.returncode == 0, r.stderr
    rows = table(r.stdout)
    assert len(rows) == 1, r.stdout
    (renderer, _, variant), curve = next(iter(rows.items()))
    assert (renderer, variant) == ("rdsl", "rgb")
    assert sorted(curve) == [1, 4]
    assert curve[4][1] < curve[1][1], r.stdout
    assert all(t > 0 for t, _ in curve.values())
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["plot.png", "sub"]  # nothing else


def test_vs_mitsuba_takes_its_reference_from_mitsuba(tmp_path: Path) -> None:
    pytest.importorskip("mitsuba")
    r = rdsl(str(CBOX), *SMALL, "--spp", "1,16", "--vs", "mitsuba", tmp=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "reference: mitsuba" in r.stdout
    rows = table(r.stdout)
    mi = [k for k in rows if k[0] == "mitsuba"]
    assert len(rows) == 2 and len(mi) == 1, r.stdout
    for curve in rows.values():  # both renderers converge to Mitsuba's image
        assert curve[16][1] < 0.6 * curve[1][1], r.stdout


def test_a_reference_of_the_right_size_is_used(tmp_path: Path) -> None:
    ref = ROOT / "examples" / "cbox" / "cbox_ref_rgb.exr"  # 256x256, the scene's default
    r = rdsl(str(CBOX), "--spp", "1,4", "--ref", str(ref), tmp=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "reference:" not in r.stdout  # none rendered
    curve = table(r.stdout)[next(iter(table(r.stdout)))]
    assert curve[4][1] < curve[1][1], r.stdout


def test_seconds_doubles_spp_until_a_render_takes_that_long(tmp_path: Path) -> None:
    r = rdsl(str(CBOX), *SMALL, "--seconds", "0.002", tmp=tmp_path)
    assert r.returncode == 0, r.stderr
    curve = next(iter(table(r.stdout).values()))
    spp = sorted(curve)
    assert spp == [2 ** k for k in range(len(spp))], r.stdout
    half = 0.5e-4  # the table prints seconds to 4 decimals: 0.0020 may be 0.00196
    assert all(curve[n][0] < 0.002 + half for n in spp[:-1]), r.stdout  # went on while short
    assert curve[spp[-1]][0] >= 0.002 - half or spp[-1] == 1 << 16, r.stdout


def test_each_variant_has_its_own_curve_and_reference(tmp_path: Path) -> None:
    r = rdsl(str(CBOX), *SMALL, "--spp", "1,16", "--variants", "rgb,spectral", tmp=tmp_path)
    assert r.returncode == 0, r.stderr
    rows = table(r.stdout)
    assert sorted(k[2] for k in rows) == ["rgb", "spectral"], r.stdout
    assert r.stdout.count("reference: rdsl") == 2, r.stdout
    for curve in rows.values():
        assert curve[16][1] < 0.6 * curve[1][1], r.stdout


@pytest.mark.parametrize("args, needle", [
    (["nope.xml"], "nope.xml: no such scene file"),
    ([str(CBOX), *SMALL, "--ref", str(ROOT / "examples" / "cbox" / "cbox_ref_rgb.exr")],
     "the reference is 256x256, but the scene renders 16x16"),
    ([str(CBOX), *SMALL, "--ref", "missing.exr"], "missing.exr: no such reference image"),
    ([str(CBOX), *SMALL, "--targets", "avx3"], "unknown target `avx3`"),
    ([str(CBOX), *SMALL, "--variants", "rgb,hyperspectral"], "unknown variant `hyperspectral`"),
    ([str(CBOX), *SMALL, "--spp", "1,x"], "--spp: expected comma-separated integers"),
    ([str(CBOX), *SMALL, "-o", "plot.jpg"], "the plot is a PNG"),
    ([str(CBOX), *SMALL, "--spp", "4", "--seconds", "1"], "give --spp or --seconds, not both"),
    ([str(CBOX), *SMALL, "--spp", "0,4"], "--spp: expected positive integers"),
])
def test_bad_input_is_one_clear_line(tmp_path: Path, args: list[str], needle: str) -> None:
    r = rdsl(*args, tmp=tmp_path)
    assert r.returncode == 1, (r.stdout, r.stderr)
    assert "Traceback" not in r.stderr
    assert needle in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1, r.stderr


def test_a_plot_without_matplotlib_is_one_clear_line(tmp_path: Path) -> None:
    (tmp_path / "matplotlib.py").write_text("raise ImportError('no matplotlib here')\n")
    env = dict(os.environ, PYTHONPATH=f"{tmp_path}{os.pathsep}{os.environ.get('PYTHONPATH', '')}")
    r = subprocess.run([sys.executable, "-m", "rdsl.cli", "bench", str(CBOX), *SMALL,
                        "-o", "plot.png"], cwd=tmp_path, capture_output=True, text=True,
                       env=env, timeout=300)
    assert r.returncode == 1, (r.stdout, r.stderr)
    assert "-o needs matplotlib, which is not installed" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert not (tmp_path / "plot.png").exists()


def test_interleaved_medians_keeps_every_image_in_seed_order() -> None:
    # bench/scene_set.py takes the RMSE over all of them (one image's error swings with its
    # fireflies); the renderers take turns, each called with seeds 0 (warm-up) .. repeat
    import numpy as np

    from rdsl.runtime.render.bench import interleaved_medians

    calls: list[tuple[str, int]] = []

    def renderer(name: str):
        def render(seed: int) -> np.ndarray:
            calls.append((name, seed))
            return np.full((2, 2, 3), seed, np.float32)
        return render

    runs: dict = {}
    images: dict = {}
    res = interleaved_medians({"a": renderer("a"), "b": renderer("b")}, 3, runs, images)
    assert calls == [("a", 0), ("b", 0), ("a", 1), ("b", 1), ("a", 2), ("b", 2),
                     ("a", 3), ("b", 3)]
    assert [float(i[0, 0, 0]) for i in images["a"]] == [0.0, 1.0, 2.0, 3.0]
    assert len(runs["b"]) == 3 and float(res["b"][2][0, 0, 0]) == 3.0
