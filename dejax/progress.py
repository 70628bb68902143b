"""Progress of long commands on stderr, and cheap projections of their wall time.

* ``ProgressBar(n_steps, t_end)``: ``compiling()`` announces the compile phase; calling it
  as ``bar(k, n, t, wall)`` (the ``progress`` callback of ``integrate.run_chunked``) draws
  ``[####......]  42%  step 1260/3000  t = 1.26/3 s  2700 steps/s  ETA 0:00:01``; ``close``
  ends the line, saying "failed at step k" after a failure (never 100 % then). On a
  terminal the line is redrawn in place (at most every 0.5 s), elsewhere (logs) a full
  line every 10 s.
* ``projected_seconds(n_elements, n_steps)``: a rough wall-time estimate before a run
  (no compilation), ``chunk_steps``: how many steps one jitted call of a chunked run takes.
"""
from __future__ import annotations

import math
import sys
import time

SECONDS_PER_ELEMENT_STEP = 2e-3
"""Rough CPU cost of one time step per element (s): the 4x8x1 tube ran at 16 steps/s
(32 elements, 2 ms per element-step; issue 10), the 1-element block at 2,700 steps/s
(0.4 ms). Used only to warn before long runs and to size progress chunks."""

LONG_RUN_SECONDS = 180.0
"""A run projected to take longer than this (s) is announced before it starts."""


def projected_seconds(n_elements: int, n_steps: int) -> float:
    """Rough wall time (s) of ``n_steps`` steps of a mesh of ``n_elements`` elements."""
    return SECONDS_PER_ELEMENT_STEP * max(int(n_elements), 1) * max(int(n_steps), 0)


def chunk_steps(n_steps: int, seconds_per_step: float, target_s: float = 1.0, max_fraction: float = 0.01,
                cap: int = 100, frames: int | None = None) -> int:
    """Steps per jitted chunk: about ``target_s`` seconds of work, at most ``max_fraction`` of
    the run (the steps computed in vain after a failure), ``cap``, and with ``frames``
    snapshots (taken at chunk ends) at most their spacing; at least 1."""
    by_time = int(target_s / seconds_per_step) if seconds_per_step > 0 else cap
    by_fraction = math.ceil(n_steps * max_fraction)
    by_frames = n_steps // frames if frames else n_steps
    return max(1, min(int(n_steps), by_time, by_fraction, cap, by_frames))


def format_duration(seconds: float) -> str:
    """``h:mm:ss`` of a duration in seconds ("?" if not finite)."""
    if not math.isfinite(seconds) or seconds < 0:
        return "?"
    s = int(round(seconds))
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}"


def format_long_duration(seconds: float) -> str:
    """A duration in words: "45 s", "12 min", "3.4 h"."""
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


def format_line(k: int, n: int, t: float, t_end: float, wall: float, width: int = 20) -> str:
    """One progress line: bar, percent, steps, simulated time (s), rate (steps/s), ETA."""
    frac = k / n if n else 1.0
    fill = int(round(width * frac))
    rate = k / wall if wall > 0 else float("nan")
    eta = (n - k) / rate if rate > 0 else float("nan")
    return (f"[{'#' * fill}{'.' * (width - fill)}] {100 * frac:3.0f}%  step {k}/{n}  t = {t:.4g}/{t_end:.4g} s  "
            f"{rate:.3g} steps/s  ETA {format_duration(eta)}")


class ProgressBar:
    """Live progress of a time-stepping run on ``stream`` (stderr); silent with ``quiet``."""

    def __init__(self, n_steps: int, t_end: float, quiet: bool = False, stream=None, interval: float | None = None):
        self.n, self.t_end, self.quiet = int(n_steps), float(t_end), bool(quiet)
        self.stream = sys.stderr if stream is None else stream
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.interval = (0.5 if self.tty else 10.0) if interval is None else float(interval)
        self._last = -math.inf
        self._compile_start = None
        self._state = (0, 0.0, 0.0)

    def _write(self, text: str, end: str = "") -> None:
        if not self.quiet:
            self.stream.write(text + end)
            self.stream.flush()

    def compiling(self, what: str = "the time stepper", cached: bool = False) -> None:
        """Announce the compile phase (the first call of a size can take tens of seconds);
        ``cached``: JAX's persistent compilation cache is on."""
        self._compile_start = time.perf_counter()
        note = " (an identical earlier run's program is loaded from the compile cache)" if cached else ""
        self._write(f"compiling {what}{note} ...", "\n")

    def __call__(self, k: int, n: int, t: float, wall: float) -> None:
        if self._compile_start is not None:
            self._write(f"compiled in {time.perf_counter() - self._compile_start - wall:.1f} s", "\n")
            self._compile_start = None
        self._state = (int(k), float(t), float(wall))
        now = time.perf_counter()
        if now - self._last < self.interval:
            return
        self._last = now
        line = format_line(k, self.n, t, self.t_end, wall)
        self._write("\r" + line + "  " if self.tty else line, "" if self.tty else "\n")

    def close(self, failed: bool = False, k: int | None = None, t: float | None = None) -> None:
        """End the line: the final state, or where a failed run stopped (``k`` steps done, at ``t``)."""
        k0, t0, wall = self._state
        k = k0 if k is None else int(k)
        t = t0 if t is None else float(t)
        if failed:
            frac = 100 * k / self.n if self.n else 0.0
            line = (f"failed after step {k}/{self.n} ({frac:.0f}%, last converged t = {t:.4g} s), "
                    f"{format_duration(wall)} of run time")
        else:
            line = format_line(k, self.n, t, self.t_end, wall)
        self._write("\r" + line + "  " if self.tty else line, "\n")
