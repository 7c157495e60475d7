"""The checks of a plugin's ``table(...) fn`` declarations (see docs/language.md, "Tables")."""

from __future__ import annotations

from typing import Any

from ..compiler.ir import F32
from . import ast as A
from .program import FnInfo
from .types import err

_TABLE_OPTIONS = ("n", "lo", "hi", "error")


def table_options(fn: FnInfo, pd: A.PluginDecl, interface: set[str]) -> dict[str, Any]:
    """The checked options of a ``table(...) fn``: a Float function of nothing (a value per
    scene, no options) or of one Float (``n`` samples on ``lo..hi`` and the stated ``error``
    of reading it back by linear interpolation)."""
    spec = fn.decl.table
    assert spec is not None
    where = f"table `{pd.name}.{fn.name}`"
    if fn.name in interface:
        raise err(f"{where}: `{fn.name}` is a function of the {pd.kind} interface and cannot "
                  "be a table", spec.loc)
    if fn.ret != F32 or fn.param_types not in ([], [F32]):
        raise err(f"{where}: a table is a `Float` function of no argument or of one `Float` "
                  f"argument, found `{fn.signature()}`", fn.decl.loc)
    for name, (_, loc) in spec.options.items():
        if name not in _TABLE_OPTIONS:
            raise err(f"{where}: unknown option `{name}`; expected "
                      + ", ".join(f"`{o}`" for o in _TABLE_OPTIONS), loc)
    if not fn.params:
        if spec.options:
            raise err(f"{where}: a table of no argument is one value and takes no options",
                      spec.loc)
        return {}
    missing = [o for o in _TABLE_OPTIONS if o not in spec.options]
    if missing:
        raise err(f"{where}: a table of one argument needs "
                  + ", ".join(f"`{o} = ...`" for o in missing), spec.loc)
    opts = {k: v for k, (v, _) in spec.options.items()}
    n, lo, hi, error = opts["n"], float(opts["lo"]), float(opts["hi"]), float(opts["error"])
    if not isinstance(n, int) or not 2 <= n <= 1 << 16:
        raise err(f"{where}: `n` must be an integer in 2..65536", spec.options["n"][1])
    if not lo < hi:
        raise err(f"{where}: `lo` must be less than `hi`", spec.options["hi"][1])
    if not error > 0.0:
        raise err(f"{where}: `error` (the stated bound on the interpolation error) must be "
                  "positive", spec.options["error"][1])
    return {"n": n, "lo": lo, "hi": hi, "error": error}
