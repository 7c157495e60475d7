"""A small progress bar on stderr, and the one-line summaries the renderer prints.

On a terminal (or with ``force=True``) the bar redraws one line in place::

    Rendering [##########..........]  50%  1.2 s  3.41 M samples/s  ETA 1.2 s

Otherwise (a log file, CI) it prints a plain line at 0, 25, 50, 75 and 100% only.
"""

from __future__ import annotations

import sys
import time
from typing import TextIO

__all__ = ["Progress", "format_duration", "format_rate", "summary_line"]

_PREFIXES = ((1e9, "G"), (1e6, "M"), (1e3, "k"))


def format_duration(seconds: float) -> str:
    """``0.42 s``, ``12.3 s``, ``2 min 05 s``, ``1 h 02 min``."""
    if seconds < 60:
        return f"{seconds:.2f} s" if seconds < 10 else f"{seconds:.1f} s"
    m, s = divmod(round(seconds), 60)
    if m < 60:
        return f"{m} min {s:02d} s"
    h, m = divmod(m, 60)
    return f"{h} h {m:02d} min"


def format_rate(amount: float, seconds: float, unit: str) -> str:
    """``3.41 M samples/s``: ``amount`` per second with an SI prefix."""
    if seconds <= 0:
        return f"- {unit}/s"
    rate = amount / seconds
    for scale, prefix in _PREFIXES:
        if rate >= scale:
            return f"{rate / scale:.2f} {prefix} {unit}/s"
    return f"{rate:.2f} {unit}/s"


def summary_line(what: str, seconds: float, amount: float | None = None,
                 unit: str = "samples", extra: str = "") -> str:
    """``what: 3.21 s (1.31 M samples/s)[, extra]`` — one line for a finished step."""
    line = f"{what}: {format_duration(seconds)}"
    if amount is not None:
        line += f" ({format_rate(amount, seconds, unit)})"
    return f"{line}, {extra}" if extra else line


class Progress:
    """Progress of ``total`` units of work; ``update(done)`` or ``advance(n)``, then ``finish()``.

    Usable as a context manager (``finish`` on exit).  ``enabled=False`` silences it;
    ``force=True`` draws the bar even when the stream is not a terminal."""

    def __init__(self, total: float, label: str = "Rendering", unit: str = "samples",
                 stream: TextIO | None = None, force: bool = False, enabled: bool = True,
                 width: int = 30, min_interval: float = 0.1) -> None:
        self.total = max(float(total), 0.0)
        self.label, self.unit, self.width = label, unit, width
        self.stream = stream if stream is not None else sys.stderr
        self.enabled = enabled
        isatty = getattr(self.stream, "isatty", None)
        self.interactive = force or bool(isatty and isatty())
        self.min_interval = min_interval
        self.done = 0.0
        self.start = time.perf_counter()
        self._last_draw = -1.0
        self._next_quarter = 0
        self._finished = False
        self._draw(final=False)

    def __enter__(self) -> Progress:  # noqa: PYI034 (typing.Self needs 3.11)
        return self

    def __exit__(self, *exc: object) -> None:
        self.finish()

    @property
    def elapsed(self) -> float:
        return time.perf_counter() - self.start

    def fraction(self) -> float:
        return 1.0 if self.total == 0 else min(self.done / self.total, 1.0)

    def advance(self, n: float = 1) -> None:
        self.update(self.done + n)

    def update(self, done: float) -> None:
        self.done = float(done)
        self._draw(final=False)

    def finish(self) -> None:
        """Draw the final state (once) and end the line."""
        if self._finished:
            return
        self._finished = True
        self._draw(final=True)

    def line(self) -> str:
        """The current status as text (without the bar)."""
        f, t = self.fraction(), self.elapsed
        text = f"{self.label} {100 * f:3.0f}%  {format_duration(t)}"
        if self.done > 0 and t > 0:
            text += f"  {format_rate(self.done, t, self.unit)}"
            if 0 < f < 1:
                text += f"  ETA {format_duration(t * (1 - f) / f)}"
        return text

    def _draw(self, final: bool) -> None:
        if not self.enabled:
            return
        if self.interactive:
            now = self.elapsed
            if not final and now - self._last_draw < self.min_interval and self._last_draw >= 0:
                return
            self._last_draw = now
            filled = round(self.fraction() * self.width)
            bar = "#" * filled + "." * (self.width - filled)
            head, _, rest = self.line().partition(" ")
            self.stream.write(f"\r{head} [{bar}] {rest}\x1b[K" + ("\n" if final else ""))
        else:
            quarter = int(self.fraction() * 4 + 1e-9)
            if final:
                quarter = 4
            if quarter < self._next_quarter:
                return
            self._next_quarter = quarter + 1
            self.stream.write(self.line() + "\n")
        self.stream.flush()
