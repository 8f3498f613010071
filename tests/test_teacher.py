"""The classical teacher of a pure policy (agents/teacher.py, ppo_fast ``pure.teacher``)."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from conftest import assert_error_names
from pneumatic_env.agents.learned import pure_current
from pneumatic_env.agents.teacher import TeacherConfig, pure_action_for_current

SMALL = {
    "hyperparameters.num_envs": 32,
    "hyperparameters.rollout_steps": 16,
    "hyperparameters.minibatches": 2,
    "training.eval_every_s": 1.0e9,
    "training.validation_steps": 60,
    "training.checkpoint_every": 100,
    "training.episode_steps": 200,
}


@pytest.mark.parametrize("smoothing", [0.0, 0.02])
def test_action_for_current_inverts_the_pure_action_map(smoothing):
    scale, deadband, i_max = 1.3, 0.072, 2.0
    a = np.random.default_rng(0).uniform(-1.0, 1.0, 500)
    u = pure_current(a, scale, deadband, smoothing, i_max)
    back = pure_action_for_current(u, scale, deadband, smoothing)
    assert np.allclose(pure_current(back, scale, deadband, smoothing, i_max), u, atol=2e-3)
    # currents beyond the action range map to its ends
    assert np.array_equal(pure_action_for_current([-5.0, 5.0], scale, deadband, smoothing), [-1, 1])


def test_teacher_weight_falls_linearly_to_zero():
    cfg = {"mode": "pure", "pure": {"teacher": "sliding_mode", "teacher_fraction": 0.4}}
    t = TeacherConfig.from_config(cfg)
    assert t.weight_at(0.0) == 1.0 and t.weight_at(0.2) == pytest.approx(0.5)
    assert t.weight_at(0.4) == 0.0 and t.weight_at(0.9) == 0.0
    assert TeacherConfig.from_config({"mode": "residual", "pure": cfg["pure"]}) is None
    assert TeacherConfig.from_config({"mode": "pure", "pure": {}}) is None


@pytest.mark.parametrize(
    "key, value, rule",
    [
        ("teacher_weight", -1.0, "> 0"),
        ("teacher_unit", 0.0, "> 0"),
        ("teacher_fraction", 1.5, "(0, 1]"),
    ],
)
def test_bad_teacher_settings_are_named(key, value, rule):
    cfg = {"mode": "pure", "pure": {"teacher": "sliding_mode", key: value}}
    with pytest.raises(ValueError) as err:
        TeacherConfig.from_config(cfg)
    assert_error_names(err, f"pure.{key}", value, rule)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_taught_policy_moves_towards_the_teacher(tmp_path, seed):
    """With the imitation term on for the whole (tiny) budget, the policy's mean action
    comes closer to the sliding mode's on the states it visits (progress.csv teacher_gap),
    and the exported actor needs no teacher (pure inputs)."""
    from pneumatic_env.agents.ppo import train

    s = train(
        "ppo_fast-pure-teacher-numatics-0.5m",
        seed=seed,
        out=tmp_path,
        minutes=10.0,  # ends by steps, not by the machine's load
        total_steps=15 * 32 * 16,
        overrides={**SMALL, "pure.teacher_fraction": 1.0},
        log=lambda *a, **k: None,
    )
    assert "base_current" not in s["inputs"]
    gaps = [float(r["teacher_gap"]) for r in csv.DictReader(open(tmp_path / "progress.csv"))]
    assert len(gaps) == 15 and np.all(np.isfinite(gaps))
    assert np.mean(gaps[-3:]) < 0.5 * np.mean(gaps[:2]), gaps


def _teacher_vec(variant, n):
    import gymnasium as gym

    return gym.make_vec(
        f"pneumatic_env/ForceTrack-{variant}-v0", num_envs=n, max_episode_steps=30, preview_steps=20
    )


@pytest.mark.parametrize("seed", [0, 3, 7])
def test_mixture_teacher_teaches_each_tuned_variant_as_it_would_alone(seed):
    """On a generalist's mixture every variant with tuned gains gets its own teacher, whose
    targets equal a teacher of that variant alone bit for bit (through a truncation); the
    rows of a variant without gains (Airpel-3m) have none (NaN, ``taught`` False)."""
    from pneumatic_env.agents.generalist import MixtureVectorEnv
    from pneumatic_env.agents.ppo_setup import row_deadband_a
    from pneumatic_env.agents.teacher import Teacher, has_tuned_gains

    cfg = TeacherConfig.from_config({"mode": "pure", "pure": {"teacher": "sliding_mode"}})
    layout = [("Numatics-0.5m", 3), ("Airpel-3m", 2), ("Airpel-2m", 2)]
    assert [has_tuned_gains("sliding_mode", v) for v, _ in layout] == [True, False, True]
    mix = MixtureVectorEnv([_teacher_vec(v, n) for v, n in layout])
    taught = Teacher(mix, cfg, 1.3, row_deadband_a(mix), 0.02)
    alone_envs = [_teacher_vec(v, n) for v, n in layout]
    alone = {
        k: Teacher(alone_envs[k], cfg, 1.3, row_deadband_a(alone_envs[k]), 0.02) for k in (0, 2)
    }
    assert taught.taught.tolist() == [True] * 3 + [False] * 2 + [True] * 2
    obs, _ = mix.reset(seed=seed)
    parts = [e.reset(seed=seed + int(mix.bounds[k]))[0] for k, e in enumerate(alone_envs)]
    rng = np.random.default_rng(seed)
    for step in range(40):
        target = taught.targets(obs)
        expect = [alone[k].targets(parts[k]) if k in alone else None for k in range(3)]
        assert np.array_equal(target[:3], expect[0]) and np.array_equal(target[5:], expect[2])
        assert np.isnan(target[3:5]).all() and np.isfinite(target[taught.taught]).all(), step
        current = np.clip(pure_current(target[taught.taught], 1.3, 0.072, 0.02, 2.0), -2, 2)
        u = rng.uniform(-0.3, 0.3, 7)
        u[taught.taught] += current  # near the teacher, so its predictor is exercised
        taught.applied(u)
        for k in alone:
            alone[k].applied(u[mix._rows(k)])
        obs, _, _, trunc, _ = mix.step(u[:, None])
        parts = [e.step(u[mix._rows(k), None])[0] for k, e in enumerate(alone_envs)]
        if trunc.any():
            taught.reset(np.flatnonzero(trunc))
            for k in alone:
                alone[k].reset(np.flatnonzero(trunc[mix._rows(k)]))
    assert taught.base_time_s > 0


def test_mixture_without_tuned_variants_is_refused_by_name():
    from pneumatic_env.agents.generalist import MixtureVectorEnv
    from pneumatic_env.agents.teacher import Teacher

    cfg = TeacherConfig.from_config({"mode": "pure", "pure": {"teacher": "sliding_mode"}})
    mix = MixtureVectorEnv([_teacher_vec("Airpel-3m", 2), _teacher_vec("Numatics-1m", 2)])
    with pytest.raises(ValueError) as err:
        Teacher(mix, cfg, 1.3, 0.072, 0.02)
    assert_error_names(err, "pure.teacher", "sliding_mode", "tuned gains")


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_taught_generalist_moves_towards_the_teachers_of_its_tuned_variants(tmp_path, seed):
    """A tiny taught generalist (a tuned and an untuned variant): the gap on the taught rows
    halves over 15 updates, and the actor reads the plant columns, not the teacher."""
    from pneumatic_env.agents.ppo import train

    variants = [f"pneumatic_env/ForceTrack-{v}-v0" for v in ("Numatics-0.5m", "Airpel-3m")]
    s = train(
        "ppo_fast-generalist-teacher",
        seed=seed,
        out=tmp_path,
        minutes=10.0,
        total_steps=15 * 32 * 16,
        overrides={
            **SMALL,
            "variants": variants,
            "training.validation_variants": None,
            "pure.teacher_fraction": 1.0,
        },
        log=lambda *a, **k: None,
    )
    assert s["inputs"][-2:] == ["param:tube_length_m", "param:bore_diameter_m"]
    gaps = [float(r["teacher_gap"]) for r in csv.DictReader(open(tmp_path / "progress.csv"))]
    assert len(gaps) == 15 and np.all(np.isfinite(gaps))
    assert np.mean(gaps[-3:]) < 0.5 * np.mean(gaps[:2]), gaps
