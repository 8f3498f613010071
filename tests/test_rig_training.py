"""From an identification report to a controller (agents/rig.py, agents/rig_training.py):
the fitted rig as an env, the randomisation drawn from the report's intervals, a
self-contained controller file, ``bench --rig``.

The report directory is written by hand (the files ``pneumatic-env identify --report``
writes, with only the keys ``agents.rig`` reads): a Numatics cylinder on a 1.6 m tube (no
registered length) with a fitted leak, a rod-seal leak the report could not rule out and a
valve null leak it could.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import yaml

from pneumatic_env.agents import rig_base
from pneumatic_env.agents.bench import load_suite, read_results, run_suite
from pneumatic_env.agents.learned import FORMAT_SELF_CONTAINED
from pneumatic_env.agents.registry import resolve_controller
from pneumatic_env.agents.rig import load_rig, rig_randomization
from pneumatic_env.agents.suite import default_suite_path
from pneumatic_env.cli import main
from pneumatic_env.params import save_parameters
from pneumatic_env.physics import layout

CYLINDER = "numatics-0750D02-03A"
FITTED = {
    "supply_pressure_pa": 640000.0,
    "discharge_coefficient": 0.23,
    "dead_volume_cap_m3": 1.0e-6,
    "leakage_area_m2": 2.0e-8,
    "static_friction_n": 0.5,
}


def _candidate(name, refitted, improvement, values, kind="plant"):
    return {
        "name": name,
        "kind": kind,
        "refitted": refitted,
        "relative_improvement": improvement if refitted else None,
        "parameters": {k: {"value": v, "neutral": 0.0} for k, v in values.items()}
        if refitted
        else {},
        "screening": {"predicted_heldout_improvement": improvement, "step_values": values},
    }


def write_report(root: Path) -> Path:
    """A minimal report directory: diagnosis.json and fitted_final.yaml."""
    root.mkdir(parents=True, exist_ok=True)
    sidecar = {
        "format": "pneumatic_env-recording",
        "version": 1,
        "cylinder": CYLINDER,
        "tube_length_m": 1.6,
        "supply_pressure_pa": 650000.0,
        "piston": {"mode": "fixed", "position_m": 0.0},
    }
    diagnosis = {
        "recordings": ["e1_steps", "e2_msine"],
        "rigs": {"e1_steps": sidecar, "e2_msine": sidecar},
        "thresholds": {"min_predicted_improvement": 0.03},
        "selected": ["leakage"],
        "final_fit": {
            "parameters": {
                "discharge_coefficient": {"value": 0.23, "kind": "plant", "ci": [0.21, 0.25]},
                # a lower end that is no valid volume: the fitted value takes its place
                "dead_volume_cap_m3": {"value": 1.0e-6, "kind": "plant", "ci": [-1e-6, 3e-6]},
                "leakage_area_m2": {"value": 2.0e-8, "kind": "plant", "ci": [1.8e-8, 2.2e-8]},
                "pressure_offset_p1_pa": {"value": 10.0, "kind": "sensor", "ci": [5.0, 15.0]},
                # not identified (an interval wider than the plausible range): left out
                "static_friction_n": {
                    "value": 0.5,
                    "kind": "plant",
                    "ci": [0.01, 400.0],
                    "identified": False,
                },
            }
        },
        "candidates": [
            _candidate("leakage", True, 0.7, {"leakage_area_m2": 2.0e-8}),
            _candidate("rod_seal_leak", True, 0.2, {"rod_seal_leak_area_m2": 1.5e-8}),
            _candidate("valve_null_leak", False, 0.01, {"valve_null_leak_area_m2": 1e-9}),
            _candidate("heat_transfer", False, 0.05, {"wall_heat_transfer_w_per_k": 0.05}),
            # off at a ratio of 1, not 0 (the catalog's neutral value)
            _candidate("exhaust_discharge", False, 0.04, {"exhaust_discharge_ratio": 0.7}),
        ],
    }
    (root / "diagnosis.json").write_text(json.dumps(diagnosis), encoding="utf-8")
    save_parameters(root / "fitted_final.yaml", FITTED, notes="test report")
    return root


def test_the_fitted_rig_is_the_nearest_variant_at_the_rigs_own_tube_length(tmp_path):
    rig = load_rig(write_report(tmp_path / "report"))
    assert rig.env_id == "pneumatic_env/ForceTrack-Numatics-2m-v0"  # 1.6 m: nearest 2 m
    env = gym.make_vec(rig.env_id, num_envs=1, **rig.env_options)
    base = env.unwrapped.base_params
    assert base["tube_length_m"] == 1.6
    for name, value in FITTED.items():  # the fitted supply wins over the sidecar's
        assert base[name] == value
    env.close()
    assert rig.nominal_parameters()["supply_pressure_pa"] == 650000.0
    assert rig.nominal_parameters()["leakage_area_m2"] == 0.0


def test_randomization_is_drawn_from_the_reports_intervals(tmp_path):
    report = write_report(tmp_path / "report")
    dr = rig_randomization(report)
    assert dr == {
        "discharge_coefficient": (0.21, 0.25),
        "dead_volume_cap_m3": (1.0e-6, 3e-6),
        "leakage_area_m2": (1.8e-8, 2.2e-8),
        # not ruled out: from none to the refitted strength, or to the screening's step
        "rod_seal_leak_area_m2": (0.0, 1.5e-8),
        "wall_heat_transfer_w_per_k": (0.0, 0.05),
        "exhaust_discharge_ratio": (0.7, 1.0),
    }  # no sensor parameter, no unidentified one; the valve null leak's 1 % is below 3 %
    rig = load_rig(report)
    env = gym.make_vec(
        rig.env_id, num_envs=64, **rig.env_options, domain_randomization=dr
    ).unwrapped
    env.reset(seed=3)
    drawn = env.core.sim.params
    for name, (lo, hi) in dr.items():
        row = drawn[layout.PARAMETER_INDEX[name]]
        assert np.all((row >= lo) & (row <= hi)), name
        assert row.max() - row.min() > 0.5 * (hi - lo), name  # spread over the interval
    env.close()


def test_a_report_without_the_rig_is_refused_by_name(tmp_path):
    report = write_report(tmp_path / "report")
    data = json.loads((report / "diagnosis.json").read_text())
    del data["rigs"]
    (report / "diagnosis.json").write_text(json.dumps(data))
    with pytest.raises(ValueError, match="no 'rigs'"):
        load_rig(report)


def _tiny_tuning() -> dict:
    from pneumatic_env.agents.config import load_agent_config

    tuning = load_agent_config("tuning", raw=("references",))
    grid = {k: v[:2] for k, v in tuning["pid"]["grid"].items() if k == "kp_a_per_n"}
    grid.update({k: v[:1] for k, v in tuning["pid"]["grid"].items() if k != "kp_a_per_n"})
    smc = {k: v[:1] for k, v in tuning["sliding_mode"]["grid"].items()}
    smc["reaching_gain_per_s"] = tuning["sliding_mode"]["grid"]["reaching_gain_per_s"][:2]
    return {
        **tuning,
        "duration_s": 0.2,
        "references": tuning["references"][:2],
        "pid": {**tuning["pid"], "grid": grid},
        "sliding_mode": {**tuning["sliding_mode"], "grid": smc},
    }


TINY_TRAINING = {
    "hyperparameters.num_envs": 32,
    "hyperparameters.rollout_steps": 8,
    "training.validation_steps": 50,
}


def test_train_rig_writes_a_controller_that_runs_by_file_name_alone(tmp_path):
    from pneumatic_env.agents.rig_base import BASE_CANDIDATES
    from pneumatic_env.agents.rig_training import train_for_rig

    report = write_report(tmp_path / "report")
    rig = load_rig(report)
    suite = load_suite()
    suite = dataclasses.replace(suite, tasks=suite.tasks[:2])
    tuning = _tiny_tuning()  # the trained file (tests/test_rig_shipped.py: a shipped one)
    tuning["rig_base"] = {**tuning["rig_base"], "shipped_candidates": []}
    res = train_for_rig(
        report,
        tmp_path / "out",
        minutes=None,
        steps=1,
        overrides=TINY_TRAINING,
        tuning=tuning,
        suite=suite,
    )
    summary = (tmp_path / "out" / "summary.md").read_text()
    for name in ("controller.npz", "pid (nominal)", "pid (retuned", *BASE_CANDIDATES):
        assert name in summary
    retuned = json.loads((tmp_path / "out" / "rig_training.json").read_text())["retuned_gains"]
    assert set(retuned) == {n for n in BASE_CANDIDATES if "retuned" in n}
    # elsewhere, with the report and the trainer's output gone
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    path = shutil.copy(res["controller"], elsewhere / "mine.npz")
    shutil.rmtree(report)
    shutil.rmtree(tmp_path / "out")
    meta = json.loads(str(np.load(path)["meta"]))
    assert meta["format"] == FORMAT_SELF_CONTAINED
    # auto: the base with the lowest error on the fitted rig, its model inside the file
    # (the six candidates, each at its best reference smoothing: its own row if none beats it)
    rms = {f["controller"]: f["rms_error_pct"] for f in res["figures"]}
    rows = res["base"]["rms_error_pct"]
    assert len(rows) == len(BASE_CANDIDATES) and set(rows) <= set(rms)
    assert {n.split(", reference smoothed")[0] for n in rows} == set(BASE_CANDIDATES)
    best = min(rows, key=lambda n: rms[n])
    assert res["base"]["controller"] == best
    kind, model = BASE_CANDIDATES[res["base"]["candidate"]]
    assert meta["base_controller"]["kind"] == res["base"]["kind"] == kind
    smoothing = meta["base_controller"]["gains"].get("reference_smoothing_steps", 0)
    assert smoothing == res["base"]["smoothing_steps"]
    on_nominal = meta["residual"]["base_model_params"]
    assert (on_nominal is None) == (model == "fitted")
    assert meta["model"]["base_params"]["tube_length_m"] == 1.6
    # on the fitted rig it gives the summary's figure exactly, from the file alone
    rows, _ = run_suite(str(path), [rig.variant], suite, env_options=rig.env_options)
    rms = np.mean([r["rms_error_pct"] for r in rows])
    assert rms == res["figures"][0]["rms_error_pct"]
    # by name on a registered variant, through the Controller interface
    spec = resolve_controller(str(path), "Numatics-0.5m")
    env = gym.make_vec("pneumatic_env/ForceTrack-Numatics-0.5m-v0", num_envs=2, **spec.env_options)
    from pneumatic_env.agents.base import ControllerContext

    ctrl = spec.build(ControllerContext.from_env(env))
    assert ctrl.context.base_params["tube_length_m"] == 1.6  # its model, not the env's
    obs, _ = env.reset(seed=0)
    ctrl.reset()
    for _ in range(5):
        u = ctrl.act(obs)
        assert u.shape == (2,) and np.all(np.isfinite(u))
        obs, *_ = env.step(u[:, None])
    env.close()


def test_an_unknown_format_version_is_refused_by_name(tmp_path):
    src = Path(__file__).resolve().parents[1] / "agents" / "policies"
    shipped = sorted(src.glob("ppo_residual-numatics-2m.npz"))[0]
    with np.load(shipped) as data:
        arrays = {k: data[k] for k in data.files}
    meta = json.loads(str(arrays.pop("meta")))
    meta["format"] = "pneumatic_env-learned-v9"
    path = tmp_path / "future.npz"
    np.savez(path, meta=np.array(json.dumps(meta)), **arrays)
    with pytest.raises(ValueError, match="pneumatic_env-learned-v9"):
        resolve_controller(str(path), "Numatics-2m")


def test_bench_rig_runs_the_suite_on_the_fitted_rig(tmp_path, capsys):
    report = write_report(tmp_path / "report")
    out = tmp_path / "bench"
    suite_file = tmp_path / "suite.yaml"
    tree = yaml.safe_load(default_suite_path().read_text())
    keep = ("step_up", "sine_10hz", "chirp")  # the metrics' and plots' tasks
    tasks = [t for t in tree["tasks"] if t["name"] in keep]
    suite_file.write_text(yaml.safe_dump({**tree, "tasks": tasks}))
    args = ["bench", "--rig", str(report), "--controller", "pid", "--suite", str(suite_file)]
    assert main([*args, "--out", str(out)]) == 0
    written = read_results(out)
    assert {r["variant"] for r in written} == {"Numatics-2m"}
    one = load_suite(suite_file)
    rig = load_rig(report)
    fitted, _ = run_suite("pid", [rig.variant], one, env_options=rig.env_options)
    nominal, _ = run_suite("pid", [rig.variant], one)
    assert written[0]["rms_error_pct"] == pytest.approx(fitted[0]["rms_error_pct"], rel=1e-6)
    assert fitted[0]["rms_error_pct"] != nominal[0]["rms_error_pct"]  # another plant


def _train_with_figures(monkeypatch, figures: dict, report, out, chatter=None, air=None) -> dict:
    """``train_for_rig`` on a tiny budget with the suite's figures faked
    (``_fake_suite_summary``)."""
    from pneumatic_env.agents import rig_training

    fake = _fake_suite_summary(figures, chatter, air)
    monkeypatch.setattr(rig_training, "suite_summary", fake)
    monkeypatch.setattr(rig_base, "suite_summary", fake)
    return rig_training.train_for_rig(
        report,
        out,
        minutes=None,
        steps=1,
        overrides=TINY_TRAINING,
        tuning=_tiny_tuning(),
        log=lambda *a, **k: None,
    )


def assert_same_currents(ctrl, twin, env, seed: int, steps: int) -> None:
    """Step ``env`` with ``ctrl``'s current from reset(``seed``); ``twin`` gives the same
    current bit for bit at every step."""
    obs, _ = env.reset(seed=seed)
    ctrl.reset()
    twin.reset()
    for _ in range(steps):
        u = ctrl.act(obs)
        assert np.array_equal(u, twin.act(obs))
        obs, *_ = env.step(u[:, None])


def _two_envs_of_the_2m_variant():
    """Two envs of the variant the report's rig maps to, as a controller file runs there."""
    return gym.make_vec(
        "pneumatic_env/ForceTrack-Numatics-2m-v0",
        num_envs=2,
        preview_steps=20,
        normalize_observation=False,
    )


PID_RETUNED, SMC_FITTED = "pid (retuned on the fitted rig)", "sliding_mode (fitted model)"
SMC_NOMINAL = "sliding_mode (nominal model)"
SMC_NOMINAL_RETUNED = "sliding_mode (nominal model, retuned on the fitted rig)"


def _fake_suite_summary(figures: dict, chatter: dict | None = None, air: dict | None = None):
    """``suite_summary`` with the controllers named in ``figures`` at their mean RMS error
    (%), any other at 9 %; those named in ``chatter`` (``air``) at that chatter (A) (air,
    mg), any other at 0."""

    def summary(rig, controllers, suite=None):
        names = [getattr(c, "name", str(c)) for c in controllers]
        return [
            {
                "controller": n,
                "rms_error_pct": figures.get(n, 9.0),
                "chatter_rms_a": (chatter or {}).get(n, 0.0),
                "air_mg": (air or {}).get(n, 0.0),
            }
            for n in names
        ]

    return summary


@pytest.mark.parametrize("winner", [PID_RETUNED, SMC_NOMINAL, SMC_NOMINAL_RETUNED])
def test_train_rig_sits_on_the_winning_base_with_exactly_its_gains_and_model(
    tmp_path, monkeypatch, winner
):
    from pneumatic_env.agents import rig_training
    from pneumatic_env.agents.registry import classical_gains
    from pneumatic_env.agents.residual import BASE_CLASSES

    custom = {
        PID_RETUNED: {"kp_a_per_n": 0.0123, "ki_a_per_n_s": 0.3},
        SMC_NOMINAL_RETUNED: {"reaching_gain_per_s": 300.0, "lambda_integral_per_s": 100.0},
    }
    retuned = {
        name: {**classical_gains(rig_base.BASE_CANDIDATES[name][0], "Numatics-2m"), **g}
        for name in rig_base.RETUNED
        for g in [custom.get(name, {"reaching_gain_per_s": 60.0})]
    }
    monkeypatch.setattr(rig_training, "retuned_gains", lambda rig, tuning=None: retuned)
    figures = {PID_RETUNED: 4.0, SMC_FITTED: 5.0, winner: 3.0}
    report, out = write_report(tmp_path / "report"), tmp_path / "out"
    res = _train_with_figures(monkeypatch, figures, report, out)
    kind, model = rig_base.BASE_CANDIDATES[winner]
    gains = retuned[winner] if winner in retuned else classical_gains(kind, "Numatics-2m")
    nominal = load_rig(report).nominal_parameters()
    assert res["base"]["controller"] == winner and res["base"]["kind"] == kind
    assert f"The residual's base: {winner} (auto:" in (out / "summary.md").read_text()
    record = json.loads((out / "rig_training.json").read_text())["base"]
    assert record["kind"] == kind and record["model"] == model and record["gains"] == gains
    assert record["rms_error_pct"] == {n: figures.get(n, 9.0) for n in rig_base.BASE_CANDIDATES}
    meta = json.loads(str(np.load(res["controller"])["meta"]))
    assert meta["base_controller"] == {"kind": kind, "gains": gains}
    assert meta["residual"]["base_model_params"] == (nominal if model == "nominal" else None)
    # by file name: the self-contained file and the trainer's own (v1, residual.gains)
    env = _two_envs_of_the_2m_variant()
    from pneumatic_env.agents.base import ControllerContext

    obs, _ = env.reset(seed=1)
    for path in (res["controller"], out / "training" / "actor.npz"):
        spec = resolve_controller(str(path), "Numatics-2m")
        ctrl = spec.build(ControllerContext.from_env(env))
        base = ctrl.residual.base
        assert type(base) is BASE_CLASSES[kind]
        if model == "nominal":  # the base on the nominal model, the actor on the fitted one
            assert base.context.base_params == nominal != ctrl.context.base_params
        twin = BASE_CLASSES[kind](base.context, **gains)  # the same gains and model anew
        ctrl.reset()
        twin.reset()
        ctrl.act(obs)
        assert np.array_equal(ctrl.residual.u_base, twin.act(obs))
    env.close()


def test_the_sliding_mode_is_retuned_on_the_fitted_rig_with_the_candidates_model(tmp_path):
    """``retuned_gains``: each retuned candidate's gains are the tuning grid's best on the
    fitted rig with the controller on the candidate's own model (the nominal model's grid
    scores differ from those on the env's own, fitted, model), with exact sensors: a
    report's sensor noise reaches the fitted rig's suites, not the gain search."""
    from pneumatic_env.agents.tune_pid import grid_search

    report = write_report(tmp_path / "report")
    data = json.loads((report / "diagnosis.json").read_text())
    data["sensor_noise"] = {"p1": 1000.0, "p2": 1000.0, "f": 0.2}
    (report / "diagnosis.json").write_text(json.dumps(data))
    rig = load_rig(report)
    assert rig.env_options["sensor_noise"] == data["sensor_noise"]
    exact = rig.noiseless_env_options
    assert exact == {k: v for k, v in rig.env_options.items() if k != "sensor_noise"}
    tuning = _tiny_tuning()
    retuned = rig_base.retuned_gains(rig, tuning)
    runs = {
        model: grid_search("sliding_mode", rig.variant, tuning, exact, base_params=p)
        for model, p in [("nominal", rig.nominal_parameters()), ("fitted", None)]
    }
    assert not np.allclose(runs["nominal"]["score"], runs["fitted"]["score"])
    noisy = grid_search("sliding_mode", rig.variant, tuning, rig.env_options)
    assert not np.allclose(noisy["score"], runs["fitted"]["score"])  # the noise matters
    grid = tuning["sliding_mode"]["grid"]
    for model, res in runs.items():
        name = f"sliding_mode ({model} model, retuned on the fitted rig)"
        best = dict(zip(res["names"], res["combos"][int(np.argmin(res["score"]))]))
        assert {k: retuned[name][k] for k in best} == best
        assert set(retuned[name]) == set(grid) | set(tuning["sliding_mode"]["fixed"])


def test_a_base_with_its_reference_smoothed_wins_and_travels_in_the_file(tmp_path, monkeypatch):
    from pneumatic_env.agents.base import ControllerContext
    from pneumatic_env.agents.registry import classical_gains

    # the search names its runs "CANDIDATE|W": the nominal sliding mode best at W = 2
    figures = {SMC_NOMINAL: 4.0, f"{SMC_NOMINAL}|2": 3.0, f"{SMC_NOMINAL}|3": 3.5}
    figures |= {f"{PID_RETUNED}|1": 3.2, PID_RETUNED: 3.6}
    report, out = write_report(tmp_path / "report"), tmp_path / "out"
    res = _train_with_figures(monkeypatch, figures, report, out)
    winner = rig_base.smoothed_name(SMC_NOMINAL, 2)
    assert res["base"]["controller"] == winner and res["base"]["smoothing_steps"] == 2
    record = json.loads((out / "rig_training.json").read_text())
    tried = record["reference_smoothing"][SMC_NOMINAL]
    assert {w: f["rms_error_pct"] for w, f in tried.items()} == {
        "0": 4.0,
        "1": 9.0,
        "2": 3.0,
        "3": 3.5,
        "4": 9.0,
    }
    assert {f["air_mg"] for f in tried.values()} == {0.0}  # the fake suite's air
    # the PID's own best smoothing is a row too; a candidate none beats gets none
    assert record["base"]["rms_error_pct"][rig_base.smoothed_name(PID_RETUNED, 1)] == 3.2
    assert not any(SMC_FITTED + "," in name for name in record["base"]["rms_error_pct"])
    gains = {**classical_gains("sliding_mode", "Numatics-2m"), "reference_smoothing_steps": 2}
    meta = json.loads(str(np.load(res["controller"])["meta"]))
    assert meta["base_controller"] == {"kind": "sliding_mode", "gains": gains}
    env = _two_envs_of_the_2m_variant()
    ctrl = resolve_controller(res["controller"], "Numatics-2m").build(
        ControllerContext.from_env(env)
    )
    assert ctrl.residual.base.smoothing_steps == 2
    env.close()


def test_train_rig_sits_on_the_sliding_mode_when_it_wins_or_when_told(tmp_path, monkeypatch):
    from pneumatic_env.agents import rig_training

    rms = {PID_RETUNED: 4.0, SMC_FITTED: 3.0, "pid (nominal)": 3.5}
    figures = _fake_suite_summary(rms)(None, rig_base.BASE_CANDIDATES)
    assert rig_base.choose_base(figures)["controller"] == SMC_FITTED
    told = rig_base.choose_base(figures, "pid")  # the better PID: the nominal one here
    assert told["controller"] == "pid (nominal)" and told["model"] == "nominal"
    assert told["kind"] == "pid" and told["reason"].startswith("given")
    tie = _fake_suite_summary(dict.fromkeys(rig_base.BASE_CANDIDATES, 2.0))
    first = rig_base.choose_base(tie(None, rig_base.BASE_CANDIDATES))
    assert first["controller"] == SMC_FITTED  # a tie: the trainer configs' own base
    with pytest.raises(ValueError, match="base = 'lqr' is not allowed"):
        rig_base.choose_base(figures, "lqr")
    with pytest.raises(ValueError, match="base = 'lqr' is not allowed"):  # before any work
        rig_training.train_for_rig(write_report(tmp_path / "r"), tmp_path / "o", base="lqr")


def test_the_cli_base_choices_are_the_trainers():
    import argparse

    from pneumatic_env.agents.rig_base import BASE_CHOICES
    from pneumatic_env.agents.train import add_arguments

    parser = argparse.ArgumentParser()
    add_arguments(parser)
    (action,) = [a for a in parser._actions if a.dest == "base"]
    assert tuple(action.choices) == BASE_CHOICES


@pytest.mark.parametrize(
    ("gains", "message"),
    [
        ([0.01], r"gains = \[0.01\] is not allowed: a mapping of the pid gains"),
        ({"kp": 0.01}, r"unknown \['kp'\], missing \['kp_a_per_n'"),
        ("nan", r"gains.kp_a_per_n = nan is not allowed: a finite number"),
        ("text", r"gains.kp_a_per_n = 'fast' is not allowed"),
    ],
)
def test_bad_residual_gains_are_refused_naming_the_field(gains, message):
    from pneumatic_env.agents.registry import classical_gains
    from pneumatic_env.agents.residual import ResidualConfig

    good = classical_gains("pid", "Numatics-2m")
    if gains == "nan":
        gains = {**good, "kp_a_per_n": float("nan")}
    elif gains == "text":
        gains = {**good, "kp_a_per_n": "fast"}
    ResidualConfig(base="pid", gains=good).validate()  # the same gains, well formed
    with pytest.raises(ValueError, match=message):
        ResidualConfig(base="pid", gains=gains).validate()
    # sliding-mode gains on a PID base: refused the same way
    with pytest.raises(ValueError, match="the pid gains are"):
        ResidualConfig(base="pid", gains=classical_gains("sliding_mode", "Numatics-2m")).validate()


@pytest.mark.parametrize(
    ("params", "message"),
    [
        ([1.0], r"base_model_params = \[1.0\] is not allowed: a mapping of model parameter"),
        ({"supply_pressure_pa": float("nan")}, r"base_model_params.supply_pressure_pa = nan is"),
        ({"supply_pressure_pa": True}, r"base_model_params.supply_pressure_pa = True is"),
    ],
)
def test_a_bad_base_model_is_refused_naming_the_field(params, message):
    from pneumatic_env.agents.residual import ResidualConfig

    ResidualConfig(base_model_params={"supply_pressure_pa": 6e5}).validate()
    with pytest.raises(ValueError, match=message):
        ResidualConfig(base_model_params=params).validate()


def test_a_residual_that_loses_to_its_base_on_the_fitted_rig_is_zeroed(tmp_path, monkeypatch):
    from pneumatic_env.agents.base import ControllerContext
    from pneumatic_env.agents.learned import LearnedActor
    from pneumatic_env.agents.registry import classical_gains
    from pneumatic_env.agents.residual import BASE_CLASSES

    # the trained controller at 9 % (the fake's default), its base (the winner) at 3 %
    out = tmp_path / "out"
    figures = {PID_RETUNED: 4.0, SMC_FITTED: 5.0, SMC_NOMINAL: 3.0}
    res = _train_with_figures(monkeypatch, figures, write_report(tmp_path / "report"), out)
    zeroed = res["base"]["residual_zeroed"]
    assert zeroed["trained"]["rms_error_pct"] == 9.0 and "did not cut its base" in zeroed["reason"]
    assert "The residual was zeroed" in (out / "summary.md").read_text()
    actor = LearnedActor(res["controller"])
    assert actor.meta["residual_zeroed"] == zeroed["reason"]
    x = np.random.default_rng(0).normal(size=(5, actor.obs_dim)) * 3.0
    assert np.array_equal(actor.action(x), np.zeros(5))
    # by file name: the current is its base's, bit for bit
    env = _two_envs_of_the_2m_variant()
    spec = resolve_controller(res["controller"], "Numatics-2m")
    ctrl = spec.build(ControllerContext.from_env(env))
    gains = classical_gains("sliding_mode", "Numatics-2m")
    twin = BASE_CLASSES["sliding_mode"](ctrl.residual.base.context, **gains)
    assert_same_currents(ctrl, twin, env, seed=2, steps=20)
    env.close()


def test_a_base_candidate_that_chatters_over_the_limit_is_not_chosen():
    """``rig_base.max_chatter_ratio`` (1.5) x the sliding mode's chatter at nominal tuning:
    a candidate over it is passed over for the next best; if every candidate of the kind
    asked for is over it, the best of them is chosen and the reason says so."""
    from pneumatic_env.agents.config import load_agent_config

    tuning = load_agent_config("tuning", raw=("references",))
    ratio = tuning["rig_base"]["max_chatter_ratio"]
    assert ratio == 1.5  # the limit
    rms = {PID_RETUNED: 3.0, SMC_FITTED: 4.0, SMC_NOMINAL: 5.0, "pid (nominal)": 3.5}
    loud = {SMC_NOMINAL: 0.010, PID_RETUNED: 0.016, "pid (nominal)": 0.016, SMC_FITTED: 0.015}
    figures = _fake_suite_summary(rms, loud)(None, rig_base.BASE_CANDIDATES)
    assert rig_base.chatter_limit(figures, ratio) == pytest.approx(0.015)
    assert rig_base.choose_base(figures)["controller"] == PID_RETUNED  # no limit given
    chosen = rig_base.choose_base(figures, "auto", None, ratio)
    assert chosen["controller"] == SMC_FITTED  # at the limit is within it
    assert "so not chosen: " + PID_RETUNED in chosen["reason"]
    pid = rig_base.choose_base(figures, "pid", None, ratio)
    assert pid["controller"] == PID_RETUNED and "so allowed" in pid["reason"]


def test_a_residual_that_chatters_over_the_limit_is_zeroed(tmp_path, monkeypatch):
    """A trained controller better than its base in RMS error but with chatter over 1.5 x
    the sliding mode's (and over its base's) on the fitted rig runs its base."""
    out = tmp_path / "out"
    trained = str(out / "controller.npz")
    figures = {PID_RETUNED: 4.0, SMC_FITTED: 5.0, SMC_NOMINAL: 3.0, trained: 2.0}
    quiet = _train_with_figures(
        monkeypatch, figures, write_report(tmp_path / "report"), out, {SMC_NOMINAL: 0.01}
    )
    assert quiet["base"]["residual_zeroed"] is None  # the trained actor is kept
    loud = {SMC_NOMINAL: 0.01, trained: 0.0151}
    res = _train_with_figures(monkeypatch, figures, tmp_path / "report", out, loud)
    zeroed = res["base"]["residual_zeroed"]
    assert zeroed["trained"]["chatter_rms_a"] == 0.0151 and "chatter" in zeroed["reason"]
