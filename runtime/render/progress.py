"""The render's progress on stderr (a ``tqdm`` bar), and the one-line summaries the renderer
prints.

On a terminal (or with ``force=True``) tqdm redraws one line in place::

    rendering:  50%|█████     | 32/64 [00:01<00:01, 21.3spp/s]

Otherwise (a log file, CI) there is no bar and no carriage return: one plain line when the
work starts and one when it ends (``rendering 100%  1.52 s  42.10 spp/s``).
"""

from __future__ import annotations

import sys
import time
from typing import TYPE_CHECKING, TextIO

if TYPE_CHECKING:
    from tqdm import tqdm

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
    """Progress of ``total`` units of work; ``update(done)`` or ``advance(n)``, then
    ``finish()``.  Usable as a context manager (``finish`` on exit).

    ``enabled=False`` silences it.  The bar is drawn only where someone watches it: on a
    terminal, or anywhere with ``force=True``; a stream that is not a terminal gets the two
    plain lines instead, since tqdm's redraws would fill a log with carriage returns (and
    tqdm's own ``disable=None`` would print nothing at all)."""

    def __init__(self, total: float, label: str = "Rendering", unit: str = "samples",
                 stream: TextIO | None = None, force: bool = False, enabled: bool = True,
                 min_interval: float = 0.1) -> None:
        self.total = max(float(total), 0.0)
        self.label, self.unit = label, unit
        self.stream = stream if stream is not None else sys.stderr
        isatty = getattr(self.stream, "isatty", None)
        interactive = force or bool(isatty and isatty())
        self.plain = enabled and not interactive
        self.done: float = 0  # as the caller counts: ints stay ints in the bar's "32/64"
        self.start = time.perf_counter()
        self._finished = False
        # no tqdm object unless it draws: even a disabled one starts tqdm's monitor thread
        self._bar: tqdm | None = None
        if enabled and interactive:
            # a whole total prints as "32/64", not "32.0/64.0"
            whole = int(self.total) if self.total.is_integer() else self.total
            from tqdm import tqdm  # only when a bar draws: 35 ms of every import

            self._bar = tqdm(total=whole, desc=label, unit=unit, file=self.stream,
                             mininterval=min_interval)
        if self.plain:
            self._write_line()

    def __enter__(self) -> Progress:  # noqa: PYI034 (typing.Self needs 3.11)
        return self

    def __exit__(self, *exc: object) -> None:
        self.finish()

    def advance(self, n: float = 1) -> None:
        self.update(self.done + n)

    def update(self, done: float) -> None:
        """Set the work done so far (not an increment, unlike tqdm's ``update``)."""
        if self._bar is not None:
            self._bar.update(done - self.done)
        self.done = done

    def finish(self) -> None:
        """Show the final state (once) and end the line."""
        if self._finished:
            return
        self._finished = True
        if self._bar is not None:
            self._bar.close()
        if self.plain:
            self._write_line()

    def _write_line(self) -> None:
        t = time.perf_counter() - self.start
        f = 1.0 if self.total == 0 else min(self.done / self.total, 1.0)
        text = f"{self.label} {100 * f:3.0f}%  {format_duration(t)}"
        if self.done > 0 and t > 0:
            text += f"  {format_rate(self.done, t, self.unit)}"
        self.stream.write(text + "\n")
        self.stream.flush()
