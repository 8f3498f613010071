"""Identification: honest progress, the drift notice, flagged strong effects, and the
report written after each round (pneumatic_env.identification)."""

from __future__ import annotations

import pytest

from pneumatic_env.identification import progress


class _Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


# --------------------------------------------------------------------------- progress


def test_progress_fraction_is_monotone_below_one_and_time_left_follows_the_work_left():
    clock = _Clock()
    bar = progress.Progress(bar=False, interval_s=1e9, clock=clock)
    rate = 100.0  # work per second, constant
    # stages as diagnose plans them; the base fit runs 3x over its estimate
    stages = [("base fit", 1000.0, 500.0, 3000.0), ("screening", 200.0, 300.0, 200.0)]
    stages.append(("refits", 300.0, 0.0, 450.0))
    fractions = []
    for name, planned, later, actual in stages:
        bar.stage(name, planned, later=later)
        for _ in range(int(actual // 10)):
            clock.t += 10.0 / rate
            bar.advance(10.0)
            fractions.append(bar.fraction)
            left = bar.seconds_left()
            assert left is not None and left > 0  # work remains: never "0 s left"
            assert left == pytest.approx(bar.work_left() / rate)
    assert fractions == sorted(fractions)
    assert max(fractions) < 1.0
    assert max(fractions) <= 0.99
    # the overrun grew the base fit's estimate: the time left never hit zero there
    assert all(f < 0.99 for f in fractions[:100])
    bar.finish()
    assert bar.fraction == 1.0 and bar.seconds_left() == 0.0


def test_progress_matches_the_plan_when_the_plan_holds():
    bar = progress.Progress(bar=False, interval_s=1e9, clock=_Clock())
    bar.stage("base fit", 60.0, later=40.0)
    bar.advance(30.0)
    assert bar.fraction == pytest.approx(0.3)
    bar.advance(20.0)
    assert bar.fraction == pytest.approx(0.5)
    assert bar.work_left() == pytest.approx(50.0)


def test_a_worker_process_reports_its_work_through_the_shared_counter():
    import multiprocessing

    counter = multiprocessing.get_context("fork").Value("d", 0.0)
    bar = progress.Progress(bar=False, interval_s=1e9)
    saved_active, saved_shared = list(progress._ACTIVE), list(progress._SHARED)
    try:
        progress._ACTIVE.append(bar)  # the parent's display, as copied by fork
        progress.report_to(counter)  # in the worker: its work goes to the counter
        progress.advance(7.0)
        assert counter.value == 7.0 and bar.done == 0.0
    finally:
        progress._ACTIVE[:], progress._SHARED[:] = saved_active, saved_shared
