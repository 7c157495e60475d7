"""The table ``rdsl test-plugin`` prints: one :class:`Row` per check and case (an incident
angle, a parameter sweep), its statistic against its threshold, PASS, FAIL or SKIP (with the
reason), and a summary line."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

PASS, FAIL, SKIP = "PASS", "FAIL", "SKIP"


@dataclass(frozen=True)
class Row:
    """One check on one case: ``value`` is the statistic, ``threshold`` what it is held to
    (both as printed), ``note`` why a check failed or was skipped."""

    check: str
    case: str
    value: str
    threshold: str
    status: str
    note: str = ""

    @property
    def failed(self) -> bool:
        return self.status == FAIL


def verdict(ok: bool) -> str:
    """PASS or FAIL."""
    return PASS if ok else FAIL


def table(rows: Sequence[Row]) -> str:
    """The rows as aligned columns under a header; notes follow their row, indented."""
    head = ("check", "case", "statistic", "threshold", "result")
    cells = [head] + [(r.check, r.case, r.value, r.threshold, r.status) for r in rows]
    widths = [max(len(c[i]) for c in cells) for i in range(len(head))]

    def line(c: Sequence[str]) -> str:
        return "  ".join(x.ljust(w) for x, w in zip(c, widths)).rstrip()

    out = [line(head), line(["-" * w for w in widths])]
    for r, c in zip(rows, cells[1:]):
        out.append(line(c))
        if r.note:
            out.append(f"    {r.note}")
    return "\n".join(out)


def summary(title: str, rows: Sequence[Row]) -> str:
    """``TITLE: 12 passed, 1 failed, 2 skipped`` and the names of the failed checks."""
    count = {s: sum(r.status == s for r in rows) for s in (PASS, FAIL, SKIP)}
    text = (f"{title}: {count[PASS]} passed, {count[FAIL]} failed, {count[SKIP]} skipped")
    failed = sorted({r.check for r in rows if r.failed})
    return text + (f" (failed: {', '.join(failed)})" if failed else "")
