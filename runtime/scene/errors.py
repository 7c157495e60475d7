"""The scene loader's user-facing error: ``file:line:col: error: ...`` like every rdsl error."""

from __future__ import annotations

from ...compiler.diagnostics import CompileError, Diagnostic
from ...compiler.ir import Loc


class SceneError(CompileError):
    """A malformed or unsupported scene.  ``str(err)`` quotes the offending XML line."""


def scene_error(message: str, loc: Loc | None) -> SceneError:
    """Shorthand: ``raise scene_error("unknown plugin", node.loc)``."""
    return SceneError([Diagnostic(loc, message)])


def file_loc(path: str) -> Loc:
    """A location naming a whole file (no line), for errors about the file itself."""
    return Loc(str(path), 0, 0)
