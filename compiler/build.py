"""What one compilation is for: a :class:`Build` holds the CPU target and the colour model.

Entry points (the command line, ``rdsl.jit``, ``rdsl.load_scene``) turn the user's target and
variant names into a Build with :meth:`Build.of`, at once, so that a bad name is reported
before any file is read; everything below them takes the Build or its parts.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..core.color import MODELS, VARIANTS, ColorModel
from .diagnostics import CompileError
from .targets import Target, get_target


AD_MODES = (None, "forward", "reverse")


@dataclass(frozen=True)
class Build:
    """A code-generation target and the colour model its kernels compute in."""

    target: Target
    model: ColorModel
    # automatic differentiation: None, "forward" or "reverse" (compiler/passes/ad_*.py)
    ad: str | None = None
    # reverse mode: the `eliminate` pass's threshold (0: not run; passes/eliminate.py)
    eliminate: int = 0
    # reverse mode: iterations of a loop whose carried state the adjoint kernel checkpoints
    # per lane (0: it recomputes the state from the start; passes/ad_reverse.py)
    tape: int = 0
    # reverse mode: the loads differentiated, None for all: elements of the generic build's
    # parameter buffer PRM, and "T" for the texel buffer (passes/ad_reverse.py)
    seeds: tuple[int | str, ...] | None = None
    # reverse mode: the tape covers every iteration (no loop is expected to run more than
    # `tape` iterations; a lane that does is flagged and skipped: passes/ad_checkpoint.py)
    tape_covers: bool = False

    @classmethod
    def of(cls, target: str | Target = "host", variant: str | ColorModel = "rgb",
           width: int | None = None, ad: str | None = None,
           eliminate: bool | int = False) -> Build:
        """The build for a target name (``host`` resolves to this machine's widest) and a
        variant name; a name that is neither raises a diagnostic listing the valid ones.
        ``width`` picks the SIMD width of target ``c`` (see :func:`get_target`); ``ad`` the
        differentiation mode (None, "forward" or "reverse": docs/ad.md); ``eliminate``
        (reverse mode) runs graph elimination, True at the default threshold (10) or an
        int threshold (0: off)."""
        if ad not in AD_MODES:
            raise CompileError(f"unknown differentiation mode `{ad}` (valid: forward, reverse)")
        return cls(get_target(target, width), color_model(variant), ad,
                   elimination_threshold(ad, eliminate))

    @property
    def width(self) -> int:
        """SIMD lanes per kernel call."""
        return self.target.width


def elimination_threshold(ad: str | None, eliminate: bool | int) -> int:
    """The threshold of the ``eliminate`` pass a build asks for (0: none)."""
    if eliminate is True:
        eliminate = 10
    if isinstance(eliminate, bool) or not eliminate:
        return 0
    if not isinstance(eliminate, int) or eliminate < 0:
        raise CompileError(f"the elimination threshold must be a non-negative integer, "
                           f"not `{eliminate}`")
    if ad != "reverse":
        raise CompileError("graph elimination (`eliminate`) needs a reverse build "
                           "(ad=\"reverse\")")
    return eliminate


def color_model(variant: str | ColorModel) -> ColorModel:
    """The colour model of a variant name, or a diagnostic naming the valid variants."""
    if isinstance(variant, ColorModel):
        return variant
    model = MODELS.get(variant)
    if model is None:
        raise CompileError(f"unknown variant `{variant}` (valid variants: "
                           f"{', '.join(VARIANTS)})")
    return model
