"""Identification: calibration, diagnosis, report, bad-data checks (pneumatic_env.identification).

The recordings come from the virtual rig (synthetic, never measured): short (1 s at 1 kHz;
1.5 s for the sliding rod's Stribeck friction), few candidates per diagnosis.
"""

from __future__ import annotations

import hashlib
import json
import math
import re
from pathlib import Path

import numpy as np
import pytest

from pneumatic_env.identification.calibrate import calibrate, prepare_datasets
from pneumatic_env.identification.candidates import (
    SENSOR_NEUTRAL,
    apply_sensor_model,
    available_candidates,
    candidate_table,
    separating_experiment,
)
from pneumatic_env.identification.checks import BadDataError, check_recordings, read_checked
from pneumatic_env.identification.config import load_config
from pneumatic_env.identification.diagnose import diagnose, phase_masks
from pneumatic_env.identification.report import write_report
from pneumatic_env.params import load_parameters
from pneumatic_env.physics.layout import EFFECT_NEUTRAL_VALUES, PARAMETER_NAMES
from pneumatic_env.recording import RecordingError, read_recording, write_recording
from pneumatic_env.studies.virtual_rig import make_recording

DURATION_S = 1.0
# A few candidates that cover a plant effect and the three sensor-side effects.
CANDIDATES = ["leakage", "pressure_sensor_offset", "pressure_sensor_lag", "channel_time_skew"]
LEAK = "leakage_conductance_kg_per_pa_s"  # the leakage candidate's parameter (a laminar leak)


@pytest.fixture(scope="module")
def rig_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("rig")


def _rig(rig_dir: Path, effect: str, seed: int, duration_s: float = DURATION_S, **kw) -> Path:
    name = "_".join(
        [effect, str(seed), f"{duration_s:g}s"] + [f"{k}{v}" for k, v in sorted(kw.items())]
    )
    csv = rig_dir / f"{name}.csv"
    if not csv.exists():
        make_recording(rig_dir, name=name, effect=effect, seed=seed, duration_s=duration_s, **kw)
    return csv


def _truth(csv: Path) -> dict:
    return json.loads(csv.with_name(csv.stem + ".truth.json").read_text())


@pytest.fixture(scope="module")
def none_diagnosis(rig_dir):
    csv = _rig(rig_dir, "none", 1)
    return csv, diagnose([read_checked(csv)], candidates=CANDIDATES[:3], max_effects=1)


@pytest.fixture(scope="module")
def leak_diagnoses(rig_dir):
    out = {}
    for seed in (1, 2):
        csv = _rig(rig_dir, "leakage", seed)
        out[seed] = diagnose([read_checked(csv)], candidates=CANDIDATES, max_effects=1)
    return out


# --------------------------------------------------------------------------- calibration


def test_calibration_recovers_perturbed_parameters_within_their_confidence_intervals(rig_dir):
    # 1.5 s, as in the evaluation: at 1 s the rod side's dead volume lands 0.1 % outside
    # its very narrow confidence interval (a small bias of the coarser fitting model)
    csv = _rig(rig_dir, "none", 1, duration_s=1.5)
    truth = _truth(csv)["parameters"]
    defaults = load_parameters()
    cal = calibrate([read_checked(csv)])
    res = cal.result
    identified = [n for n in res.values if res.identified[n]]
    # the rig's supply, spool damping and overlap are perturbed from the configs and
    # must be found; the data pin them down
    assert {"supply_pressure_pa", "spool_damping_n_s_per_m", "spool_half_width_m"} <= set(
        identified
    )
    for name in identified:
        lo, hi = res.ci[name]
        assert lo <= truth[name] <= hi, (name, truth[name], (lo, hi))
    # the fit moved away from the warm start toward the truth
    for name in ("spool_damping_n_s_per_m", "discharge_coefficient"):
        assert abs(res.values[name] - truth[name]) < abs(defaults[name] - truth[name])


def test_calibration_flags_parameters_the_data_cannot_identify(rig_dir):
    csv = _rig(rig_dir, "none", 1)
    # with the rod clamped the piston never moves: friction has no effect on the data
    cal = calibrate(
        [read_checked(csv)], fit=["supply_pressure_pa", "dynamic_friction_n"], max_nfev=4
    )
    assert cal.result.identified["supply_pressure_pa"]
    assert not cal.result.identified["dynamic_friction_n"]
    assert any("no sensitivity" in f for f in cal.result.flags["dynamic_friction_n"])


def test_calibration_never_reads_the_sidecar_notes(rig_dir, tmp_path):
    csv = _rig(rig_dir, "none", 1)
    rec = read_checked(csv)
    misleading = dict(rec.rig, notes="leakage 1e-7 m^2 and a 5 ms sensor lag (this is a lie)")
    write_recording(tmp_path / "renamed", rec.t, rec.channels, misleading)
    fits = [
        calibrate(
            [read_checked(p)], fit=["supply_pressure_pa", "discharge_coefficient"], max_nfev=4
        ).result.values
        for p in (csv, tmp_path / "renamed.csv")
    ]
    assert fits[0] == fits[1]


def test_saved_fit_is_accepted_by_load_parameters_and_gym_make(rig_dir, tmp_path):
    import gymnasium as gym

    import pneumatic_env  # noqa: F401  (registers the environments)

    csv = _rig(rig_dir, "none", 1)
    cal = calibrate(
        [read_checked(csv)], fit=["supply_pressure_pa", "discharge_coefficient"], max_nfev=6
    )
    path = tmp_path / "fit.yaml"
    cal.save(path)
    loaded = load_parameters(params=path)
    for name, value in cal.result.plant_values().items():
        assert loaded[name] == pytest.approx(value, rel=1e-12)
    env = gym.make("pneumatic_env/ForceTrack-Numatics-0.5m-v0", params=str(path))
    env.reset(seed=0)
    env.close()


# --------------------------------------------------------------------------- diagnosis


@pytest.mark.parametrize("seed", [1, 2])
def test_leakage_is_diagnosed_and_lowers_the_heldout_error(leak_diagnoses, seed):
    diag = leak_diagnoses[seed]
    assert diag.selected == ["leakage"]
    assert diag.winner == "leakage"
    before = np.mean(list(diag.baseline_nrmse.values()))
    after = np.mean(list(diag.after_nrmse.values()))
    assert after < 0.6 * before
    lo, hi = diag.final.ci[LEAK]
    assert lo > 0.0  # the leak is significantly non-zero


def test_leakage_diagnosis_is_stable_across_noise_seeds(leak_diagnoses, rig_dir):
    # same leak strength, different base perturbation and noise draws: the same effect is
    # selected, and the fitted laminar conductance, relative to the rig's (its laminar leak
    # is matched to an orifice of C_f * A_ref at half the supply span, with its own
    # perturbed C_f and supply), agrees within 25 % between the seeds
    from pneumatic_env.studies.rig_plants import _laminar_conductance

    assert leak_diagnoses[1].selected == leak_diagnoses[2].selected == ["leakage"]
    ratios = []
    for seed in (1, 2):
        fit = leak_diagnoses[seed].final.all_values()
        truth = _truth(_rig(rig_dir, "leakage", seed))
        rig_conductance = _laminar_conductance(truth["parameters"], truth["effect_reference"])
        ratios.append(fit[LEAK] / rig_conductance)
    assert abs(ratios[0] - ratios[1]) < 0.25 * max(ratios)


def test_ablation_refuses_a_candidate_whose_effect_does_not_carry_the_improvement(leak_diagnoses):
    """``diagnose._improvement_is_the_basin`` (the moving-piston acceptance rule) keeps a
    candidate whose effect, switched off at its fitted values, costs the held-out error
    or the training fit (to above the current model's, the held-out error not falling),
    and refuses one whose effect is too weak to matter to either, with a reason naming
    the errors."""
    from dataclasses import replace

    from pneumatic_env.identification.calibrate import run_fit
    from pneumatic_env.identification.diagnose import _improvement_is_the_basin, _mean, _Split
    from pneumatic_env.identification.problem import FitProblem

    cfg = load_config()
    diag = leak_diagnoses[1]
    split = _Split(diag.datasets, "time", cfg)
    score = next(s for s in diag.scores if s.name == "leakage")
    assert score.accepted
    real = replace(score, reasons=list(score.reasons), notes=[])
    assert not _improvement_is_the_basin(real, diag.base, 0.10, split, cfg)
    assert real.accepted and real.reasons == score.reasons and not real.notes

    def simulated(values):  # the model at these values: training cost, held-out errors
        fixed = {**diag.base.fixed, **values}
        train = FitProblem(split.train, [], fixed=fixed, n_samples=split.train_n, config=cfg)
        fit = run_fit(train)
        nrmse, preds = split.heldout_nrmse(fit)
        per = {k: _mean(v) for k, v in split.per_recording(preds).items()}
        return fit.cost, _mean(nrmse), per

    # the same fitted base with a leak far too small to matter (held out or in training)
    values = {**score.fit.values, LEAK: 1e-17}
    cost, mean, per = simulated(values)
    fit = replace(score.fit, values=values, cost=cost)
    weak = replace(score, fit=fit, heldout_mean=mean, per_recording_nrmse=per, reasons=[])
    assert _improvement_is_the_basin(weak, diag.base, 0.10, split, cfg)
    assert not weak.accepted
    assert weak.reasons[0].startswith(
        "with leakage switched off at its fitted values the held-out NRMSE is "
    )
    # the real leak scored as if its held-out errors were those of the leak switched
    # off: the training fit still needs the leak at these base values, so it stays
    _, mean_off, per_off = simulated({**score.fit.values, LEAK: 0.0})
    blind = replace(score, heldout_mean=mean_off, per_recording_nrmse=per_off, notes=[])
    assert not _improvement_is_the_basin(blind, diag.base, 0.10, split, cfg)
    assert blind.accepted and "the base parameters need the effect" in blind.notes[0]
    # ... but not when the effect raises the held-out error (switched off, it falls) ...
    worse = {k: 1.2 * v for k, v in per_off.items()}
    hurts = replace(score, heldout_mean=1.2 * mean_off, per_recording_nrmse=worse, reasons=[])
    assert _improvement_is_the_basin(hurts, diag.base, 0.10, split, cfg)
    assert not hurts.accepted and "the base needs the effect only if" in hurts.reasons[0]
    # ... nor when the refit's base alone, the effect off, fits better than the current
    # model (a current model whose training cost is above the one with the leak off)
    cost_off, _, _ = simulated({**score.fit.values, LEAK: 0.0})
    worse_current = replace(diag.base, cost=1.5 * cost_off)
    basin = replace(score, heldout_mean=mean_off, per_recording_nrmse=per_off, reasons=[])
    assert _improvement_is_the_basin(basin, worse_current, 0.10, split, cfg)
    assert not basin.accepted


def test_sensor_lag_is_diagnosed(rig_dir):
    csv = _rig(rig_dir, "pressure_sensor_lag", 3)
    diag = diagnose(
        [read_checked(csv)],
        candidates=["pressure_sensor_lag", "channel_time_skew", "leakage"],
        max_effects=1,
    )
    assert diag.selected == ["pressure_sensor_lag"]
    tau = diag.final.values["pressure_sensor_time_constant_s"]
    reference = _truth(csv)["effect_reference"]
    # the rig's two cascaded lags of tau/2 have the same mean delay as one lag of tau
    assert 0.7 * reference < tau < 1.3 * reference


@pytest.mark.parametrize("seed", [6, 7])
def test_tube_volume_is_identified_from_two_tube_lengths(rig_dir, seed):
    # The rig's tube air (studies/rig_forms.py) sits behind the tube's laminar resistance,
    # fills and empties adiabatically and relaxes to the wall temperature in 0.08 s; the
    # candidate's is isothermal with no resistance: a dead volume that fills at alpha_out
    # and empties at alpha_in, which the base fit's dead volumes can only partly mimic.
    # Recordings at 0.5 m and 2 m fitted at once (the volume scales with the length)
    # identify it; 70 % of the tube's air (strength 0.7), two noise seeds.
    short_tube = _rig(rig_dir, "tube_volume", seed, tube_length_m=0.5, strength=0.7)
    long_tube = _rig(rig_dir, "tube_volume", seed, tube_length_m=2.0, strength=0.7)
    both = diagnose(
        [read_checked(short_tube), read_checked(long_tube)],
        candidates=["tube_volume", "leakage"],
        max_effects=1,
        holdout="time",
    )
    assert both.selected == ["tube_volume"]
    before, after = (np.mean(list(d.values())) for d in (both.baseline_nrmse, both.after_nrmse))
    assert after < 0.7 * before


# Each effect at its realistic strength (strength 1 of configs/identification.yaml) against
# its closest rival (the runner-up of the evaluation in docs/identification.md): the
# effect must be selected, and the held-out error must drop clearly.
EFFECT_RIVALS = {
    "load_cell_compliance": "pressure_sensor_offset",
    "rod_seal_leak": "exhaust_discharge",
    "supply_droop": "exhaust_discharge",
    "pressure_sensor_offset": "rod_seal_leak",
    "channel_time_skew": "pressure_sensor_lag",
    "heat_transfer": "exhaust_discharge",
    "iso_flow_law": "rod_seal_leak",
    "exhaust_discharge": "valve_null_leak",
    "spool_friction": "coil_lag",
    "coil_lag": "channel_time_skew",
    "tube_waves": "tube_volume",
    "exhaust_muffler": "exhaust_backpressure",
}
# Effects whose test recording is 1.5 s, as in the evaluation (the others: DURATION_S). The
# rig's supply line lags its droop by 20 ms, which a resistance fits less well: at 1 s the
# held-out error fell by 12.5 %, short of the 15 % asked here.
EFFECT_DURATIONS_S = {"supply_droop": 1.5}


@pytest.fixture(scope="module")
def effect_diagnoses(rig_dir):
    """effect -> (recording, diagnosis against the effect and its rival), made on demand."""
    cache = {}

    def get(effect):
        if effect not in cache:
            csv = _rig(rig_dir, effect, 1, EFFECT_DURATIONS_S.get(effect, DURATION_S))
            cache[effect] = (
                csv,
                diagnose(
                    [read_checked(csv)], candidates=[effect, EFFECT_RIVALS[effect]], max_effects=1
                ),
            )
        return cache[effect]

    return get


@pytest.mark.slow
@pytest.mark.parametrize("effect", sorted(EFFECT_RIVALS))
def test_effect_at_realistic_strength_is_diagnosed(effect_diagnoses, effect):
    _, diag = effect_diagnoses(effect)
    assert diag.selected == [effect], [
        (s.name, s.relative_improvement, s.reasons) for s in diag.scores
    ]
    before = np.mean(list(diag.baseline_nrmse.values()))
    after = np.mean(list(diag.after_nrmse.values()))
    assert after < 0.85 * before


@pytest.mark.slow
def test_the_valve_null_leak_and_the_piston_leak_are_named_as_close_rivals(rig_dir):
    """The valve's null leak (the rig's laminar form through the spool clearance) against
    the laminar cross-piston leak, on one 1 s recording of the identification excitation:
    with fits run to convergence both cut the held-out error by about as much (seeds 1-3:
    81 against 82 %, 80 against 85 %, 67 against 70 %; 2026-12-07), so these data cannot
    tell them apart (the test once asked for the null leak on seed 1 alone, and passed
    only where a fit stopping on the 1 % plateau left the piston leak behind). The claim,
    on every seed: a leak of the two is selected and cuts the error by 50 % or more, the
    other is the runner-up, and the report suggests the experiment that separates them
    (``separating_experiments``)."""
    pair = {"valve_null_leak", "leakage"}
    for seed in (1, 2, 3):
        csv = _rig(rig_dir, "valve_null_leak", seed)
        diag = diagnose([read_checked(csv)], candidates=sorted(pair), max_effects=1)
        assert len(diag.selected) == 1 and diag.selected[0] in pair, seed
        assert {diag.winner, diag.runner_up} == pair, seed
        assert diag.suggestion == separating_experiment(*sorted(pair)), seed
        before = np.mean(list(diag.baseline_nrmse.values()))
        after = np.mean(list(diag.after_nrmse.values()))
        assert after < 0.5 * before, seed


@pytest.mark.slow
@pytest.mark.parametrize("effect, law_parameter", [("stribeck", "stribeck_velocity_m_per_s")])
def test_friction_law_is_diagnosed_on_a_moving_rod(rig_dir, effect, law_parameter):
    """A friction law shows only where the rod slides (spring rod, 1.5 s).

    Stribeck: the calibrated static friction of the base model sits in the wrong
    stick-event basin for this recording (5.0 N against the rig's 4.3 N); without the fit's
    static-friction restarts (fit.static_friction_restarts) the candidate stays there and
    is refused. LuGre: the rig's (a bristle damping that falls with speed, at 10 us)
    against the kernel's (a constant damping, once per 25 us fitting substep); its rival,
    the Stribeck curve without pre-sliding, is left to the evaluation (time), where it is
    the runner-up; at 1 s the held-out error fell by 26 % only.
    """
    csv = _rig(rig_dir, effect, 1, duration_s=1.5, piston="spring")
    diag = diagnose([read_checked(csv)], candidates=[effect], max_effects=1)
    assert diag.selected == [effect], [
        (s.name, s.relative_improvement, s.reasons) for s in diag.scores
    ]
    before = np.mean(list(diag.baseline_nrmse.values()))
    after = np.mean(list(diag.after_nrmse.values()))
    assert after < 0.5 * before
    truth = _truth(csv)["parameters"]
    assert 0.5 < diag.final.values[law_parameter] / truth[law_parameter] < 2.0
    assert abs(diag.final.values["static_friction_n"] / truth["static_friction_n"] - 1) < 0.1


@pytest.mark.slow
def test_lugre_is_diagnosed_on_every_seed(rig_dir):
    """LuGre friction on a spring rod (1.5 s), rig seeds 1-3 (issue 20: the former test
    passed by its seed, after/before 0.36, 0.52, 0.87 against 0.5). The claim, fixed before
    this run: on every seed LuGre is selected and the held-out error falls by at least the
    acceptance threshold (10 %, diagnosis.min_relative_improvement, set before any test
    data), and the bristle stiffness is within a factor 3 of the rig's (half a decade of
    its four-decade plausible range; the rig's bristle damping falls with speed, the
    candidate's is constant, so the stiffness absorbs some of that form difference)."""
    min_rel = load_config().diagnosis("min_relative_improvement")
    for seed in (1, 2, 3):
        csv = _rig(rig_dir, "lugre", seed, duration_s=1.5, piston="spring")
        diag = diagnose([read_checked(csv)], candidates=["lugre"], max_effects=1)
        assert diag.selected == ["lugre"], (
            seed,
            [(s.name, s.relative_improvement, s.reasons) for s in diag.scores],
        )
        before = np.mean(list(diag.baseline_nrmse.values()))
        after = np.mean(list(diag.after_nrmse.values()))
        assert after <= (1.0 - min_rel) * before, (seed, after / before)
        truth = _truth(csv)["parameters"]["lugre_stiffness_n_per_m"]
        assert 1 / 3 < diag.final.values["lugre_stiffness_n_per_m"] / truth < 3, seed


def test_muffler_vent_and_volume_are_recovered(effect_diagnoses):
    """The rig's muffler (explicit steps at the plant rate) against the kernel's muffler
    node (backward Euler per substep): the vent area and the volume within 20 %."""
    csv, diag = effect_diagnoses("exhaust_muffler")
    assert diag.selected == ["exhaust_muffler"]
    truth = _truth(csv)["parameters"]
    for name in ("exhaust_vent_area_m2", "exhaust_volume_m3"):
        assert abs(diag.final.values[name] / truth[name] - 1.0) < 0.2, name


def test_load_cell_stiffness_is_recovered_and_the_rest_position_follows_the_clamp(effect_diagnoses):
    csv, diag = effect_diagnoses("load_cell_compliance")
    assert diag.selected == ["load_cell_compliance"]
    truth = _truth(csv)["parameters"]["spring_stiffness_n_per_m"]
    lo, hi = diag.final.ci["spring_stiffness_n_per_m"]
    assert 0.7 * truth < diag.final.values["spring_stiffness_n_per_m"] < 1.3 * truth
    assert (
        lo
        < hi
        < load_config().raw["candidates"]["load_cell_compliance"]["parameters"][
            "spring_stiffness_n_per_m"
        ]["plausible_max"]
    )
    # the rest position is each recording's clamp position, not a number in the config
    ds = diag.datasets[0]
    values = diag.final.dataset_values(ds)
    assert values["piston_mode"] == 2
    assert values["spring_rest_position_m"] == ds.values["fixed_position_m"]


def test_a_transmission_line_excludes_a_tube_storage_volume():
    """Greedy selection never combines an effect that fixes a parameter with one that fits
    it: the transmission line holds the tube's air itself (tube_volume_fraction = 0)."""
    from pneumatic_env.identification.diagnose import _conflicts

    table = candidate_table()
    assert _conflicts(table["tube_waves"], [table["tube_volume"]])
    assert _conflicts(table["tube_volume"], [table["tube_waves"]])
    assert not _conflicts(table["tube_waves"], [table["leakage"], table["coil_lag"]])


def test_scoped_and_per_recording_overrides():
    # a candidate limited to clamped rods (rod_modes) reaches only those recordings, and a
    # text value takes the recording's own parameter
    from pneumatic_env.identification.calibrate import Dataset, dataset_overrides

    def ds(mode, values):
        return Dataset(
            name=mode,
            recording=None,
            values=values,
            channels=(),
            scales={},
            usable={},
            dt_s=1e-3,
            substeps=10,
            initial=None,
            moving=False,
            rod_mode=mode,
        )

    cand = candidate_table()["load_cell_compliance"]
    overrides = {**cand.scoped_set(), "spring_stiffness_n_per_m": 1e6, "supply_pressure_pa": 6e5}
    clamped = dataset_overrides(ds("fixed", {"fixed_position_m": 0.01}), overrides, cand.scopes())
    assert clamped["spring_rest_position_m"] == 0.01 and clamped["piston_mode"] == 2
    spring = dataset_overrides(ds("spring", {"fixed_position_m": 0.0}), overrides, cand.scopes())
    assert spring == {"supply_pressure_pa": 6e5}  # only the unscoped base value


def test_no_extra_effect_gives_none(none_diagnosis):
    _, diag = none_diagnosis
    assert diag.selected == []
    assert diag.winner is None
    # the calibrated base model leaves a residual at the sensor-noise level
    noise = load_config().number("virtual_rig", "noise", "p1")
    assert diag.baseline_nrmse["p1"] < 1.5 * noise / diag.datasets[0].scales["p1"]


def test_effect_outside_the_catalog_gets_no_confident_wrong_answer(rig_dir):
    # a 3 Hz supply-pressure ripple is not a candidate: nothing may be accepted, and the
    # report must say the residual stays systematic
    csv = _rig(rig_dir, "supply_ripple", 4)
    diag = diagnose([read_checked(csv)], candidates=CANDIDATES, max_effects=1)
    assert diag.selected == []
    assert not all(r["whiteness"]["white"] for r in diag.after_residuals.values())


def test_report_files_and_diagnosis_json_keys(none_diagnosis, tmp_path):
    csv, diag = none_diagnosis
    digest = {
        p: hashlib.sha256(p.read_bytes()).hexdigest() for p in (csv, csv.with_suffix(".json"))
    }
    data = write_report(diag, tmp_path / "report")
    on_disk = json.loads((tmp_path / "report" / "diagnosis.json").read_text())
    assert on_disk == data
    for key in ("baseline_nrmse", "candidates", "selected", "after_nrmse"):
        assert key in on_disk
    assert on_disk["selected"] == []
    assert set(on_disk["baseline_nrmse"]) == {"p1", "p2", "f"} == set(on_disk["after_nrmse"])
    scores = [c["score"] for c in on_disk["candidates"] if c["round"] == 1]
    assert scores == sorted(scores, reverse=True)
    for cand in on_disk["candidates"]:
        assert {"name", "parameters", "heldout_nrmse", "score"} <= set(cand)
    for name in (
        "report.md",
        "fitted_base.yaml",
        "fitted_final.yaml",
        f"fit_{csv.stem}.png",
        f"residuals_{csv.stem}.png",
    ):
        assert (tmp_path / "report" / name).is_file()
    load_parameters(params=tmp_path / "report" / "fitted_final.yaml")
    for p, h in digest.items():  # the inputs are untouched
        assert hashlib.sha256(p.read_bytes()).hexdigest() == h


def test_report_refuses_to_overwrite_an_input(none_diagnosis, tmp_path):
    _, diag = none_diagnosis
    rec = diag.datasets[0].recording
    target = tmp_path / "evil"
    target.mkdir()
    copied = target / "diagnosis.json"
    copied.write_text("{}")
    original = rec.path
    try:
        rec.path = target / "diagnosis.csv"  # pretend the input sits where the report goes
        with pytest.raises(ValueError, match="would overwrite an input recording"):
            write_report(diag, target, plots=False)
    finally:
        rec.path = original
    assert copied.read_text() == "{}"


# --------------------------------------------------------------------------- candidates


def test_candidate_table_is_consistent_with_the_kernel_and_its_configs():
    table = candidate_table()
    assert {"leakage", "pressure_sensor_offset", "pressure_sensor_lag", "channel_time_skew"} <= set(
        table
    )
    for cand in table.values():
        for p in cand.parameters:
            assert p.lower <= p.initial <= p.upper
            assert p.plausible_min <= p.plausible_max
            switched_by_another = any(
                q.neutral is not None and not math.isinf(q.neutral)
                for q in cand.parameters
                if q is not p
            )
            if (
                cand.kind == "plant"
                and cand.available
                and (p.neutral is None or math.isinf(p.neutral))
            ):
                if switched_by_another:  # a shape (the coil lag's): the kernel's default
                    default = load_parameters()[p.name]  # is allowed, or is the parameter's
                    assert (
                        p.lower <= default <= p.upper  # own off value (LuGre's damping)
                        or default == EFFECT_NEUTRAL_VALUES.get(p.name)
                    ), (cand.name, p.name)
                    continue
                # off only in a limit (a rigid load cell) or by a switch (the transmission
                # line): the kernel's defaults do not switch on what the candidate `set`s,
                # or the kernel's default is its own off value, outside the fitted range
                # (a vent area of 0: no vent, the limit A -> inf of an open exhaust)
                defaults = load_parameters()
                off_by_default = (
                    defaults[p.name] == EFFECT_NEUTRAL_VALUES.get(p.name)
                    and not p.lower <= defaults[p.name] <= p.upper
                )
                assert off_by_default or any(
                    defaults[k] != v for k, v in cand.set.items() if not isinstance(v, str)
                ), cand.name
            elif cand.kind == "plant" and cand.available:
                # the neutral value is the kernel's default: the effect is off by default
                assert load_parameters()[p.name] == pytest.approx(p.neutral)
            if cand.kind == "sensor":
                assert SENSOR_NEUTRAL[p.name] == p.neutral
    available = {c.name for c in available_candidates()}
    for cand in table.values():
        in_kernel = all(n in PARAMETER_NAMES for n in cand.parameter_names)
        assert (cand.name in available) == (in_kernel or cand.kind == "sensor")


def test_unknown_candidate_name_is_a_clear_error():
    from pneumatic_env.params import ConfigError

    with pytest.raises(ConfigError, match="candidate 'leakagee' is not declared"):
        available_candidates(["leakagee"])


def test_sensor_model_matches_closed_forms():
    dt = 1e-3
    n = 200
    step = np.zeros((n, 1))
    step[50:] = 1.0
    out = apply_sensor_model(
        {"p1": step, "f": step},
        [
            {
                "pressure_sensor_time_constant_s": 0.01,
                "pressure_offset_p1_pa": 5.0,
                "channel_skew_s": 0.003,
            }
        ],
        dt,
    )
    # skew: a 3-sample delay of every output channel
    assert np.array_equal(out["f"][:, 0], np.concatenate([np.zeros(53), np.ones(n - 53)]))
    # lag of a held step: 1 - exp(-k dt / tau) after the (delayed) step; then the offset
    k = np.arange(n - 53)
    expected = 5.0 + np.concatenate([np.zeros(53), 1.0 - np.exp(-(k + 1) * dt / 0.01)])
    assert np.allclose(out["p1"][:, 0], expected, atol=1e-12)
    # neutral values leave the channels untouched
    same = apply_sensor_model({"p2": step}, [{}], dt)
    assert np.array_equal(same["p2"], step)


def test_separating_experiment_lookup_is_symmetric():
    a = separating_experiment("leakage", "pressure_sensor_offset")
    assert a == separating_experiment("pressure_sensor_offset", "leakage")
    assert "rest" in a
    assert separating_experiment("leakage", "no_such_effect") == load_config().default_experiment()


def test_phase_masks_follow_the_valve_dead_band():
    cfg = load_config()
    values = load_parameters()
    dt = 1e-3
    i_c = np.concatenate([np.zeros(100), np.full(100, 0.5), np.zeros(300), np.full(100, -0.5)])
    ph = phase_masks(i_c, dt, values, cfg)
    assert not ph["flow"][:100].any() and ph["rest"][:100].all()
    assert ph["flow"][100:200].all()
    window = int(round(cfg.diagnosis("after_flow_window_s") / dt))
    assert ph["after_flow"][200 : 200 + window].all() and ph["rest"][200 + window + 1 : 500].all()
    assert ph["reversal"][500] and not ph["reversal"][100]


# --------------------------------------------------------------------------- bad data


def _copy_with(src: Path, dst: Path, **changes) -> Path:
    rec = read_checked(src)
    channels = dict(rec.channels)
    for name, fn in changes.items():
        channels[name] = fn(channels[name].copy())
    rig = dict(rec.rig)
    write_recording(dst, rec.t, channels, rig, overwrite=True)
    return dst.with_suffix(".csv")


@pytest.mark.parametrize(
    "change,needle",
    [
        ({"p1": lambda p: p - 101325.0}, "gauge"),
        ({"p2": lambda p: p / 1e5}, "bar"),
    ],
)
def test_wrong_pressure_units_are_refused(rig_dir, tmp_path, change, needle):
    bad = _copy_with(_rig(rig_dir, "none", 1), tmp_path / "bad", **change)
    with pytest.warns(Warning):
        read_recording(bad)  # the reader itself only warns
    with pytest.raises(BadDataError, match=needle) as info:
        prepare_datasets([read_checked(bad)])
    assert all(i.code == "units" for i in info.value.issues)


def test_position_in_millimetres_is_refused(rig_dir, tmp_path):
    src = _rig(rig_dir, "none", 2, piston="spring")
    bad = _copy_with(src, tmp_path / "mm", x=lambda x: 1000.0 * x)
    with pytest.raises(BadDataError, match="millimetres"):
        prepare_datasets([read_checked(bad)])


def test_identify_cli_refuses_bad_units_with_exit_status_2(rig_dir, tmp_path, capsys):
    from pneumatic_env.cli import main

    bad = _copy_with(_rig(rig_dir, "none", 1), tmp_path / "bad", p1=lambda p: p - 101325.0)
    status = main(["identify", str(bad), "--report", str(tmp_path / "rep"), "--quiet"])
    assert status == 2
    err = capsys.readouterr().err
    assert "refusing to fit" in err and "gauge" in err and "p1" in err
    assert not (tmp_path / "rep").exists()


def test_clipped_samples_are_left_out_of_the_fit(rig_dir, tmp_path):
    src = _rig(rig_dir, "none", 1)
    top = 0.9 * float(read_checked(src).channels["p1"].max())  # a sensor saturating at 90 %
    bad = _copy_with(src, tmp_path / "clip", p1=lambda p: np.minimum(p, top))
    datasets, issues = prepare_datasets([read_checked(bad)])
    assert [i.code for i in issues if i.channel == "p1"] == ["clipped"]
    usable = datasets[0].usable["p1"]
    p1 = datasets[0].measured("p1")
    assert not usable[np.flatnonzero(p1 == top)[10]]  # inside a clipped run
    assert usable.sum() < len(p1)
    assert datasets[0].usable["p2"].all()


def test_no_usable_output_is_refused(rig_dir, tmp_path):
    src = read_checked(_rig(rig_dir, "none", 1))
    # rod clamped and only x recorded: x is the clamp position, nothing to fit
    write_recording(
        tmp_path / "onlyx",
        src.t,
        {"i_c": src.i_c, "x": np.zeros_like(src.t)},
        src.rig,
        overwrite=True,
    )
    with pytest.raises(BadDataError, match="no usable output channel"):
        prepare_datasets([read_checked(tmp_path / "onlyx.csv")])


def test_no_excitation_and_too_short_are_refused(rig_dir, tmp_path):
    src = read_checked(_rig(rig_dir, "none", 1))
    write_recording(
        tmp_path / "quiet",
        src.t,
        {"i_c": np.full_like(src.t, 0.01), "p1": src.channels["p1"]},
        src.rig,
    )
    with pytest.raises(BadDataError, match="dead band"):
        prepare_datasets([read_checked(tmp_path / "quiet.csv")])
    write_recording(
        tmp_path / "short",
        src.t[:20],
        {"i_c": src.i_c[:20], "p1": src.channels["p1"][:20]},
        src.rig,
    )
    issues = check_recordings([read_checked(tmp_path / "short.csv")], raise_on_error=False)
    assert "too_short" in {i.code for i in issues}


def test_broken_files_are_rejected_by_the_reader(rig_dir, tmp_path):
    src = _rig(rig_dir, "none", 1)
    lines = src.read_text().splitlines()
    cases = {
        "nan": lines[:5] + [lines[5].rsplit(",", 1)[0] + ",nan"] + lines[6:],
        "gap": lines[:5] + lines[7:],
        "unsorted": lines[:5] + [lines[6], lines[5]] + lines[7:],
    }
    for name, content in cases.items():
        csv = tmp_path / f"{name}.csv"
        csv.write_text("\n".join(content) + "\n")
        csv.with_suffix(".json").write_text(src.with_suffix(".json").read_text())
        with pytest.raises(RecordingError):
            read_checked(csv)


def test_missing_position_with_a_moving_piston_warns_and_skips_friction(rig_dir, tmp_path):
    src = read_checked(_rig(rig_dir, "none", 2, piston="spring"))
    write_recording(
        tmp_path / "nox",
        src.t,
        {"i_c": src.i_c, "p1": src.channels["p1"], "p2": src.channels["p2"]},
        src.rig,
    )
    datasets, issues = prepare_datasets([read_checked(tmp_path / "nox.csv")])
    assert "no_position" in {i.code for i in issues}
    from pneumatic_env.identification.calibrate import base_fit_parameters

    names = {p.name for p in base_fit_parameters(datasets)}
    assert not names & {"static_friction_n", "dynamic_friction_n", "viscous_friction_n_s_per_m"}
    assert math.isfinite(datasets[0].scales["p1"])


def test_bad_static_friction_restarts_are_refused_with_the_field_and_value(tmp_path):
    from pneumatic_env.params import ConfigError

    text = Path(load_config().path).read_text(encoding="utf-8")
    bad = tmp_path / "identification.yaml"
    bad.write_text(
        re.sub(r"(static_friction_restarts:\n    value: )\[[^\]]*\]", r"\g<1>[0.9, -1.0]", text),
        encoding="utf-8",
    )
    with pytest.raises(
        ConfigError,
        match=r"fit\.static_friction_restarts = \[0\.9, -1\.0\] is "
        r"not allowed: must be a list of finite numbers > 0",
    ):
        load_config(bad).positive_numbers("fit", "static_friction_restarts")
