"""Progress of ``pneumatic-env identify``: the stage, the fraction done and the time left.

A :class:`Progress` counts work in units of simulated samples (one sample of one
parameter column of one recording): every simulation of :class:`.calibrate.FitProblem`
reports its work through :func:`advance`, and each stage states the work left
(:meth:`Progress.stage`). The time left is the planned work still to do at the rate
measured so far. It draws a ``tqdm`` bar when ``tqdm`` is importable (the ``train``
extra) and the output is a terminal, else it writes a log line at most every
``interval_s`` seconds. Nothing is shown unless a :class:`Progress` is active (the
library is silent by default; the CLI activates one unless ``--quiet``).
"""

from __future__ import annotations

import logging
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager

__all__ = ["Progress", "active", "advance", "plan", "restart_clock", "stage", "tracking"]

log = logging.getLogger("pneumatic_env.identification")
_ACTIVE: list[Progress] = []


class Progress:
    """A progress display: ``plan(work)`` adds planned work, ``advance(work)`` does it."""

    def __init__(self, bar: bool | None = None, interval_s: float = 5.0, stream=None):
        self.stream = stream or sys.stderr
        self.planned = 0.0
        self.done = 0.0
        self.stage_name = "starting"
        self.started = time.monotonic()
        self._done_at_start = 0.0
        self.interval_s = interval_s
        self._last_line = -float("inf")
        self._bar = None
        if bar is None:
            bar = bool(getattr(self.stream, "isatty", lambda: False)())
        if bar:
            try:
                from tqdm import tqdm
            except ImportError:  # the core install has no tqdm: log lines
                tqdm = None
            if tqdm is not None:
                self._bar = tqdm(
                    total=1.0,
                    file=self.stream,
                    unit="",
                    unit_scale=False,
                    bar_format="{desc} {percentage:3.0f}%|{bar}| {elapsed} elapsed{postfix}",
                )

    # -- bookkeeping ----------------------------------------------------------------------
    @property
    def fraction(self) -> float:
        return min(self.done / self.planned, 1.0) if self.planned > 0 else 0.0

    def seconds_left(self) -> float | None:
        """Planned work still to do at the rate since :meth:`restart_clock` (None before
        any work)."""
        elapsed = time.monotonic() - self.started
        done = self.done - self._done_at_start
        if done <= 0 or elapsed <= 0:
            return None
        return max(self.planned - self.done, 0.0) * elapsed / done

    def restart_clock(self) -> None:
        """Measure the rate from now on (e.g. after a first call that compiled the kernel)."""
        self.started = time.monotonic()
        self._done_at_start = self.done

    def plan(self, work: float) -> None:
        self.planned += max(float(work), 0.0)
        self._show(force=False)

    def stage(self, name: str, work_left: float = 0.0) -> None:
        """Start stage ``name``; ``work_left`` is all the work known to be left (this stage
        and the later ones), which replaces the plan."""
        self.stage_name = name
        self.planned = self.done + max(float(work_left), 0.0)
        self._show(force=True)

    def advance(self, work: float) -> None:
        self.done += max(float(work), 0.0)
        if self.done > self.planned:  # a stage took more than it planned
            self.planned = self.done
        self._show(force=False)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None

    # -- display --------------------------------------------------------------------------
    def status(self) -> str:
        left = self.seconds_left()
        eta = "time left unknown" if left is None else f"about {_duration(left)} left"
        return f"{self.stage_name}: {100 * self.fraction:.0f} % done, {eta}"

    def _show(self, force: bool) -> None:
        if self._bar is not None:
            left = self.seconds_left()
            self._bar.set_description_str(self.stage_name, refresh=False)
            self._bar.set_postfix_str(
                "time left " + ("?" if left is None else _duration(left)), refresh=False
            )
            self._bar.n = self.fraction
            self._bar.refresh()
            return
        now = time.monotonic()
        if force or now - self._last_line >= self.interval_s:
            self._last_line = now
            log.info("progress: %s", self.status())


def _duration(seconds: float) -> str:
    seconds = int(round(seconds))
    return f"{seconds // 60} min {seconds % 60:02d} s" if seconds >= 60 else f"{seconds} s"


def active() -> Progress | None:
    return _ACTIVE[-1] if _ACTIVE else None


def plan(work: float) -> None:
    if _ACTIVE:
        _ACTIVE[-1].plan(work)


def stage(name: str, work_left: float = 0.0) -> None:
    if _ACTIVE:
        _ACTIVE[-1].stage(name, work_left)


def advance(work: float) -> None:
    if _ACTIVE:
        _ACTIVE[-1].advance(work)


def restart_clock() -> None:
    if _ACTIVE:
        _ACTIVE[-1].restart_clock()


@contextmanager
def tracking(progress: Progress) -> Iterator[Progress]:
    """Make ``progress`` receive the work of everything run inside the block."""
    _ACTIVE.append(progress)
    try:
        yield progress
    finally:
        _ACTIVE.remove(progress)
        progress.close()
