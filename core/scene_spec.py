"""The scene specification: what the runtime tells the compiler about one scene.

The renderer reads a scene and describes it as a :class:`SceneSpec`: its plugin instances
(BSDFs, emitters, textures, the BSDFs nested in combinators) with their parameter values, and
the kinds of emitters and shapes it has.  The ``specialize`` pass fits the program to it.  A
parameter value is a number, a tuple, a :class:`SpectrumValue` (a colour), a
:class:`TextureRef` (a texture of the scene) or, in the generic build, a :class:`Slot` of the
parameter buffer.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any


@dataclass(frozen=True)
class TextureRef:
    """A parameter value that is the scene's texture ``index`` (in ``SceneSpec.textures``)."""

    index: int


@dataclass(frozen=True)
class Slot:
    """A parameter value read at run time from ``PRM[offset:offset + size]`` (the generic
    build).  Ints and bools are stored as floats (exact below 2**24) and converted back.  A
    colour of a spectral build is 4 floats: its upsampling coefficients and a scale; a
    tabulated spectrum there (``table``) is ``spectral.GENERIC_SLOT`` floats, its cells on a
    fixed 1 nm grid (``spectral.tabulated_slot``)."""

    offset: int
    size: int
    illuminant: bool = False
    table: bool = False


@dataclass(frozen=True)
class SpectrumValue:
    """A colour parameter: its linear sRGB value, the tabulated spectrum the scene gave if
    any (wavelengths in nm, values), and whether it is emitted light (an illuminant, which
    spectral variants upsample with D65, as Mitsuba 3) rather than a reflectance."""

    rgb: tuple[float, float, float]
    samples: tuple[tuple[float, ...], tuple[float, ...]] | None = None
    illuminant: bool = False


@dataclass
class Instance:
    """One plugin instance of the scene: its plugin type and parameter values (floats,
    ints, bools, or tuples for colors and vectors).  Missing parameters take the plugin's
    defaults."""

    plugin: str
    params: dict[str, Any] = field(default_factory=dict)
    name: str = ""
    # a combinator's nested instances (twosided, blendbsdf, mask), before the renderer moves
    # them to ``SceneSpec.bsdf_leaves`` and sets the combinator's leaf-id parameters
    children: list[Instance] = field(default_factory=list)


@dataclass
class SceneSpec:
    """What ``specialize`` needs to know about a scene."""

    bsdfs: list[Instance] = field(default_factory=list)
    emitters: list[Instance] = field(default_factory=list)
    textures: list[Instance] = field(default_factory=list)
    bsdf_leaves: list[Instance] = field(default_factory=list)  # nested in combinators
    # the kinds of emitter the scene has (lights.rdsl's EK kinds); None: any kind may occur
    emitter_kinds: tuple[int, ...] | None = None
    # the kinds of shape (geometry.rdsl: 0 mesh, 1 sphere, 2 disk); None: any kind may occur
    shape_kinds: tuple[int, ...] | None = None
    # the scene's integrators (one per plugin type: a wrapper such as `aov`, its nested one)
    integrators: list[Instance] = field(default_factory=list)
    # how rays are traced: "embree", or "bvh" (stdlib/render/bvh.rdsl)
    accel: str = "embree"
