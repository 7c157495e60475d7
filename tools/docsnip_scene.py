"""Scene wrappers and generated data files for tools/docsnip.py: each snippet kind becomes a
small complete Mitsuba 3 scene, and each data file a snippet names (bitmap, mesh, spectrum,
environment map) is written as a small synthetic file beside it."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

POLARIZED = {"polarizer", "pplastic", "retarder", "circular", "measured_polarized", "stokes"}

SENSOR = """<sensor type="perspective">
  <float name="fov" value="40"/>
  <transform name="to_world"><lookat origin="0, 2, 4" target="0, 0.5, 0" up="0, 1, 0"/>
  </transform>
  {sampler}
  {film}
</sensor>"""
FILM = """<film type="hdrfilm"><integer name="width" value="{res}"/>
  <integer name="height" value="{res}"/>{rfilter}</film>"""
SAMPLER = '<sampler type="independent"><integer name="sample_count" value="16"/></sampler>'
FLOOR = """<shape type="rectangle">
  <transform name="to_world"><rotate x="1" angle="-90"/><scale value="3"/></transform>
  <bsdf type="diffuse"><texture type="checkerboard" name="reflectance">
    <rgb name="color0" value="0.7, 0.7, 0.6"/><rgb name="color1" value="0.2, 0.3, 0.5"/>
    <transform name="to_uv"><scale x="6" y="6"/></transform></texture></bsdf>
</shape>"""
LIGHT = """<shape type="rectangle">
  <transform name="to_world"><rotate x="1" angle="90"/><scale value="0.6"/>
    <translate x="0.5" y="3" z="0.8"/></transform>
  <emitter type="area">{radiance}</emitter>
</shape>"""
RADIANCE = '<rgb name="radiance" value="12"/>'
AMBIENT = '<emitter type="constant"><rgb name="radiance" value="0.25"/></emitter>'


def _sphere(bsdf: str) -> str:
    return f"""<shape type="sphere"><point name="center" x="0" y="0.7" z="0"/>
  <float name="radius" value="0.7"/>{bsdf}</shape>"""


def _named(text: str, name: str) -> str:
    """``text`` (one property element) with its ``name`` attribute set to ``name``."""
    if re.search(r'\bname="[^"]*"', text.split(">", 1)[0]):
        return re.sub(r'\bname="[^"]*"', f'name="{name}"', text, count=1)
    return re.sub(r"^(\s*<\w+)", rf'\1 name="{name}"', text, count=1)


# long: one wrapper per snippet kind, read as a table
def build_scene(kind: str, text: str, res: int) -> str:
    """The complete scene around a snippet of ``kind``."""
    text = text.strip()
    sampler, rfilter = SAMPLER, ""
    integrator = '<integrator type="path"><integer name="max_depth" value="6"/></integrator>'
    film = FILM.format(res=res, rfilter="")
    sensor = None
    lights = [LIGHT.format(radiance=RADIANCE), AMBIENT]
    body = [FLOOR]
    if kind == "bsdf":
        body.append(_sphere(text))
    elif kind == "texture":
        body.append(_sphere(f'<bsdf type="diffuse">{_named(text, "reflectance")}</bsdf>'))
    elif kind == "spectrum":
        lights = [LIGHT.format(radiance=_named(text, "radiance")), AMBIENT]
        body.append(_sphere('<bsdf type="diffuse"/>'))
    elif kind == "emitter":
        lights = [text]
        body.append(_sphere('<bsdf type="diffuse"/>'))
    elif kind == "shape":
        body.append(text)
    else:
        body.append(_sphere('<bsdf type="diffuse"/>'))
        if kind == "integrator":
            integrator = text
        elif kind == "sampler":
            sampler = text
        elif kind == "rfilter":
            film = FILM.format(res=res, rfilter=text)
        elif kind == "film":
            film = text
        elif kind == "sensor":
            sensor = text
    if sensor is None:
        sensor = SENSOR.format(sampler=sampler, film=film)
    # a $name the snippet uses gets a <default>: 16 where an <integer> takes it, else the
    # colour "0.2, 0.4, 0.6"
    defaults = []
    for n in dict.fromkeys(re.findall(r"\$([A-Za-z_]\w*)", text)):
        integer = re.search(r"<integer[^>]*\$" + n + r"\b", text)
        defaults.append(f'<default name="{n}" value="{16 if integer else "0.2, 0.4, 0.6"}"/>')
    parts = [*defaults, integrator, sensor, *lights, *body]
    return '<scene version="3.0.0">\n' + "\n".join(parts) + "\n</scene>\n"


def _image(path: Path, grey: bool) -> None:
    from PIL import Image
    y, x = np.mgrid[0:32, 0:32]
    if grey or any(k in path.name for k in ("mask", "bump", "grey", "rough")):
        a = (((x // 8 + y // 8) % 2) * 200 + 40).astype(np.uint8)
        img = Image.fromarray(a, "L")
    elif "normal" in path.name:
        n = np.stack([0.3 * np.cos(x / 32 * 4 * np.pi), 0.3 * np.sin(y / 32 * 2 * np.pi),
                      np.ones(x.shape)], -1)
        n /= np.linalg.norm(n, axis=-1, keepdims=True)
        img = Image.fromarray(((n * 0.5 + 0.5) * 255).round().astype(np.uint8), "RGB")
    else:
        rgb = np.stack([(x * 8) % 256, ((x // 8 + y // 8) % 2) * 180 + 40, (y * 8) % 256], -1)
        img = Image.fromarray(rgb.astype(np.uint8), "RGB")
    path.parent.mkdir(parents=True, exist_ok=True)
    img.save(path)


def _exr(path: Path) -> None:
    from rdsl.runtime.render.image import write_exr
    ey, ex = np.mgrid[0:16, 0:32]
    env = np.stack([0.3 + 0.2 * (ex / 32), 0.3 + 0.0 * ey, 0.5 - 0.3 * (ey / 16)], -1)
    env[3:5, 8:11] = [20.0, 18.0, 15.0]
    if path.suffix.lower() in (".hdr", ".rgbe"):  # flat Radiance RGBE
        m = env.max(axis=-1)
        e = np.floor(np.log2(m)) + 1
        mant = np.clip(env * (256.0 / np.ldexp(1.0, e.astype(np.int32)))[..., None], 0, 255)
        pix = np.concatenate([mant.astype(np.uint8), (e + 128).astype(np.uint8)[..., None]], -1)
        path.write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 16 +X 32\n" + pix.tobytes())
        return
    write_exr(path, env.astype(np.float32))


def _mesh(path: Path) -> None:
    """A bumpy, tilted 12 x 12 grid patch with uvs (OBJ or ASCII PLY)."""
    n = 12
    g = np.linspace(-0.8, 0.8, n + 1)
    x, z = np.meshgrid(g, g)
    y = 0.6 + 0.25 * np.cos(3 * x) * np.cos(3 * z) + 0.3 * z
    p = np.stack([x, y, z], -1).reshape(-1, 3)
    uv = np.stack(np.meshgrid(np.linspace(0, 1, n + 1), np.linspace(0, 1, n + 1)),
                  -1).reshape(-1, 2)
    k = np.arange(n * (n + 1)).reshape(n, n + 1)[:, :n].reshape(-1)
    tris = np.concatenate([np.stack([k, k + n + 1, k + 1], -1),
                           np.stack([k + 1, k + n + 1, k + n + 2], -1)])
    if path.suffix == ".obj":
        lines = [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in p]
        lines += [f"vt {u:.6f} {v:.6f}" for u, v in uv]
        lines += ["f " + " ".join(f"{k + 1}/{k + 1}" for k in t) for t in tris]
    else:
        lines = ["ply", "format ascii 1.0", f"element vertex {len(p)}",
                 *(f"property float {k}" for k in ("x", "y", "z", "u", "v")),
                 f"element face {len(tris)}", "property list uchar int vertex_indices",
                 "end_header"]
        lines += [" ".join(f"{c:.6f}" for c in (*a, *b)) for a, b in zip(p, uv)]
        lines += ["3 " + " ".join(str(k) for k in t) for t in tris]
    path.write_text("\n".join(lines) + "\n")


def _spd(path: Path) -> None:
    wl = np.arange(360, 831, 10)
    vals = 0.4 + 0.3 * np.sin((wl - 360) / 470 * 3 * np.pi)
    if "eta" in path.name:
        vals = 0.3 + 0.5 * (wl - 360) / 470
    elif ".k." in path.name:
        vals = 2.0 + 2.0 * (wl - 360) / 470
    path.write_text("".join(f"{w} {v:.4f}\n" for w, v in zip(wl, vals)))


def write_assets(text: str, folder: Path) -> None:
    """Every data file ``text`` names, generated under ``folder``."""
    names = re.findall(r'name="filename"\s+value="([^"]+)"', text)
    names += re.findall(r'filename="([^"]+)"', text)
    for name in names:
        path = folder / name
        path.parent.mkdir(parents=True, exist_ok=True)
        suf = path.suffix.lower()
        if suf in (".png", ".jpg", ".jpeg", ".bmp", ".tga"):
            _image(path, grey=False)
        elif suf in (".exr", ".hdr"):
            _exr(path)
        elif suf in (".obj", ".ply"):
            _mesh(path)
        elif suf == ".spd":
            _spd(path)
        else:  # a format nothing here writes: a few bytes, so that the file exists
            path.write_bytes(b"\0" * 16)
