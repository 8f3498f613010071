"""Progress of ``pneumatic-env identify``: the stage, the fraction done and the time left.

A :class:`Progress` counts work in units of simulated samples x substeps x parameter
columns: every simulation of :class:`.problem.FitProblem` reports its work through
:func:`advance` (a refit in a worker process through a shared counter,
:func:`report_to`), and each stage states its own work and the work planned after it
before it starts (:meth:`Progress.stage`). The time left is the work left at the rate
measured so far. When a stage runs over its estimate, the estimate grows (the work
left in the stage becomes ``overrun_share`` of the stage's work done so far), so the
time left never reads 0 while work remains. The fraction done is the share of the
work left that each step did: it never falls when an estimate grows, and it stays at
most ``max_unfinished`` (99 %) until :meth:`Progress.finish`.

It draws a ``tqdm`` bar when ``tqdm`` is importable (the ``train`` extra) and the
output is a terminal, else it writes a log line at most every ``interval_s`` seconds.
Nothing is shown unless a :class:`Progress` is active (the library is silent by
default; the CLI activates one unless ``--quiet``). Shown or not, every stage's start and
the work done by then go to a ledger (:func:`ledger`): what each stage cost.
"""

from __future__ import annotations

import logging
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

__all__ = [
    "Progress",
    "active",
    "advance",
    "finish",
    "ledger",
    "plan",
    "report_to",
    "restart_clock",
    "stage",
    "tracking",
]

log = logging.getLogger("pneumatic_env.identification")
_ACTIVE: list[Progress] = []
_SHARED: list = []  # in a worker process: the parent's multiprocessing.Value of work done
_WORK = [0.0]  # all the work reported here (and by this process's workers), shown or not
_LEDGER: list[tuple[str, float, float]] = []  # (stage, start, work done before it)


class Progress:
    """A progress display: :meth:`stage` states the work ahead, :meth:`advance` does it."""

    def __init__(
        self,
        bar: bool | None = None,
        interval_s: float = 5.0,
        stream=None,
        clock: Callable[[], float] = time.monotonic,
        overrun_share: float = 0.25,
        max_unfinished: float = 0.99,
    ):
        self.stream = stream or sys.stderr
        self.clock = clock
        self.overrun_share = overrun_share
        self.max_unfinished = max_unfinished
        self.done = 0.0
        self.stage_name = "starting"
        self.stage_work = 0.0  # the current stage's estimate (grows when overrun)
        self.stage_done = 0.0
        self.later = 0.0  # work planned after the current stage
        self.finished = False
        self._fraction = 0.0
        self.started = clock()
        self._done_at_start = 0.0
        self.interval_s = interval_s
        self._last_line = -float("inf")
        self._bar = _tqdm_bar(self.stream) if _wants_bar(bar, self.stream) else None

    # -- bookkeeping ----------------------------------------------------------------------
    @property
    def planned(self) -> float:
        """All work: done, and left by the current estimates."""
        return self.done + self.work_left()

    @property
    def fraction(self) -> float:
        """Share done: 1 only after :meth:`finish`."""
        return 1.0 if self.finished else min(self._fraction, self.max_unfinished)

    def work_left(self) -> float:
        """Work left in the current stage and the ones planned after it."""
        return max(self.stage_work - self.stage_done, 0.0) + self.later

    def seconds_left(self) -> float | None:
        """The work left at the rate since :meth:`restart_clock` (None before any work)."""
        if self.finished:
            return 0.0
        elapsed = self.clock() - self.started
        done = self.done - self._done_at_start
        if done <= 0 or elapsed <= 0:
            return None
        return self.work_left() * elapsed / done

    def restart_clock(self) -> None:
        """Measure the rate from now on (e.g. after a first call that compiled the kernel)."""
        self.started = self.clock()
        self._done_at_start = self.done

    def plan(self, work: float) -> None:
        """Add ``work`` to the work planned after the current stage."""
        self.later += max(float(work), 0.0)
        self._show(force=False)

    def stage(self, name: str, work: float = 0.0, later: float = 0.0) -> None:
        """Start stage ``name`` of ``work``, with ``later`` planned after it (replacing
        the previous plan)."""
        self.stage_name = name
        self.stage_work = max(float(work), 0.0)
        self.stage_done = 0.0
        self.later = max(float(later), 0.0)
        self._show(force=True)

    def advance(self, work: float) -> None:
        work = max(float(work), 0.0)
        self.done += work
        self.stage_done += work
        if self.stage_done >= self.stage_work and work > 0:  # the stage ran over: grow
            self.stage_work = self.stage_done * (1.0 + self.overrun_share)
        left = self.work_left()
        if work > 0 and left + work > 0:
            self._fraction += (1.0 - self._fraction) * work / (left + work)
        self._show(force=False)

    def finish(self, name: str = "done") -> None:
        """All work is done: 100 %."""
        self.stage_name = name
        self.stage_work = self.stage_done = self.later = 0.0
        self.finished = True
        self._show(force=True)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None

    # -- display --------------------------------------------------------------------------
    def status(self) -> str:
        left = self.seconds_left()
        eta = "time left unknown" if left is None else f"about {_duration(left)} left"
        return f"{self.stage_name}: {int(100 * self.fraction)} % done, {eta}"

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


def _wants_bar(bar: bool | None, stream) -> bool:
    return bool(getattr(stream, "isatty", lambda: False)()) if bar is None else bar


def _tqdm_bar(stream):
    """A ``tqdm`` bar over the fraction 0..1, or None without ``tqdm``."""
    try:
        from tqdm import tqdm
    except ImportError:  # the core install has no tqdm: log lines
        return None
    return tqdm(
        total=1.0,
        file=stream,
        unit="",
        unit_scale=False,
        bar_format="{desc} {percentage:3.0f}%|{bar}| {elapsed} elapsed{postfix}",
    )


def _duration(seconds: float) -> str:
    seconds = int(round(seconds))
    return f"{seconds // 60} min {seconds % 60:02d} s" if seconds >= 60 else f"{seconds} s"


def active() -> Progress | None:
    return _ACTIVE[-1] if _ACTIVE else None


def plan(work: float) -> None:
    if _ACTIVE:
        _ACTIVE[-1].plan(work)


def stage(name: str, work: float = 0.0, later: float = 0.0) -> None:
    _LEDGER.append((name, time.monotonic(), _WORK[0]))
    if _ACTIVE:
        _ACTIVE[-1].stage(name, work, later)


def ledger(start: bool = False) -> list[dict]:
    """Each stage since the ledger was last started, in order: its name, seconds and work
    (the stage running now up to now); ``start=True`` starts the ledger afresh instead."""
    if start:
        _LEDGER.clear()
        return []
    ends = [(t, w) for _, t, w in _LEDGER[1:]] + [(time.monotonic(), _WORK[0])]
    return [
        {"stage": name, "seconds": t_end - t, "work": w_end - w}
        for (name, t, w), (t_end, w_end) in zip(_LEDGER, ends)
    ]


def advance(work: float) -> None:
    _WORK[0] += work
    if _ACTIVE:
        _ACTIVE[-1].advance(work)
    for counter in _SHARED:
        with counter.get_lock():
            counter.value += work


def finish(name: str = "done") -> None:
    if _ACTIVE:
        _ACTIVE[-1].finish(name)


def restart_clock() -> None:
    if _ACTIVE:
        _ACTIVE[-1].restart_clock()


def report_to(counter) -> None:
    """In a worker process: add the work done to ``counter`` (a ``multiprocessing.Value``
    the parent reads and shows), not to the parent's display copied by ``fork``."""
    _ACTIVE.clear()
    _SHARED[:] = [counter]


@contextmanager
def tracking(progress: Progress) -> Iterator[Progress]:
    """Make ``progress`` receive the work of everything run inside the block."""
    _ACTIVE.append(progress)
    try:
        yield progress
    finally:
        _ACTIVE.remove(progress)
        progress.close()
