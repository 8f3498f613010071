"""Identification on a campaign of experiments (issue 20): screening, the moving-rod base
fit, the campaign hold-out, progress, and the report's confidence fields.

All recordings come from the virtual rig (synthetic): campaigns of three 1 s experiments
(clamped steps, clamped multisine, spring), few candidates. The claims and their
thresholds were fixed before the data were generated (comments say why).
"""

from __future__ import annotations

import json
import logging
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from pneumatic_env.identification import progress
from pneumatic_env.identification.calibrate import (
    Dataset,
    base_fit_parameters,
    calibrate,
    prepare_datasets,
    run_fit,
)
from pneumatic_env.identification.candidates import candidate_table
from pneumatic_env.identification.checks import read_checked
from pneumatic_env.identification.config import load_config
from pneumatic_env.identification.diagnose import diagnose
from pneumatic_env.identification.holdout import Holdout
from pneumatic_env.identification.later_effects import (
    FreerForm,
    fit_freer_form,
    freer_form_check,
    per_mode_parameters,
    second_effect_support,
)
from pneumatic_env.identification.problem import FitProblem
from pneumatic_env.identification.report import write_report
from pneumatic_env.identification.scoring import CandidateScore
from pneumatic_env.identification.selection import best_first
from pneumatic_env.studies.rig_campaign import CAMPAIGNS, Experiment, make_campaign

SEEDS = (1, 2, 3)
# a plant effect, its closest rivals (a leak elsewhere) and two sensor effects
CANDIDATES = [
    "leakage",
    "rod_seal_leak",
    "valve_null_leak",
    "pressure_sensor_offset",
    "pressure_sensor_lag",
]


@pytest.fixture(scope="module")
def campaign_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("campaigns")


def _campaign(root: Path, effect: str, seed: int, campaign="small") -> list[Path]:
    out = root / f"{effect}_{seed}"
    paths = sorted(out.glob("*.csv"))
    if not paths:
        paths = make_campaign(out, effect=effect, seed=seed, campaign=campaign)
    return paths


# --------------------------------------------------------------------------- screening


@pytest.mark.slow
def test_screening_ranks_the_true_effect_first_on_every_seed(campaign_dir):
    """Quick mode (screening only) on a small leak campaign: the leak is ranked first on
    each of three rig seeds, with a predicted BIC drop and training-error drop that pass
    the acceptance thresholds (10 and 10 %): a ranking that a refit can confirm. (The
    first version ranked by the predicted held-out error and failed this on seed 2: -140 %
    held out for the leak, whose refit is right; see screening.py.)"""
    cfg = load_config()
    for seed in SEEDS:
        recs = [read_checked(p) for p in _campaign(campaign_dir, "leakage", seed)]
        diag = diagnose(recs, candidates=CANDIDATES, quick=True)
        ranking = diag.screening[0]["ranking"]
        assert ranking[0]["name"] == "leakage", (seed, ranking[:3])
        assert ranking[0]["predicted_delta_ic"] <= -cfg.diagnosis("min_ic_drop"), seed
        assert ranking[0]["predicted_training_improvement"] >= cfg.diagnosis(
            "min_relative_improvement"
        ), seed
        assert diag.selected == [] and diag.quick
        assert all(not s.refitted for s in diag.scores)


# --------------------------------------------------------------------------- base fit


@pytest.mark.slow
@pytest.mark.parametrize("seed", [1, 2])
def test_moving_rod_base_fit_converges_monotonically(campaign_dir, seed):
    """Spring and free rods (stick-slip friction): every accepted point of the base fit
    lowers the robust cost, the number of Jacobians is bounded, the fit states why it
    stopped, and it ends far below its start (the stick-event staircase does not stall
    it: at least a 5x lower cost, fixed before the run from the clamped fits' 10-100x),
    in the rig's stick-event basin: the static friction within 10 % of the rig's (a claim
    added with the wider friction search, fixed before its run; the narrow search ended
    16 % low on a clean seed-2 campaign)."""
    campaign = (
        Experiment("spring", "spring", "prbs", 1.0),
        Experiment("free", "free", "multisine", 1.0),
    )
    paths = make_campaign(
        campaign_dir / f"moving_{seed}", seed=seed, campaign=campaign, overwrite=True
    )
    cfg = load_config()
    cal = calibrate([read_checked(p) for p in paths])
    res = cal.result
    history = np.array(res.cost_history)
    assert history.size >= 2
    assert np.all(np.diff(history) <= 1e-12 * history[:-1]), history
    bound = (1 + cfg.number("fit", "friction_searches")) * cfg.number("fit", "max_nfev") + 1
    assert res.n_jacobians <= bound
    assert res.message and res.message != "nothing to fit"
    assert history[-1] < history[0] / 5.0
    assert {"static_friction_n", "dynamic_friction_n"} <= set(res.values)
    truth = json.loads(paths[0].with_suffix(".truth.json").read_text(encoding="utf-8"))
    rig_static_n = truth["parameters"]["static_friction_n"]
    assert abs(res.values["static_friction_n"] / rig_static_n - 1.0) < 0.10, (
        res.values["static_friction_n"],
        rig_static_n,
    )


# --------------------------------------------------------------------------- hold-out


def _fake(name: str, mode: str, n: int = 1000) -> Dataset:
    return Dataset(
        name=name,
        recording=SimpleNamespace(n_samples=n),
        values={},
        channels=("p1",),
        scales={"p1": 1.0},
        usable={"p1": np.ones(n, bool)},
        dt_s=1e-3,
        substeps=10,
        initial=None,
        moving=mode != "fixed",
        rod_mode=mode,
    )


def test_campaign_holdout_scores_every_experiment_type():
    """Of each rod mode with two or more recordings the last is held out whole; a mode
    with one recording is split in time; every mode is scored on held-out data."""
    cfg = load_config()
    ds = [
        _fake("c1", "fixed"),
        _fake("c2", "fixed"),
        _fake("c3", "fixed"),
        _fake("s1", "spring"),
        _fake("f1", "free"),
    ]
    split = Holdout(ds, "auto", cfg)
    assert split.info["mode"] == "campaign"
    assert split.info["held_out"] == ["c3"]
    assert split.info["time_split"] == ["s1", "f1"]
    assert [d.name for d in split.train] == ["c1", "c2", "s1", "f1"]
    assert split.train_n == [1000, 1000, 600, 600]
    assert {d.rod_mode for d in split.held} == {"fixed", "spring", "free"}
    masks = dict(zip([d.name for d in split.held], split.held_masks))
    assert masks["c3"]["p1"].all()
    assert not masks["s1"]["p1"][:600].any() and masks["s1"]["p1"][600:].all()
    # two recordings: a time split keeps both in the fit
    assert Holdout(ds[:2], "auto", cfg).info["mode"] == "time"
    with pytest.raises(ValueError, match=r"holdout = 'loo' is not allowed: must be one of"):
        Holdout(ds, "loo", cfg)


def _score(per: dict) -> CandidateScore:
    cand = candidate_table()["rod_seal_leak"]
    return CandidateScore(
        cand, 2, None, {}, 0.1, 0.15, -20.0, True, True, True, [], per_recording=per
    )


@pytest.mark.parametrize(
    "per, acts_on, accepted, reason",
    [
        ({"c3": 0.25, "s1": 0.12}, {"c3", "s1"}, True, None),
        ({"c3": 0.25, "s1": 0.02}, {"c3", "s1"}, False, "not 10 % better on every held-out"),
        ({"c3": 0.30, "s1": -0.04}, {"c3", "s1"}, False, "worse with it: s1 -4.0 %"),
        # a friction law: judged where the rod moves (s1), the clamped c3 may stay as it was
        ({"c3": 0.01, "s1": 0.2}, {"s1"}, True, None),
        ({"c3": 0.25, "s1": 0.05}, {"s1"}, False, "not 10 % better on every held-out"),
    ],
)
def test_a_second_effect_needs_support_on_every_recording_it_acts_on(
    per, acts_on, accepted, reason
):
    sc = _score(per)
    second_effect_support(sc, 0.10, acts_on)
    assert sc.accepted is accepted
    if reason:
        assert any(reason in r for r in sc.reasons), sc.reasons


@pytest.mark.parametrize(
    "per, accepted, reason",
    [
        # a recording the refit changed by less than the band did not show the effect
        ({"c3": -0.014, "s1": 0.495, "f1": 0.297}, True, None),
        ({"c3": 0.008, "s1": 0.3, "f1": 0.12}, True, None),
        # shown, but not enough / the other way: refused as before
        ({"c3": 0.05, "s1": 0.495, "f1": 0.297}, False, "not 10 % better on every held-out"),
        ({"c3": -0.029, "s1": 0.4, "f1": 0.3}, False, "worse with it: c3 -2.9 %"),
        # no recording shows it
        ({"c3": 0.01, "s1": -0.015, "f1": 0.019}, False, "none changed by 2 % or more"),
    ],
)
def test_a_recording_a_second_effect_leaves_as_it_was_neither_supports_nor_refuses_it(
    per, accepted, reason
):
    """With a band of 2 % (``diagnosis.refit_noise_band``: what refits that add nothing
    change), a held-out recording whose error moved by less either way is left out of the
    later-effect rule; the others must be 10 % better and none worse by the band."""
    sc = _score(per)
    second_effect_support(sc, 0.10, {"c3", "s1", "f1"}, 0.02)
    assert sc.accepted is accepted
    if reason:
        assert any(reason in r for r in sc.reasons), sc.reasons


def test_the_accepted_effect_that_predicts_the_held_out_data_best_is_adopted():
    """Of the accepted effects of a round, the one whose model has the lowest held-out
    NRMSE goes first, not the one with the best median over recordings (issue 34: on a
    2 m tube-wave rig an exhaust discharge, median 56 % better but one recording 22 %
    worse, NRMSE 0.112, was adopted over the tube's waves, 51 %, every recording better,
    0.076); equal errors keep the order of the median."""
    table = candidate_table()

    def accepted(name, nrmse, median):
        return CandidateScore(table[name], 1, None, {}, nrmse, median, -50.0, True, True, True)

    exhaust = accepted("exhaust_discharge", 0.112, 0.555)
    waves = accepted("tube_waves", 0.076, 0.505)
    heat = accepted("heat_transfer", 0.076, 0.6)
    assert [s.name for s in best_first([exhaust, waves])] == ["tube_waves", "exhaust_discharge"]
    assert [s.name for s in best_first([exhaust, waves, heat])] == [
        "heat_transfer",
        "tube_waves",
        "exhaust_discharge",
    ]


def test_the_freer_form_frees_each_effect_per_rod_mode_it_acts_in():
    """Per-mode copies of a selected effect's plant parameters: every rod mode for a
    plant effect, the moving ones for a friction law, none for a sensor effect or an
    effect that acts in one mode only (a load cell's compliance: clamped rods)."""
    table = candidate_table()
    modes = ["fixed", "free", "spring"]
    names = [p.name for p in per_mode_parameters([table["heat_transfer"]], modes)]
    (param,) = table["heat_transfer"].parameter_names
    assert names == [f"{param}@{m}" for m in modes]
    lugre = [p.name for p in per_mode_parameters([table["lugre"]], modes)]
    assert lugre and all(n.endswith(("@free", "@spring")) for n in lugre)
    assert len(lugre) == 2 * len(table["lugre"].parameters)
    for name in ("pressure_sensor_offset", "load_cell_compliance"):
        assert per_mode_parameters([table[name]], modes) == []
    assert per_mode_parameters([table["heat_transfer"]], ["fixed"]) == []


@pytest.mark.parametrize(
    "freer, accepted, reason",
    [
        # the freer form explains little: the second effect is 15-20 % better than it
        ({"c3": 0.0095, "s1": 0.0098, "f1": 0.0099}, True, None),
        # the freer form explains as much as the second effect on one experiment type
        ({"c3": 0.0095, "s1": 0.0079, "f1": 0.0099}, False, "per experiment type"),
        # a freer form that extrapolates worse than the current model sets no bar
        ({"c3": 0.02, "s1": 0.03, "f1": 0.04}, True, None),
    ],
)
def test_a_second_effect_must_beat_the_first_refitted_per_experiment(freer, accepted, reason):
    """The current model's held-out NRMSE is 0.01 on each recording, the second effect's
    0.008 (20 % better, past the 10 % threshold): it stays only when it is also 10 %
    better than the freer form of the first effect on every recording, each against the
    lower of the freer form's and the current model's error."""
    sc = _score({"c3": 0.2, "s1": 0.2, "f1": 0.2})
    sc.per_recording_nrmse = {"c3": 0.008, "s1": 0.008, "f1": 0.008}
    current = {"c3": 0.01, "s1": 0.01, "f1": 0.01}
    form = FreerForm(fit=None, per_recording_nrmse=freer, parameters=[])
    margin = freer_form_check(sc, form, current, 0.10, {"c3", "s1", "f1"})
    assert sc.accepted is accepted
    assert (margin >= 0.10) is accepted
    if reason:
        assert any(reason in r for r in sc.reasons), sc.reasons
    else:
        assert any("beats the freer form" in n for n in sc.notes), sc.notes


def test_the_freer_form_is_not_asked_to_lose_on_a_recording_that_did_not_show_the_effect():
    """A recording the second effect left as it was (c3: 1 % better than the current model,
    within the 2 % band) is not compared with the freer form, which fits it 10 % better;
    without the band it refuses the effect."""
    current = {"c3": 0.01, "s1": 0.01, "f1": 0.01}
    freer = FreerForm(
        fit=None, per_recording_nrmse={"c3": 0.009, "s1": 0.0098, "f1": 0.0099}, parameters=[]
    )
    for band, accepted in ((0.02, True), (0.0, False)):
        sc = _score({"c3": 0.01, "s1": 0.2, "f1": 0.2})
        sc.per_recording_nrmse = {"c3": 0.0099, "s1": 0.008, "f1": 0.008}
        margin = freer_form_check(sc, freer, current, 0.10, {"c3", "s1", "f1"}, band)
        assert sc.accepted is accepted, (band, sc.reasons)
        assert (margin >= 0.10) is accepted


@pytest.mark.slow
def test_the_freer_form_nests_the_current_model(campaign_dir):
    """Fitted from the current model's values, the freer form (the selected effect per
    rod mode) reaches a training cost no higher than the current model's over two rig
    seeds, and its per-mode values differ from each other (they are fitted, not copied)."""
    cfg = load_config()
    cand = candidate_table(cfg)["heat_transfer"]
    for seed in (1, 2):
        paths = _campaign(campaign_dir, "heat_transfer", seed)
        datasets, _ = prepare_datasets([read_checked(p) for p in paths], None, cfg)
        split = Holdout(datasets, "auto", cfg)
        refit = base_fit_parameters(datasets, ["discharge_coefficient"], cfg)
        free = refit + list(cand.parameters)
        problem = FitProblem(split.train, free, n_samples=split.train_n, config=cfg)
        current = run_fit(problem, tolerance=1e-3)
        form = fit_freer_form([cand], current, refit, split, 20, cfg)
        assert form is not None
        assert form.fit.cost <= current.cost * (1 + 1e-9), seed
        values = [form.fit.values[n] for n in form.parameters]
        assert len(values) == len({ds.rod_mode for ds in split.train}) >= 2
        assert len(set(values)) == len(values), values
        assert set(form.per_recording_nrmse) == {ds.name for ds in split.held}
        assert all(math.isfinite(v) and v > 0 for v in form.per_recording_nrmse.values())


def test_a_refit_that_falls_short_of_the_screening_is_repeated_from_its_step():
    """A refit that stops near its warm start (the exhaust muffler of issue 20's seed-2
    rig: 1 % lower training RSS where the screening predicted 65 %) runs again from the
    screening's step, and the lower cost wins; a refit that delivers, or a prediction
    below screening.min_predicted_improvement, is not repeated."""
    from pneumatic_env.identification.scoring import refit_with_restart

    cfg = load_config()
    shortfall = cfg.number("screening", "restart_shortfall")
    worth = cfg.number("screening", "min_predicted_improvement")
    starts = []

    def run(costs):
        def fit(start):
            starts.append(dict(start))
            cost = costs[len(starts) - 1]
            return SimpleNamespace(cost=cost, rss=2 * cost)

        return fit

    base, step = {"dead_volume_cap_m3": 1e-6}, {"exhaust_vent_area_m2": 1.5e-6, "v": math.nan}
    # 1 % gained of 65 % predicted: refitted from the step, which is better
    fit, again = refit_with_restart(run([0.99, 0.3]), base, step, 0.65, 2.0, cfg)
    assert again and fit.cost == 0.3
    assert starts == [base, {**base, "exhaust_vent_area_m2": 1.5e-6}]
    # the second start can be worse: the first fit stays
    starts.clear()
    fit, again = refit_with_restart(run([0.99, 1.2]), base, step, 0.65, 2.0, cfg)
    assert again and fit.cost == 0.99
    # delivered (more than the shortfall share of the prediction): one fit
    starts.clear()
    gained = 0.65 * shortfall * 1.1
    fit, again = refit_with_restart(run([1.0 - gained]), base, step, 0.65, 2.0, cfg)
    assert not again and len(starts) == 1

    # a step the kernel rejects: the first fit stays
    def rejects(start):
        if "exhaust_vent_area_m2" in start:
            raise ValueError("exhaust_vent_area_m2 = 1.5e-06 is not allowed")
        return SimpleNamespace(cost=0.99, rss=1.98)

    fit, again = refit_with_restart(rejects, base, step, 0.65, 2.0, cfg)
    assert again and fit.cost == 0.99
    # a prediction not worth a restart, or no step: one fit
    for predicted, stp in ((0.5 * worth, step), (0.65, {})):
        starts.clear()
        assert not refit_with_restart(run([1.0]), base, stp, predicted, 2.0, cfg)[1]
        assert len(starts) == 1


# --------------------------------------------------------------------------- progress


def test_many_heldout_recordings_judge_by_their_median_improvement():
    """Three or more held-out recordings: the median of their improvements (one badly
    extrapolated recording neither vetoes nor carries an effect); fewer: the pooled one.
    Recordings without a value (NaN) do not count."""
    from pneumatic_env.identification.scoring import heldout_improvement

    cfg = load_config()
    n = int(cfg.diagnosis("median_from_recordings"))
    assert n == 3
    veto = {"clamped": 0.31, "spring": 0.39, "free": -0.46}
    assert heldout_improvement(veto, -0.06, cfg)[0] == pytest.approx(0.31)
    carry = {"clamped": 0.01, "spring": -0.02, "free": 0.9}
    assert heldout_improvement(carry, 0.3, cfg)[0] == pytest.approx(0.01)
    two = {"clamped": 0.31, "free": -0.46, "spring": math.nan}
    rel, how = heldout_improvement(two, -0.06, cfg)
    assert rel == -0.06 and how.startswith("pooled")


def test_an_effect_is_judged_on_the_heldout_recordings_it_acts_on():
    """A friction law is judged where the rod moves, a load cell's compliance where it is
    clamped, a leak everywhere (Holdout.acted_on); the median is then taken over those
    recordings only, so a clamped recording that cannot show a friction law does not
    dilute it (the Stribeck rig of issue 20's evaluation: 0.1 %, 9 % and 70 % on the
    clamped, spring and free recordings)."""
    from pneumatic_env.identification.scoring import heldout_improvement

    cfg = load_config()
    table = candidate_table(cfg)
    channels = ("p1", "p2", "f", "x")
    held = [
        SimpleNamespace(name="clamped", rod_mode="fixed", moving=False, channels=channels),
        SimpleNamespace(name="spring", rod_mode="spring", moving=True, channels=channels),
        SimpleNamespace(name="free", rod_mode="free", moving=True, channels=channels),
    ]
    split = SimpleNamespace(held=held)
    assert Holdout.acted_on(split, table["stribeck"]) == {"spring", "free"}
    assert Holdout.acted_on(split, table["load_cell_compliance"]) == {"clamped"}
    assert Holdout.acted_on(split, table["leakage"]) == {"clamped", "spring", "free"}
    per = {"clamped": 0.001, "spring": 0.09, "free": 0.70}
    rel, how = heldout_improvement(per, 0.49, cfg, {"spring", "free"})
    assert rel == pytest.approx(0.395) and "2 of 3" in how
    assert heldout_improvement(per, 0.49, cfg, {"clamped"})[0] == pytest.approx(0.001)
    # acting on all of them, or on none that was held out: the plain median
    assert heldout_improvement(per, 0.49, cfg, {"clamped", "spring", "free"})[0] == 0.09
    assert heldout_improvement(per, 0.49, cfg, {"elsewhere"})[0] == 0.09


def test_a_clamped_only_effect_keeps_the_moving_recordings_friction():
    """The load cell's compliance sets the piston's sliding friction to 0 on clamped rods
    (pre-sliding); a campaign's spring and free recordings keep the calibrated friction.
    Before the scoped keys the set value was dropped there and the sidecar's nominal
    friction came back (issue 20: the cell's screening predicted the free rod 154 % worse
    and it was never refitted)."""
    from pneumatic_env.identification.datasets import dataset_overrides

    cell = candidate_table(load_config())["load_cell_compliance"]
    scoped = cell.scoped_set()
    assert set(scoped) == {f"{k}@fixed" for k in cell.set}
    model = {"static_friction_n": 4.3, "spring_stiffness_n_per_m": 5e5, **scoped}
    values = {"static_friction_n": 3.5, "fixed_position_m": 0.01, "spring_stiffness_n_per_m": 0}
    rods = {
        mode: SimpleNamespace(rod_mode=mode, values=values) for mode in ("fixed", "spring", "free")
    }
    scopes = cell.scopes()
    clamped = dataset_overrides(rods["fixed"], model, scopes)
    assert clamped["static_friction_n"] == 0.0 and clamped["dynamic_friction_n"] == 0.0
    assert clamped["spring_rest_position_m"] == 0.01  # the recording's clamp position
    assert clamped["spring_stiffness_n_per_m"] == 5e5
    for mode in ("spring", "free"):
        moving = dataset_overrides(rods[mode], model, scopes)
        assert moving["static_friction_n"] == 4.3, mode
        assert "spring_stiffness_n_per_m" not in moving and "piston_mode" not in moving


def test_progress_log_lines_state_the_stage_fraction_and_time_left(caplog):
    bar = progress.Progress(bar=False, interval_s=0.0)
    with caplog.at_level(logging.INFO, logger="pneumatic_env.identification"):
        with progress.tracking(bar):
            progress.stage("base fit", 100.0)
            progress.advance(25.0)
            progress.advance(25.0)
    assert bar.fraction == pytest.approx(0.5)
    lines = [r.getMessage() for r in caplog.records]
    assert lines[0] == "progress: base fit: 0 % done, time left unknown"
    assert lines[-1].startswith("progress: base fit: 50 % done, about ")
    assert lines[-1].endswith(" left")
    progress.advance(10.0)  # no active progress: nothing happens
    assert bar.done == 50.0


def test_data_larger_than_expected_get_a_notice_with_the_time_and_what_is_done():
    from pneumatic_env.identification.diagnose import _size_issue

    cfg = load_config()
    long = [_fake(f"r{k}", "fixed", 10000) for k in range(3)]  # 30 s
    issue = _size_issue(long, cfg, 1e-6, 1.2e8)
    assert (issue.severity, issue.code) == ("warning", "size")
    assert "30.0 s of data, more than the 15 s" in issue.message
    assert "about 2 min" in issue.message and "--quick" in issue.message
    assert _size_issue(long[:1], cfg, 1e-6, 1.2e8) is None


# --------------------------------------------------------------------------- report


@pytest.fixture(scope="module")
def leak_campaign_diagnosis(campaign_dir):
    recs = [read_checked(p) for p in _campaign(campaign_dir, "leakage", 1)]
    return diagnose(
        recs, candidates=["leakage", "rod_seal_leak", "pressure_sensor_offset"], max_effects=2
    )


@pytest.mark.slow
def test_report_states_how_sure_and_the_error_per_recording(leak_campaign_diagnosis, tmp_path):
    diag = leak_campaign_diagnosis
    assert diag.selected == ["leakage"]
    data = write_report(diag, tmp_path / "rep", plots=False)
    (conf,) = data["confidence"]
    assert conf["effect"] == "leakage" and conf["round"] == 1
    assert conf["margin_over_none"] >= 0.10
    assert conf["runner_up"] in ("rod_seal_leak", "pressure_sensor_offset")
    assert conf["margin_over_runner_up"] == pytest.approx(
        conf["heldout_improvement"] - conf["runner_up_improvement"]
    )
    assert conf["holds_on_every_heldout_recording"] is all(
        v > 0 for v in conf["heldout_improvement_per_recording"].values()
    )
    held = set(diag.holdout["held_out"]) | set(diag.holdout["time_split"])
    assert set(conf["heldout_improvement_per_recording"]) == held
    assert set(conf["supported_by"]) <= held
    # a leak acts on every recording, so "where it acts" is every held-out recording
    assert conf["acts_on"] == sorted(held)
    assert conf["holds_where_it_acts"] is conf["holds_on_every_heldout_recording"]
    # which channels it explains: each held-out channel's drop from the base to the leak
    leak = next(c for c in data["candidates"] if c["name"] == "leakage" and c["round"] == 1)
    assert set(conf["explains_channels"]) == set(data["baseline_nrmse"])
    for c, drop in conf["explains_channels"].items():
        assert drop == pytest.approx(1 - leak["heldout_nrmse"][c] / data["baseline_nrmse"][c])
    assert max(conf["explains_channels"][c] for c in ("p1", "p2")) >= 0.10
    for row in data["per_recording"].values():
        assert set(row["before"]) == set(row["after"])
        assert set(row["before"]) in ({"p1", "p2", "f"}, {"p1", "p2", "x"})
        assert math.isfinite(row["before_mean"]) and math.isfinite(row["after_mean"])
    saved = json.loads((tmp_path / "rep" / "diagnosis.json").read_text())
    assert saved["confidence"][0]["effect"] == "leakage"
    md = (tmp_path / "rep" / "report.md").read_text()
    assert "## How sure" in md and "## Held-out error per recording" in md
    assert "explains (held-out channels)" in md
    assert "## Screening, round 1" in md


def test_campaigns_are_named_experiments():
    assert sum(e.duration_s for e in CAMPAIGNS["standard"]) == pytest.approx(13.0)
    assert [e.piston for e in CAMPAIGNS["standard"]].count("fixed") == 3
    with pytest.raises(ValueError, match="campaign = 'huge' is not known; allowed: standard"):
        make_campaign("unused", campaign="huge")


@pytest.mark.slow
def test_identify_quick_names_the_effects_worth_a_full_fit(campaign_dir, tmp_path, capsys):
    from pneumatic_env.cli import main

    paths = _campaign(campaign_dir, "leakage", 1)
    status = main(
        [
            "identify",
            *map(str, paths),
            "--report",
            str(tmp_path / "q"),
            "--quick",
            "--no-plots",
            "--quiet",
            "--candidates",
            ",".join(CANDIDATES),
        ]
    )
    assert status == 0
    out = capsys.readouterr().out
    assert "screening only" in out and "worth a full fit" in out
    worth = out.split("worth a full fit", 1)[1]
    assert worth.index("leakage") < worth.index("%")  # the leak is named first
    data = json.loads((tmp_path / "q" / "diagnosis.json").read_text())
    assert data["quick"] and data["selected"] == [] and data["confidence"] == []


@pytest.mark.slow
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_greedy_rounds_find_both_effects_of_a_two_effect_rig(tmp_path, seed):
    """A rig with a rod-seal leak and a pressure-sensor lag at once (the multi-effect
    rig's plant, studies/rig_multi_effect.py, written apart from the candidates), recorded
    as the small campaign: the greedy rounds select both, and nothing else, among four
    candidates (two decoys of the same kinds: a cross-piston leak, a channel time skew),
    and the stand-in check keeps both."""
    paths = make_campaign(
        tmp_path,
        seed=seed,
        campaign="small",
        effects={"rod_seal_leak": 1.0, "pressure_sensor_lag": 1.0},
        overwrite=True,
    )
    diag = diagnose(
        [read_checked(p) for p in paths],
        candidates=["rod_seal_leak", "pressure_sensor_lag", "leakage", "channel_time_skew"],
        max_effects=3,
    )
    assert sorted(diag.selected) == ["pressure_sensor_lag", "rod_seal_leak"]
    # the stand-in check (identification/stand_ins.py) keeps the first: it still earns its
    # place with the second in the model
    assert [t["dropped"] for t in diag.stand_ins] == [False]
