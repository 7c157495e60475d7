"""Image formats Mitsuba 3's Bitmap reads besides PNG, JPEG and OpenEXR: BMP, TGA, PPM
(8-bit, sRGB-encoded, read with Pillow) and the linear high-dynamic-range RGBE (``.hdr``,
flat and run-length encoded) and PFM (runtime/render/float_images.py).  Each is written here
from one known image and used as a ``bitmap`` reflectance and as an ``envmap``; the images are
compared with Mitsuba 3's renders of the same files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from _mitsuba_render import block_error, render_both, scene_header

Y, X = np.mgrid[0:8, 0:16]
LDR = np.stack([(X * 16) % 256, ((X // 4 + Y // 4) % 2) * 180 + 40, (Y * 32) % 256],
               -1).astype(np.uint8)
HDR = np.stack([0.2 + X / 16, 0.3 + 0.0 * Y, 0.9 - Y / 10], -1).astype(np.float32)
HDR[2:4, 4:7] = [12.0, 9.0, 6.0]


def write_rgbe(path: Path, img: np.ndarray, rle: bool) -> None:
    """``img`` as Radiance RGBE: flat pixels, or new-style run-length scanlines (literal
    chunks, and runs where a byte repeats)."""
    h, w, _ = img.shape
    m = img.max(axis=-1)
    e = np.where(m > 1e-32, np.floor(np.log2(np.maximum(m, 1e-32))) + 1, 0).astype(np.int32)
    mant = np.where(m[..., None] > 1e-32, img * (256.0 / np.ldexp(1.0, e))[..., None], 0)
    pix = np.concatenate([np.clip(mant, 0, 255).astype(np.uint8),
                          np.where(m > 1e-32, e + 128, 0).astype(np.uint8)[..., None]], -1)
    out = bytearray(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n" + f"-Y {h} +X {w}\n".encode())
    if not rle:
        out += pix.tobytes()
    for y in range(h) if rle else ():
        out += bytes([2, 2, w >> 8, w & 255])
        for c in range(4):
            row, x = pix[y, :, c], 0
            while x < w:
                run = 1
                while x + run < w and run < 127 and row[x + run] == row[x]:
                    run += 1
                if run >= 3:
                    out += bytes([128 + run, row[x]])
                    x += run
                else:
                    n = min(2, w - x)
                    out += bytes([n]) + row[x:x + n].tobytes()
                    x += n
    path.write_bytes(bytes(out))


def write_pfm(path: Path, img: np.ndarray) -> None:
    h, w, _ = img.shape
    path.write_bytes(f"PF\n{w} {h}\n-1.0\n".encode()
                     + np.ascontiguousarray(img[::-1], "<f4").tobytes())


def write_image(path: Path) -> None:
    from PIL import Image
    if path.suffix in (".bmp", ".tga", ".ppm"):
        Image.fromarray(LDR, "RGB").save(path)
    elif path.suffix == ".pfm":
        write_pfm(path, HDR)
    else:
        write_rgbe(path, HDR, rle="rle" in path.stem)


def textured(name: str) -> str:
    return scene_header("0, 0, 3", "0, 0, 0", "0, 1, 0", fov=45, res=16, max_depth=2) + f"""
  <emitter type="constant"><rgb name="radiance" value="1"/></emitter>
  <shape type="rectangle">
    <bsdf type="diffuse"><texture type="bitmap" name="reflectance">
      <string name="filename" value="{name}"/><string name="filter_type" value="nearest"/>
    </texture></bsdf>
  </shape>
</scene>
"""


def lit_by(name: str) -> str:
    return scene_header("0, 0, 3", "0, 0, 0", "0, 1, 0", fov=60, res=16, max_depth=2) + f"""
  <emitter type="envmap"><string name="filename" value="{name}"/></emitter>
  <shape type="sphere"><float name="radius" value="0.7"/><bsdf type="diffuse"/></shape>
</scene>
"""


@pytest.mark.parametrize("name", ["tex.bmp", "tex.tga", "tex.ppm", "tex.pfm", "flat.hdr",
                                  "rle.hdr"])
def test_bitmap_format_matches_mitsuba(name: str, tmp_path: Path) -> None:
    write_image(tmp_path / name)
    path = tmp_path / "s.xml"
    path.write_text(textured(name))
    ours, theirs = render_both(path, "rgb", spp=128)
    # under the constant environment the rectangle shows its texels (noisy only where the
    # pixel filter straddles two texels): compare 4 x 4 block means
    assert block_error(ours, theirs, 4) < 0.06
    assert theirs[4:12, 4:12].std() > 0.05  # an image, not a constant stand-in


@pytest.mark.parametrize("name", ["env.pfm", "env_rle.hdr"])
def test_envmap_format_matches_mitsuba(name: str, tmp_path: Path) -> None:
    write_image(tmp_path / name)
    path = tmp_path / "s.xml"
    path.write_text(lit_by(name))
    ours, theirs = render_both(path, "rgb", spp=256)
    a, b = ours.mean(axis=(0, 1)), theirs.mean(axis=(0, 1))
    np.testing.assert_allclose(a, b, rtol=0.03)


@pytest.mark.parametrize("name, content", [("bad.hdr", b"#?RADIANCE\n\n-Y 4 +X 4\n\x01"),
                                           ("bad.pfm", b"PX\n2 2\n-1\n"),
                                           ("bad.bmp", b"BM not a bitmap")])
def test_broken_image_is_a_clear_error(name: str, content: bytes, tmp_path: Path) -> None:
    import rdsl
    from rdsl.compiler.diagnostics import CompileError
    (tmp_path / name).write_bytes(content)
    path = tmp_path / "s.xml"
    path.write_text(textured(name))
    with pytest.raises(CompileError) as e:
        rdsl.load_scene(path).render(spp=1)
    assert name in str(e.value) and "s.xml:" in str(e.value), str(e.value)


def test_storage_and_sampling_options_are_accepted(tmp_path: Path) -> None:
    """bitmap's ``format`` and ``accel`` (how Mitsuba stores texels) and envmap's
    ``mis_compensation`` (how it samples) change no expectation: rdsl accepts them and
    renders the image it renders without them, bit for bit; a wrong value is an error at
    its line."""
    import rdsl

    ASSETS = Path(__file__).resolve().parent / "compat" / "assets"
    bitmap = f'<string name="filename" value="{ASSETS / "tex_rgb.png"}"/>'
    env = f'<string name="filename" value="{ASSETS / "env.exr"}"/>'

    def scene(extra_tex: str, extra_env: str) -> Path:
        path = tmp_path / f"s{len(list(tmp_path.iterdir()))}.xml"
        path.write_text(
            '<scene version="3.0.0">\n<sensor type="perspective"><film type="hdrfilm">'
            '<integer name="width" value="16"/><integer name="height" value="16"/></film>'
            '</sensor>\n<shape type="sphere"><transform name="to_world"><translate z="5"/>'
            '</transform><bsdf type="diffuse"><texture type="bitmap" name="reflectance">'
            f'{bitmap}{extra_tex}</texture></bsdf></shape>\n'
            f'<emitter type="envmap">{env}{extra_env}</emitter>\n</scene>\n')
        return path

    plain = rdsl.load_scene(scene("", "")).render(spp=4, seed=1)
    opts = scene('<string name="format" value="fp16"/><boolean name="accel" value="false"/>',
                 '<boolean name="mis_compensation" value="true"/>')
    assert np.array_equal(rdsl.load_scene(opts).render(spp=4, seed=1), plain)
    bad = scene('<string name="format" value="fp8"/>', "")
    with pytest.raises(Exception, match=rf"{bad}:3.*format"):
        rdsl.load_scene(bad)
