"""IR passes.  Each pass is a class with a ``name`` and ``run(module)``, registered by name
so that ``--print-after=NAME`` works for every pass."""

from __future__ import annotations

from collections.abc import Callable

from ..ir import Module


class Pass:
    """Base class.  Subclasses set ``name`` and implement ``run``; options come through
    ``__init__``.  ``run`` mutates the module in place (and may also return it)."""

    name: str = "?"

    def run(self, module: Module) -> None:
        raise NotImplementedError


REGISTRY: dict[str, type[Pass]] = {}


def register(cls: type[Pass]) -> type[Pass]:
    """Class decorator adding a pass to the registry."""
    REGISTRY[cls.name] = cls
    return cls


def pass_names() -> list[str]:
    _load_all()
    return sorted(REGISTRY)


def _load_all() -> None:
    # import every pass module so that its @register runs
    from . import ad_reverse, eliminate  # noqa: F401
    from . import evaluate, inline, lift, optimize, scalarize, specialize, tape_stores  # noqa: F401
    from . import vectorize  # noqa: F401


PassFactory = Callable[[], Pass]
