"""The checks of a plugin's ``table(...) fn`` declarations (see docs/language.md, "Tables")."""

from __future__ import annotations

from typing import Any

from ..compiler.ir import F32, I32
from . import ast as A
from .program import FnInfo
from .types import err

_TABLE_OPTIONS = ("n", "lo", "hi", "error", "sum")
MAX_POINTS = 1 << 16


def table_options(fn: FnInfo, pd: A.PluginDecl, interface: set[str]) -> dict[str, Any]:
    """The checked options of a ``table(...) fn``: a Float function of nothing (a value per
    scene, no options), of one Float (``n`` samples on ``lo..hi`` and the stated ``error``
    of reading it back by linear interpolation), or, with ``sum = N``, of one Int: a value
    per scene, the sum of its N terms (``{"sum": N}``; called with no argument)."""
    spec = fn.decl.table
    assert spec is not None
    where = f"table `{pd.name}.{fn.name}`"
    if fn.name in interface:
        raise err(f"{where}: `{fn.name}` is a function of the {pd.kind} interface and cannot "
                  "be a table", spec.loc)
    for name, (_, loc) in spec.options.items():
        if name not in _TABLE_OPTIONS:
            raise err(f"{where}: unknown option `{name}`; expected "
                      + ", ".join(f"`{o}`" for o in _TABLE_OPTIONS), loc)
    if "sum" in spec.options:
        return _sum_options(fn, spec, where)
    if fn.ret != F32 or fn.param_types not in ([], [F32]):
        raise err(f"{where}: a table is a `Float` function of no argument or of one `Float` "
                  f"argument (or, with `sum = N`, of one `Int`), found `{fn.signature()}`",
                  fn.decl.loc)
    if not fn.params:
        if spec.options:
            raise err(f"{where}: a table of no argument is one value and takes no options",
                      spec.loc)
        return {}
    missing = [o for o in _TABLE_OPTIONS if o != "sum" and o not in spec.options]
    if missing:
        raise err(f"{where}: a table of one argument needs "
                  + ", ".join(f"`{o} = ...`" for o in missing), spec.loc)
    opts = {k: v for k, (v, _) in spec.options.items()}
    n, lo, hi, error = opts["n"], float(opts["lo"]), float(opts["hi"]), float(opts["error"])
    if not isinstance(n, int) or not 2 <= n <= MAX_POINTS:
        raise err(f"{where}: `n` must be an integer in 2..{MAX_POINTS}", spec.options["n"][1])
    if not lo < hi:
        raise err(f"{where}: `lo` must be less than `hi`", spec.options["hi"][1])
    if not error > 0.0:
        raise err(f"{where}: `error` (the stated bound on the interpolation error) must be "
                  "positive", spec.options["error"][1])
    return {"n": n, "lo": lo, "hi": hi, "error": error}


def _sum_options(fn: FnInfo, spec: A.TableSpec, where: str) -> dict[str, Any]:
    """``table(sum = N) fn name(k: Int) -> Float``: the value sum over k < N of the function
    (a quadrature's terms, computed side by side: lanes and threads), read as ``name()``."""
    if fn.ret != F32 or fn.param_types != [I32]:
        raise err(f"{where}: a `sum` table is a `Float` function of one `Int` (the term's "
                  f"index), found `{fn.signature()}`", fn.decl.loc)
    others = [k for k in spec.options if k != "sum"]
    if others:
        raise err(f"{where}: a `sum` table takes no other option (found `{others[0]}`): it is "
                  "one value, not read back by interpolation", spec.options[others[0]][1])
    n, loc = spec.options["sum"]
    if not isinstance(n, int) or not 1 <= n <= MAX_POINTS:
        raise err(f"{where}: `sum` (the number of terms) must be an integer in "
                  f"1..{MAX_POINTS}", loc)
    return {"sum": n}


def check_sum_table_read(fn: FnInfo, caller: FnInfo, loc: Any) -> None:
    """A `sum` table is one value per instance, filled before any other table: only its own
    plugin's non-table functions read it."""
    if not fn.summed or fn.plugin is None:
        return
    if caller.plugin is not fn.plugin:
        raise err(f"`{fn.plugin.name}.{fn.name}` is a `sum` table, read only inside "
                  "its plugin", loc)
    if caller.decl.table is not None:
        raise err(f"`{fn.name}` is a `sum` table: another table cannot read it "
                  "(tables are filled independently of each other)", loc)
