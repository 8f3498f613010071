"""Identification: honest progress, the drift notice, flagged strong effects, and the
report written after each round (pneumatic_env.identification)."""

from __future__ import annotations

import json
from types import SimpleNamespace

import pytest

from pneumatic_env.identification import progress
from pneumatic_env.identification.checks import read_checked
from pneumatic_env.identification.config import _parse_parameter, load_config
from pneumatic_env.identification.diagnose import diagnose
from pneumatic_env.identification.drift import base_drifts, suggested_effects
from pneumatic_env.identification.report import _drift_lines, write_report
from pneumatic_env.identification.results import WIDE_INTERVAL, FitResult
from pneumatic_env.identification.scoring import _parameter_verdict, acceptance
from pneumatic_env.identification.selection import WorkPlan, work_after_refits
from pneumatic_env.params import ConfigError
from pneumatic_env.studies.virtual_rig import make_recording


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


def test_a_round_that_may_accept_an_effect_keeps_the_next_round_in_the_plan():
    """Round 1 plans what accepting an effect would start (re-converging, round 2's
    screening and refits): at the end of its refits the display shows the share of that
    plan done, not 99 %; the last round and ``--quick`` plan nothing after their refits."""
    plan = WorkPlan(base=0.0, round=0.0, refit=100.0, column=1.0)
    settings = SimpleNamespace(max_effects=3, top_k=3)
    pool = [SimpleNamespace(kind="plant", parameters=[1, 2]) for _ in range(10)]
    after = work_after_refits(plan, settings, 4, pool, 1, False)
    # re-converging 1 refit, round 2: 3 refits + its freer form, 9 candidates x 3 columns
    assert after == pytest.approx(100.0 * 5 + (4 + 1 + 9 * 3))
    assert work_after_refits(plan, settings, 4, pool, 3, False) == 0.0  # the last round
    assert work_after_refits(plan, settings, 4, pool, 1, True) == 0.0  # --quick
    assert work_after_refits(plan, settings, 4, pool[:1], 1, False) == 0.0  # none left
    bar = progress.Progress(bar=False, interval_s=1e9, clock=_Clock())
    screening = plan.screening(pool, 4)
    bar.stage("screening", screening, later=3 * plan.refit + after)
    bar.advance(screening)
    bar.stage("refits", 3 * plan.refit, later=after)
    bar.advance(3 * plan.refit)  # round 1 done as planned
    done = screening + 3 * plan.refit
    assert 0.3 < bar.fraction <= done / (done + after)
    # without the next round in the plan the same work would read nearly done
    unplanned = progress.Progress(bar=False, interval_s=1e9, clock=_Clock())
    unplanned.stage("screening", screening, later=3 * plan.refit)
    unplanned.advance(screening)
    unplanned.stage("refits", 3 * plan.refit)
    unplanned.advance(3 * plan.refit)
    assert unplanned.fraction > 0.75


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


# --------------------------------------------------------------------------- drift notice


def _fit_with(values: dict) -> FitResult:
    """A calibrated base model with these fitted values (statistics left neutral)."""
    cfg = load_config()
    params = [cfg.base_parameters[n] for n in values]
    return FitResult(
        parameters=params,
        values=dict(values),
        fixed={},
        std=dict.fromkeys(values, 0.0),
        ci={n: (v, v) for n, v in values.items()},
        identified=dict.fromkeys(values, True),
        plausible={p.name: p.plausible_min <= values[p.name] <= p.plausible_max for p in params},
        flags={n: [] for n in values},
        correlations=[],
        condition_number=1.0,
        cost=1.0,
        rss=1.0,
        n_residuals=10,
        rho1=0.0,
        n_eff=10.0,
        nfev=1,
        message="",
    )


def test_drift_notice_names_the_parameters_outside_their_range_and_what_they_stand_for():
    cfg = load_config()
    nominal = {"discharge_coefficient": 0.25, "coil_force_n_per_a": 2.78}
    data = SimpleNamespace(values={**nominal, "dead_volume_cap_m3": 1e-6})
    fit = _fit_with(
        {"discharge_coefficient": 0.02, "coil_force_n_per_a": 2.9, "dead_volume_cap_m3": 9e-6}
    )
    drifts = base_drifts(fit, [data], cfg)
    # farthest first: 0.05 / 0.02 = 2.5 x below, 9 / 5 = 1.8 x above; the gain is inside
    assert [d.name for d in drifts] == ["discharge_coefficient", "dead_volume_cap_m3"]
    cd = drifts[0]
    assert cd.direction == "below" and cd.nominal == 0.25 and cd.fitted == 0.02
    assert cd.factor == pytest.approx(0.05 / 0.02)  # plausible_min / fitted
    assert "tube_waves" in cd.effects and cd.explanation
    assert drifts[1].direction == "above" and drifts[1].factor == pytest.approx(9e-6 / 5e-6)
    assert suggested_effects(drifts)[0] == drifts[0].effects[0]
    # the report's table names each, with its values and what it may stand for
    tube = {"name": "tube_waves", "round": 1, "refitted": True, "accepted": False}
    data_json = {
        "base_drift": [d.to_dict() for d in drifts],
        "suggested_by_drift": suggested_effects(drifts),
        "candidates": [tube],
    }
    lines = "\n".join(_drift_lines(data_json))
    assert "| discharge_coefficient | 0.25 - | 0.02 | [0.05, 0.95] | 2.50 x below |" in lines
    assert "tube_waves (refitted, not accepted)" in lines
    assert "supply_droop (not tried)" in lines
    assert _drift_lines({"base_drift": [], "suggested_by_drift": [], "candidates": []}) == []


def test_a_dead_volume_held_at_its_floor_is_a_drift_a_friction_at_zero_is_not():
    """The dead volumes are simulated no smaller than their plausible minimum
    (``simulated_min``: a smaller chamber makes the kernel split its substeps): a
    coordinate below maps to the floor, one above is untouched; a fit held there is
    reported, a fit just inside is not, and a friction at its physical floor of zero is not
    a held edge."""
    cfg = load_config()
    cap = cfg.base_parameters["dead_volume_cap_m3"]
    assert cap.lower < cap.simulated_min == cap.plausible_min  # the config's floor
    assert cap.from_u(cap.to_u(0.5 * cap.plausible_min)) == cap.plausible_min
    above = 1.37 * cap.plausible_min
    assert cap.from_u(cap.to_u(above)) == pytest.approx(above, rel=1e-12)
    data = SimpleNamespace(values={"dead_volume_cap_m3": 1e-6, "dead_volume_rod_m3": 1e-6})
    fit = _fit_with(
        {
            "dead_volume_cap_m3": cap.from_u(cap.to_u(0.2 * cap.plausible_min)),
            "dead_volume_rod_m3": 2.0 * cap.plausible_min,
            "static_friction_n": 0.0,
        }
    )
    drifts = base_drifts(fit, [data], cfg)
    assert [d.name for d in drifts] == ["dead_volume_cap_m3"]
    held = drifts[0]
    assert held.held_at_bound and held.direction == "below" and held.factor == 1.0
    row = "\n".join(
        _drift_lines({"base_drift": [held.to_dict()], "suggested_by_drift": [], "candidates": []})
    )
    assert "| held at its floor, below |" in row
    # a floor outside the optimiser's bounds is refused, naming the entry, value and range
    entry = {**cfg.raw["base_parameters"]["dead_volume_cap_m3"], "simulated_min": 1e-5}
    refused = r"'dead_volume_cap_m3': 'simulated_min' 1e-05 must be in \[1e-08, 6e-06\)"
    with pytest.raises(ConfigError, match=refused):
        _parse_parameter("identification.yaml", "dead_volume_cap_m3", entry, "plant", False)


# --------------------------------------------------------------------------- acceptance


def test_a_strong_effect_outside_its_plausible_range_is_accepted_flagged_a_weak_one_not():
    cfg = load_config()
    outside = ["supply_resistance_pa_s_per_kg = 3.3e+07 Pa s/kg is outside the plausible range"]
    args = dict(how="median", delta_ic=-500.0, identified=True, min_rel=0.1, min_ic=10.0)
    accepted, reasons, flags = acceptance(0.37, outside=outside, cfg=cfg, **args)
    assert accepted and not reasons
    assert flags == ["fitted value outside the plausible range: " + outside[0]]
    accepted, reasons, flags = acceptance(0.15, outside=outside, cfg=cfg, **args)
    assert not accepted and not flags and outside[0] in reasons
    accepted, reasons, flags = acceptance(0.15, outside=[], cfg=cfg, **args)
    assert accepted and not reasons and not flags
    # a strong improvement is no licence without identification
    accepted, _, _ = acceptance(0.37, outside=outside, cfg=cfg, **{**args, "identified": False})
    assert not accepted


def test_a_strong_effect_whose_strength_is_loose_is_accepted_flagged_a_weak_one_not():
    """A parameter whose only shortfall is a confidence interval wider than its plausible
    range (off value outside it): the data show the effect, not its strength. Accepted
    flagged at or above diagnosis.min_improvement_when_implausible (25 %), refused below
    with the reason; an effect not identified otherwise stays refused however strong."""
    cfg = load_config()
    loose = ["wall_heat_transfer_w_per_k = 0.0267 W/K, confidence interval [0.000325, 2.19]"]
    args = dict(how="median", delta_ic=-34.0, identified=True, outside=[], min_rel=0.1)
    accepted, reasons, flags = acceptance(0.58, min_ic=10.0, cfg=cfg, loose=loose, **args)
    assert accepted and not reasons
    assert flags == ["strength not pinned down: " + loose[0]]
    accepted, reasons, flags = acceptance(0.15, min_ic=10.0, cfg=cfg, loose=loose, **args)
    assert not accepted and not flags
    assert "needs a held-out improvement of at least 25 %" in reasons[-1]
    # the BIC rule still holds, and another parameter not identified is no licence
    accepted, _, _ = acceptance(0.58, min_ic=50.0, cfg=cfg, loose=loose, **args)
    assert not accepted
    unidentified = {**args, "identified": False}
    accepted, _, _ = acceptance(0.58, min_ic=10.0, cfg=cfg, loose=loose, **unidentified)
    assert not accepted


def test_only_a_wide_interval_with_the_off_value_outside_it_counts_as_loose():
    """_parameter_verdict: a parameter is loose when its one flag is the wide interval
    and its neutral (off) value lies outside the interval; a collinear one, one at a
    bound as well, or one whose interval holds the off value is not."""
    par = SimpleNamespace(name="g", unit="W/K", neutral=0.0, plausible_min=1e-3, plausible_max=2.0)
    cand = SimpleNamespace(parameters=[par])

    def verdict(ci, flags):
        fit = SimpleNamespace(
            ci={"g": ci},
            flags={"g": flags},
            identified={"g": not flags},
            values={"g": 0.03},
            plausible={"g": True},
        )
        return _parameter_verdict(cand, fit)

    plausible, identified, reasons, outside, loose = verdict((3e-4, 2.2), [WIDE_INTERVAL])
    assert plausible and identified and not outside and len(loose) == 1  # apart from loose
    assert "[0.0003, 2.2]" in loose[0] and "g not identified" in reasons[0]
    for ci, flags in (
        ((-0.5, 2.6), [WIDE_INTERVAL]),  # the off value inside
        ((3e-4, 2.2), [WIDE_INTERVAL, "at a bound of the fit"]),
        ((3e-4, 2.2), ["near-collinear with h", WIDE_INTERVAL]),
    ):
        _, identified, _, _, loose = verdict(ci, flags)
        assert not identified and not loose
    assert verdict((0.01, 0.1), [])[1:] == (True, [], [], [])


# --------------------------------------------------------------------------- anytime report


def test_the_report_is_written_before_each_round_with_what_was_found_so_far(tmp_path):
    csv = tmp_path / "leakage_1.csv"
    make_recording(tmp_path, name="leakage_1", effect="leakage", seed=1, duration_s=1.0)
    out = tmp_path / "report"
    seen = []

    def write_so_far(diag):
        data = write_report(diag, out, plots=False)
        seen.append(json.loads((out / "diagnosis.json").read_text()))
        assert data == seen[-1]
        assert "Status: running" in (out / "report.md").read_text()
        assert (out / "fitted_final.yaml").is_file()

    diag = diagnose(
        [read_checked(csv)],
        candidates=["leakage", "pressure_sensor_offset"],
        max_effects=2,
        jobs=1,
        on_round=write_so_far,
    )
    assert [s["status"] for s in seen] == ["running, round 1", "running, round 2"]
    assert seen[0]["selected"] == [] and seen[0]["candidates"] == []
    after_round_1 = seen[1]
    assert after_round_1["selected"] == ["leakage"] == diag.selected[:1]
    assert {c["name"] for c in after_round_1["candidates"]} == {"leakage", "pressure_sensor_offset"}
    assert "beyond leakage" in after_round_1["still_checking"]
    assert diag.status == "complete" and diag.to_json()["still_checking"] is None
    # what each stage cost beside the kernel: every simulating stage is in the ledger, the
    # lane-substeps add up to the work the stages reported, and none beat the kernel by
    # much (the kernel alone on every core is the floor; timing noise aside)
    costs = diag.to_json()["stage_costs"]
    names = [r["stage"] for r in costs]
    assert names[0] == "timing a simulation of the data" and "base fit" in names
    assert any(n.startswith("screening") for n in names)
    assert any(n.startswith("refitting") for n in names)
    simulating = [r for r in costs if r["lane_substeps"] > 0]
    assert len(simulating) >= 4
    assert all(r["ratio_to_kernel"] > 0.5 for r in simulating), costs
    assert diag.to_json()["kernel_lane_substeps_per_s"] > 1e5
    total = sum(r["seconds"] for r in costs)
    assert total <= diag.timings["total"] + 1e-6
    write_report(diag, out, plots=False)
    report = (out / "report.md").read_text()
    assert "## Time" in report and "| base fit |" in report
