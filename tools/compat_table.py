"""The compat table: each case of the compatibility suite (tests/compat/), rdsl's RMSE to
Mitsuba 3's high-spp reference, Mitsuba's own at the same spp, and their ratio.

    python -m rdsl.tools.compat_table [SHEET ...] [--no-live] [--markdown]

Mitsuba's RMSE is rendered live (its scalar variants) when the ``mitsuba`` package is
installed, else read from tests/compat/refs/noise.json (``--no-live`` forces that).  A case
rdsl does not load shows its error; the status column is ``ok``, ``FAIL`` (ratio above the
suite's limit), ``xfail`` (a known, listed difference) or ``XPASS``."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

COMPAT = Path(__file__).resolve().parents[1] / "tests" / "compat"


def rows(names: list[str], live: bool) -> list[tuple[str, str, str, str, str]]:
    sys.path.insert(0, str(COMPAT))
    from _sheet import RATIO, measure
    from _suite import SHEETS

    out = []
    for sh in SHEETS:
        if names and sh.name not in names:
            continue
        try:
            got = measure(sh, live=live)
        except Exception as e:  # noqa: BLE001 - a load error is a row of the table
            msg = str(e).splitlines()[0][:90]
            out += [(c.name, "-", "-", "-", "xfail" if c.xfail else f"FAIL: {msg}")
                    for c in sh.cases]
            continue
        for c in sh.cases:
            ours, theirs, _ = got[c.name]
            ok = ours <= RATIO * theirs
            status = ("XPASS" if ok else "xfail") if c.xfail else ("ok" if ok else "FAIL")
            # a noise-free case (Mitsuba's RMSE 0) passes only when rdsl's is 0 too
            ratio = f"{ours / theirs:.2f}" if theirs else ("1.00" if ours == 0 else "inf")
            out.append((c.name, f"{ours:.5f}", f"{theirs:.5f}", ratio, status))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("sheets", nargs="*", help="sheet names (default: all)")
    ap.add_argument("--no-live", action="store_true",
                    help="Mitsuba's RMSE from refs/noise.json, not rendered")
    ap.add_argument("--markdown", action="store_true", help="a Markdown table")
    args = ap.parse_args(argv)
    table = rows(args.sheets, not args.no_live)
    head = ("scene", "rdsl RMSE", "Mitsuba RMSE", "ratio", "status")
    if args.markdown:
        print("| " + " | ".join(head) + " |\n|" + "---|" * len(head))
        for r in table:
            print("| " + " | ".join(r) + " |")
    else:
        w = [max(len(x) for x in col) for col in zip(head, *table)]
        for r in (head, tuple("-" * n for n in w), *table):
            print("  ".join(x.ljust(n) for x, n in zip(r, w)).rstrip())
    bad = sum(r[4].startswith(("FAIL", "XPASS")) for r in table)
    print(f"\n{len(table)} cases, {sum(r[4] == 'ok' for r in table)} ok, "
          f"{sum(r[4] == 'xfail' for r in table)} known differences, {bad} failing")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
