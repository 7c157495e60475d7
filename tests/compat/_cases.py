"""The compat suite's scenes, as data: sheets of cases (tests/compat/sheet.py), one case a
Mitsuba 3 plugin with one of its documented parameters in one form Mitsuba accepts (float,
spectrum, rgb, texture, a named material...).  Asset paths are under ``$ASSETS``."""

from __future__ import annotations

from _sheet import Case, Sheet

CHECKER = (
    '<texture type="checkerboard" name="{n}"><float name="color0" value="{a}"/>'
    '<float name="color1" value="{b}"/><transform name="to_uv"><scale value="4"/>'
    "</transform></texture>"
)
CHECKER_RGB = (
    '<texture type="checkerboard" name="{n}"><rgb name="color0" value="0.8, 0.2, 0.1"/>'
    '<rgb name="color1" value="0.1, 0.3, 0.7"/><transform name="to_uv">'
    '<scale value="4"/></transform></texture>'
)
BITMAP = (
    '<texture type="bitmap" name="{n}"><string name="filename" value="$ASSETS/{f}"/>{x}</texture>'
)


def checker(name: str, a: float = 0.1, b: float = 0.8) -> str:
    return CHECKER.format(n=name, a=a, b=b)


def bitmap(name: str, file: str = "tex_rgb.png", extra: str = "") -> str:
    return BITMAP.format(n=name, f=file, x=extra)


def bsdf(kind: str, *params: str) -> str:
    return f'<bsdf type="{kind}">{"".join(params)}</bsdf>'


def cases(kind: str, table: dict[str, list[str]]) -> tuple[Case, ...]:
    """One case per entry: ``name -> params`` of a ``kind`` BSDF."""
    return tuple(Case(f"{kind}.{k}", bsdf(kind, *v)) for k, v in table.items())


SPEC_PAIRS = "400:0.1, 500:0.7, 600:0.3, 700:0.6"

DIFFUSE = cases(
    "diffuse",
    {
        "default": [],
        "float": ['<float name="reflectance" value="0.3"/>'],
        "rgb": ['<rgb name="reflectance" value="0.7, 0.3, 0.1"/>'],
        "spectrum": ['<spectrum name="reflectance" value="0.45"/>'],
        "spectrum_pairs": [f'<spectrum name="reflectance" value="{SPEC_PAIRS}"/>'],
        "checkerboard": [CHECKER_RGB.format(n="reflectance")],
        "bitmap": [bitmap("reflectance")],
        "bitmap_l": [bitmap("reflectance", "tex_l.png")],
    },
)

CONDUCTOR = cases(
    "conductor",
    {
        "default": [],
        "material_au": ['<string name="material" value="Au"/>'],
        "material_cu": ['<string name="material" value="Cu"/>'],
        "eta_k_float": ['<float name="eta" value="0.2"/>', '<float name="k" value="3"/>'],
        "eta_k_rgb": [
            '<rgb name="eta" value="0.2, 0.9, 1.1"/>',
            '<rgb name="k" value="3.9, 2.4, 2.2"/>',
        ],
        "eta_k_spectrum": [
            '<spectrum name="eta" value="400:1.5, 500:0.9, 650:0.3"/>',
            '<spectrum name="k" value="400:3, 700:2"/>',
        ],
        "specular_float": ['<float name="specular_reflectance" value="0.5"/>'],
        "specular_texture": [CHECKER_RGB.format(n="specular_reflectance")],
    },
)

ROUGHCONDUCTOR = cases(
    "roughconductor",
    {
        "default": [],
        "alpha": ['<float name="alpha" value="0.3"/>'],
        "alpha_texture": [checker("alpha", 0.05, 0.5)],
        "alpha_uv": ['<float name="alpha_u" value="0.05"/>', '<float name="alpha_v" value="0.4"/>'],
        "beckmann": [
            '<string name="distribution" value="beckmann"/>',
            '<float name="alpha" value="0.2"/>',
        ],
        "no_visible": [
            '<boolean name="sample_visible" value="false"/>',
            '<float name="alpha" value="0.2"/>',
        ],
        "material_cr": [
            '<string name="material" value="Cr"/>',
            '<float name="alpha" value="0.15"/>',
        ],
        "eta_k_rgb": [
            '<rgb name="eta" value="0.2, 0.9, 1.1"/>',
            '<rgb name="k" value="3.9, 2.4, 2.2"/>',
        ],
        "specular_texture": [bitmap("specular_reflectance"), '<float name="alpha" value="0.2"/>'],
    },
)

DIELECTRIC = cases(
    "dielectric",
    {
        "default": [],
        "named_ior": [
            '<string name="int_ior" value="water"/>',
            '<string name="ext_ior" value="air"/>',
        ],
        "float_ior": ['<float name="int_ior" value="1.9"/>', '<float name="ext_ior" value="1.1"/>'],
        "specular_reflectance": ['<float name="specular_reflectance" value="0.5"/>'],
        "specular_transmittance_rgb": [
            '<rgb name="specular_transmittance" value="0.9, 0.5, 0.2"/>'
        ],
        "specular_transmittance_texture": [CHECKER_RGB.format(n="specular_transmittance")],
    },
)

THINDIELECTRIC = cases(
    "thindielectric",
    {
        "default": [],
        "named_ior": ['<string name="int_ior" value="bk7"/>'],
        "specular_transmittance": [bitmap("specular_transmittance")],
    },
)

ROUGHDIELECTRIC = cases(
    "roughdielectric",
    {
        "default": [],
        "alpha": ['<float name="alpha" value="0.3"/>'],
        "alpha_texture": [checker("alpha", 0.05, 0.4)],
        "beckmann": ['<string name="distribution" value="beckmann"/>'],
        "ior": ['<float name="int_ior" value="1.33"/>', '<string name="ext_ior" value="air"/>'],
        "specular_transmittance": ['<rgb name="specular_transmittance" value="0.9, 0.5, 0.2"/>'],
    },
)

PLASTIC = cases(
    "plastic",
    {
        "default": [],
        "diffuse_rgb": ['<rgb name="diffuse_reflectance" value="0.1, 0.3, 0.7"/>'],
        "diffuse_texture": [bitmap("diffuse_reflectance")],
        "specular_float": ['<float name="specular_reflectance" value="0.5"/>'],
        "named_ior": ['<string name="int_ior" value="polypropylene"/>'],
        "nonlinear": [
            '<boolean name="nonlinear" value="true"/>',
            '<rgb name="diffuse_reflectance" value="0.7, 0.3, 0.1"/>',
        ],
    },
)

ROUGHPLASTIC = cases(
    "roughplastic",
    {
        "default": [],
        "alpha": ['<float name="alpha" value="0.3"/>'],
        "beckmann": ['<string name="distribution" value="beckmann"/>'],
        "diffuse_texture": [CHECKER_RGB.format(n="diffuse_reflectance")],
        "nonlinear": [
            '<boolean name="nonlinear" value="true"/>',
            '<rgb name="diffuse_reflectance" value="0.7, 0.3, 0.1"/>',
        ],
        "ior": ['<float name="int_ior" value="1.9"/>'],
        "no_visible": ['<boolean name="sample_visible" value="false"/>'],
    },
)

PRINCIPLED = cases(
    "principled",
    {
        "default": [],
        "base_color_rgb": ['<rgb name="base_color" value="0.8, 0.3, 0.1"/>'],
        "base_color_texture": [bitmap("base_color")],
        "roughness_texture": [checker("roughness", 0.1, 0.7)],
        "metallic": [
            '<float name="metallic" value="0.8"/>',
            '<float name="roughness" value="0.3"/>',
        ],
        "specular_tint": [
            '<float name="specular" value="0.9"/>',
            '<float name="spec_tint" value="0.7"/>',
            '<rgb name="base_color" value="0.2, 0.6, 0.9"/>',
        ],
        "anisotropic": [
            '<float name="anisotropic" value="0.8"/>',
            '<float name="metallic" value="1"/>',
            '<float name="roughness" value="0.4"/>',
        ],
        "sheen": ['<float name="sheen" value="1"/>', '<float name="sheen_tint" value="0.5"/>'],
        "clearcoat": [
            '<float name="clearcoat" value="1"/>',
            '<float name="clearcoat_gloss" value="0.3"/>',
        ],
        "spec_trans": [
            '<float name="spec_trans" value="0.8"/>',
            '<float name="eta" value="1.4"/>',
            '<float name="roughness" value="0.2"/>',
        ],
        "metallic_texture": [
            checker("metallic", 0.0, 1.0),
            '<float name="roughness" value="0.25"/>',
        ],
        "sampling_rates": [
            '<float name="diffuse_reflectance_sampling_rate" value="0.3"/>',
            '<float name="main_specular_sampling_rate" value="2"/>',
        ],
    },
)

PRINCIPLEDTHIN = cases(
    "principledthin",
    {
        "default": [],
        "base_color_texture": [CHECKER_RGB.format(n="base_color")],
        "diff_trans": [
            '<float name="diff_trans" value="0.6"/>',
            '<float name="flatness" value="0.5"/>',
        ],
        "spec_trans": [
            '<float name="spec_trans" value="0.7"/>',
            '<float name="eta" value="1.33"/>',
            '<float name="roughness" value="0.15"/>',
        ],
        "anisotropic_sheen": [
            '<float name="anisotropic" value="0.6"/>',
            '<float name="sheen" value="0.8"/>',
        ],
    },
)

PPLASTIC = cases(
    "pplastic",
    {
        "default": [],
        "alpha": [
            '<float name="alpha" value="0.3"/>',
            '<rgb name="diffuse_reflectance" value="0.1, 0.3, 0.7"/>',
        ],
        "beckmann_texture": [
            '<string name="distribution" value="beckmann"/>',
            bitmap("diffuse_reflectance"),
        ],
    },
)

# Chiang et al.'s hair on spheres (the fibers along the meridians: the shading frame's y)
HAIR = cases(
    "hair",
    {
        "default": [],
        "pigments": [
            '<float name="eumelanin" value="0.2"/>',
            '<float name="pheomelanin" value="0.4"/>',
        ],
        "sigma_a": [
            '<rgb name="sigma_a" value="0.2, 0.25, 0.7"/>',
            '<float name="scale" value="2"/>',
        ],
        "rough": [
            '<float name="longitudinal_roughness" value="0.7"/>',
            '<float name="azimuthal_roughness" value="0.6"/>',
        ],
        "smooth_tilt": [
            '<float name="longitudinal_roughness" value="0.1"/>',
            '<float name="scale_tilt" value="6"/>',
            '<float name="eumelanin" value="0.5"/>',
        ],
        "sigma_a_texture": [bitmap("sigma_a"), '<float name="scale" value="1.5"/>'],
        "ior_string": [
            '<string name="int_ior" value="water"/>',
            '<float name="eumelanin" value="0.8"/>',
        ],
    },
)

# the absorption upsampled (the pigments' and sigma_a's colours, as reflectances)
HAIR_SPECTRAL = (
    Case("hair.spectral.default", bsdf("hair")),
    Case("hair.spectral.sigma_a", bsdf("hair", '<rgb name="sigma_a" value="0.2, 0.25, 0.7"/>')),
)

# anisotropic roughdielectric, on a sheet of its own (once an xfail case, kept as it was so
# that its reference image still applies)
ROUGHDIELECTRIC_ALPHA_UV = (
    Case(
        "roughdielectric.alpha_uv",
        bsdf(
            "roughdielectric",
            '<float name="alpha_u" value="0.05"/>',
            '<float name="alpha_v" value="0.3"/>',
        ),
    ),
)

# cases rdsl does not load: each alone on its sheet, so that it fails by itself
UNSUPPORTED: tuple[Case, ...] = ()

BSDF_SHEETS: list[Sheet] = [
    Sheet("diffuse", DIFFUSE),
    Sheet("conductor", CONDUCTOR),
    Sheet("roughconductor", ROUGHCONDUCTOR),
    Sheet("dielectric", DIELECTRIC + THINDIELECTRIC),
    Sheet("roughdielectric", ROUGHDIELECTRIC),
    Sheet("roughdielectric.alpha_uv", ROUGHDIELECTRIC_ALPHA_UV),
    Sheet("plastic", PLASTIC + ROUGHPLASTIC + PPLASTIC, cols=4),
    Sheet("principled", PRINCIPLED + PRINCIPLEDTHIN, cols=4),
    Sheet("hair", HAIR, cols=4),
    Sheet("hair.spectral", HAIR_SPECTRAL, variant="spectral"),
]
