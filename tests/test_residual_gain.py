"""The residual's gain after training (agents/residual_gain.py, learned.scale_the_residual)."""

import json
import shutil

import numpy as np
import pytest

from conftest import assert_error_names
from pneumatic_env.agents import actor_validation as AV
from pneumatic_env.agents import residual_gain as RG
from pneumatic_env.agents.base import ControllerContext
from pneumatic_env.agents.bench import make_env
from pneumatic_env.agents.config import ConfigError
from pneumatic_env.agents.learned import (
    LearnedActor,
    scale_the_residual,
    shipped_policy_path,
    trained_correction_fraction,
)
from pneumatic_env.agents.ppo_config import load_config
from pneumatic_env.agents.registry import classical_gains, resolve_controller

VARIANT = "Numatics-2m"
CONFIG = "configs/agents/ppo_fast-adaptive-mixture-numatics-2m.yaml"


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_gain_scales_the_correction_and_zero_runs_the_base_alone(tmp_path, seed):
    src = tmp_path / "actor.npz"
    shutil.copyfile(shipped_policy_path("ppo_adaptive", VARIANT), src)
    spec = resolve_controller(
        str(scale_the_residual(src, tmp_path / "full.npz", 1.0, "test")), VARIANT
    )  # the actor as trained (the shipped one may be scaled already)
    env = make_env(VARIANT, 2, 200, **spec.env_options)
    full = spec.build(ControllerContext.from_env(env))
    zero = resolve_controller(
        str(scale_the_residual(src, tmp_path / "zero.npz", 0.0, "test")), VARIANT
    ).build(ControllerContext.from_env(env))
    half = resolve_controller(
        str(scale_the_residual(src, tmp_path / "half.npz", 0.5, "test")), VARIANT
    ).build(ControllerContext.from_env(env))
    base = full.residual.base
    twin = type(base)(base.context, **classical_gains("pid", VARIANT))
    obs, _ = env.reset(seed=seed)
    for c in (full, zero, half, twin):
        c.reset()
    largest = 0.0
    for k in range(60):
        u_full, u_zero, u_half, u_base = (c.act(obs) for c in (full, zero, half, twin))
        largest = max(largest, float(np.abs(u_full - u_base).max()))
        assert np.array_equal(u_zero, u_base)  # gain 0: the base controller bit for bit
        if k == 0:  # the same observation: half the full actor's correction
            np.testing.assert_allclose(u_half - u_base, 0.5 * (u_full - u_base), atol=1e-12)
        obs, *_ = env.step(u_zero[:, None])
    env.close()
    assert largest > 0.01  # the full actor does correct its base (A)


def test_a_scaled_file_is_scaled_from_its_trained_bound(tmp_path):
    src = tmp_path / "actor.npz"
    shutil.copyfile(shipped_policy_path("ppo_adaptive", VARIANT), src)
    trained = LearnedActor(src).meta
    trained_bound = trained_correction_fraction(trained)
    once = scale_the_residual(src, tmp_path / "a.npz", 0.5, "test")
    twice = scale_the_residual(once, tmp_path / "b.npz", 0.5, "test again")
    meta = LearnedActor(twice).meta
    assert meta["residual"]["correction_fraction"] == pytest.approx(0.5 * trained_bound)
    assert meta["residual_gain"] == {
        "gain": 0.5,
        "trained_correction_fraction": trained_bound,
        "source": "test again",
    }
    with pytest.raises(ValueError) as err:
        scale_the_residual(src, tmp_path / "c.npz", -0.1, "test")
    assert_error_names(err, "gain", -0.1, [">= 0"])
    with pytest.raises(ValueError) as err:
        scale_the_residual(shipped_policy_path("ppo_pure", VARIANT), tmp_path / "d.npz", 1, "x")
    assert "pure actor" in str(err.value)


def test_the_lowest_validation_score_is_chosen_from_the_unscaled_actor(tmp_path, monkeypatch):
    """The choice reads the validation scores only: a scripted validation whose error is
    lowest at a bound of 0.6 x the trained one, on both plants; each plant set's seeds and
    options are those documented (draws shifted by DRAW_SEED_STRIDE, the config's
    randomisation)."""
    cfg = load_config(CONFIG)
    run = tmp_path / "run"
    run.mkdir()
    shutil.copyfile(shipped_policy_path("ppo_adaptive", VARIANT), run / "actor_best.npz")
    trained = LearnedActor(run / "actor_best.npz").meta
    bound = trained_correction_fraction(trained)
    calls = []

    def scripted(path, variant, validation, n_steps, env_options=None):
        gain = LearnedActor(path).meta["residual"]["correction_fraction"] / bound
        calls.append((variant, [v["seed"] for v in validation], env_options))
        return {"val_rms_pct": 4.0 + (gain - 0.6) ** 2 + (1.0 if env_options else 0.0)}

    monkeypatch.setattr(AV, "validate_actor", scripted)
    chosen = RG.apply_residual_gain(run, cfg, log=lambda *a: None)
    assert chosen["gain"] == 0.6 and len(chosen["scores"]) == len(cfg.training.residual_gains)
    assert LearnedActor(run / "actor_best.npz").meta["residual_gain"]["gain"] == 0.6
    assert LearnedActor(run / "actor_best_unscaled.npz").meta["residual"] == trained["residual"]
    seeds = [v["seed"] for v in RG.references(cfg)[1]]
    draws = cfg.training.residual_gain_draws
    nominal, drawn = calls[0], calls[1]
    assert nominal == (VARIANT, seeds, None)
    assert drawn[1] == [s + RG.DRAW_SEED_STRIDE * k for k in range(1, draws + 1) for s in seeds]
    assert drawn[2] == {"domain_randomization": cfg.env_kwargs["domain_randomization"]}
    # run again: chosen again from the unscaled actor, not from the scaled one
    RG.apply_residual_gain(run, cfg, log=lambda *a: None)
    assert LearnedActor(run / "actor_best.npz").meta["residual"][
        "correction_fraction"
    ] == pytest.approx(0.6 * bound)


def test_a_config_without_gains_or_draws_to_make_is_refused(tmp_path):
    (tmp_path / "actor_best.npz").write_bytes(b"")
    pure = load_config("configs/agents/ppo_fast-pure-numatics-2m.yaml")
    with pytest.raises(ConfigError) as err:
        RG.apply_residual_gain(tmp_path, pure)
    assert_error_names(err, "training.residual_gains", None, ["residual"])
    tree = load_config(CONFIG).to_tree()
    del tree["env_kwargs"]["domain_randomization"]
    with pytest.raises(ConfigError) as err:
        RG.apply_residual_gain(tmp_path, load_config(tree))
    assert_error_names(err, "training.residual_gain_draws", 4, ["domain_randomization"])


def test_the_command_records_the_choice_in_train_json(tmp_path, monkeypatch):
    run = tmp_path / "run"
    run.mkdir()
    shutil.copyfile(shipped_policy_path("ppo_adaptive", VARIANT), run / "actor_best.npz")
    (run / "train.json").write_text(json.dumps({"config": load_config(CONFIG).to_tree()}))
    monkeypatch.setattr(
        AV, "validate_actor", lambda *a, **k: {"val_rms_pct": 1.0 if a[4:] or k else 2.0}
    )
    assert RG.main([str(run)]) == 0
    summary = json.loads((run / "train.json").read_text())
    assert summary["residual_gain"]["gain"] == load_config(CONFIG).training.residual_gains[0]


def test_the_choice_runs_on_drawn_plants_and_keeps_the_trained_actor(tmp_path):
    """Unscripted: the shipped actor's gains scored by the closed loop (short validation
    episodes) on the nominal plant and on plants drawn from the config's randomisation."""
    cfg = load_config(
        CONFIG,
        {
            "training.validation_steps": 60,
            "training.residual_gains": [1.0, 0.0],
            "training.residual_gain_draws": 1,
        },
    )
    run = tmp_path / "run"
    run.mkdir()
    shutil.copyfile(shipped_policy_path("ppo_adaptive", VARIANT), run / "actor_best.npz")
    chosen = RG.apply_residual_gain(run, cfg, log=lambda *a: None)
    scores = chosen["scores"]
    assert [r["gain"] for r in scores] == [1.0, 0.0]
    assert chosen["gain"] == min(scores, key=lambda r: r["score_rms_pct"])["gain"]
    for r in scores:  # as many drawn episodes as nominal ones, each plant set its own error
        assert np.isfinite(r["nominal_rms_pct"]) and r["mixture_rms_pct"] != r["nominal_rms_pct"]
        assert r["score_rms_pct"] == pytest.approx(
            0.5 * (r["nominal_rms_pct"] + r["mixture_rms_pct"])
        )
    trained = LearnedActor(run / "actor_best_unscaled.npz").meta
    assert (
        trained["residual"]
        == LearnedActor(shipped_policy_path("ppo_adaptive", VARIANT)).meta["residual"]
    )


def test_the_trainer_chooses_its_best_actor_on_drawn_plants_beside_the_nominal_one(tmp_path):
    """training.validation_draws: each validation scores the actor on the nominal plant and
    on drawn plants (the gain step's score); the record keeps both parts and their
    episode-weighted mean, and the best actor is the one with the lowest mean."""
    from conftest import small_run
    from pneumatic_env.agents.ppo_setup import references

    overrides = {
        "training.eval_every_steps": 256,
        "training.validation_draws": 2,
        "training.residual_gains": None,
    }
    config = "configs/agents/ppo_fast-adaptive-tube-air-numatics-2m.yaml"
    summary = small_run(config, tmp_path / "run", 3, seed=2, **overrides)
    n = len(references(load_config(CONFIG))[1])
    curve = summary["curve"]
    assert len(curve) >= 2
    for r in curve:
        assert np.isfinite(r["mixture_rms_pct"]) and r["mixture_rms_pct"] > 0
        mean = (r["nominal_rms_pct"] * n + r["mixture_rms_pct"] * 2 * n) / (3 * n)
        assert r["val_rms_pct"] == pytest.approx(mean, rel=1e-12)
    assert summary["best"] == min(curve, key=lambda r: r["val_rms_pct"])


@pytest.mark.parametrize("draws", [-1, 2])
def test_validation_draws_need_a_randomisation(draws):
    with pytest.raises(ConfigError) as err:
        load_config(
            "configs/agents/ppo_fast-numatics-2m.yaml", {"training.validation_draws": draws}
        )
    assert_error_names(err, "training.validation_draws", draws, ["domain_randomization"])
