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
