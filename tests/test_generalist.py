"""Pure learned policies: the dead-band step of their action map, and one policy for several
variants (issue 19's generalist): the mixture vector env, its plant columns, training on it,
and the learned controller that rebuilds its observation."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from conftest import SMALL, assert_error_names, suite_rms_pct
from pneumatic_env.agents.base import ControllerContext
from pneumatic_env.agents.generalist import MixtureVectorEnv, param_values
from pneumatic_env.envs.observation import observation_dim

IDS = ["pneumatic_env/ForceTrack-Numatics-0.5m-v0", "pneumatic_env/ForceTrack-Airpel-3m-v0"]
OPTIONS = dict(preview_steps=20, action_history=3, measurement_history=2, tracking_error=True)
TINY = {**SMALL, "variants": IDS, "training.validation_variants": None}


def _vec(env_id, n, episode=40, **kw):
    return gym.make_vec(env_id, num_envs=n, max_episode_steps=episode, **{**OPTIONS, **kw})


@pytest.mark.parametrize("seed", [0, 5, 11])
def test_mixture_rows_are_each_variant_alone_with_its_plant_columns(seed):
    """Every row of the mixture is the same env stepped alone (same seed, same actions),
    followed by its variant's nominal tube length and bore, also in ``final_obs``."""
    mix = MixtureVectorEnv([_vec(IDS[0], 3), _vec(IDS[1], 2)])
    alone = [_vec(IDS[0], 3), _vec(IDS[1], 2)]
    assert mix.columns[-2:] == ["param:tube_length_m", "param:bore_diameter_m"]
    assert mix.single_observation_space.shape == (len(mix.columns),)
    obs, _ = mix.reset(seed=seed)
    parts = [alone[0].reset(seed=seed)[0], alone[1].reset(seed=seed + 3)[0]]
    plant = np.array([[0.5, 0.01905]] * 3 + [[3.0, 0.01593]] * 2, dtype=np.float32)
    rng = np.random.default_rng(seed)
    finals = 0
    for k in range(45):  # through one truncation at step 40
        assert np.array_equal(obs, np.concatenate([np.concatenate(parts), plant], axis=1)), k
        actions = rng.uniform(-1.5, 1.5, size=(5, 1))
        obs, reward, _, trunc, info = mix.step(actions)
        steps = [alone[0].step(actions[:3]), alone[1].step(actions[3:])]
        parts = [s[0] for s in steps]
        assert np.array_equal(reward, np.concatenate([s[1] for s in steps]))
        assert np.array_equal(
            info["tracking_error"], np.concatenate([s[4]["tracking_error"] for s in steps])
        )
        if trunc.any():
            finals += 1
            own = np.concatenate([s[4]["final_obs"] for s in steps])
            for i in np.flatnonzero(trunc):
                assert np.array_equal(info["final_obs"][i], np.concatenate([own[i], plant[i]]))
    assert finals == 1
    assert np.array_equal(mix.reference_scale[[0, 3]], [e.unwrapped.reference_scale for e in alone])


def test_mixture_and_config_errors_name_the_field():
    from pneumatic_env.agents.config import ConfigError
    from pneumatic_env.agents.ppo_setup import load_config, make_training_env

    with pytest.raises(ValueError) as err:
        MixtureVectorEnv([_vec(IDS[0], 2), _vec(IDS[1], 2, action_history=4)])
    assert_error_names(err, "observation shapes", rule="same options")
    with pytest.raises(ValueError) as err:
        param_values({"tube_length_m": 2.0}, ["param:tube_length"])
    assert_error_names(err, "plant column", "param:tube_length", "param:<name>")
    with pytest.raises(ConfigError) as err:
        load_config("ppo_fast-generalist", {"variants": [IDS[0], "pneumatic_env/Nope-v0"]})
    assert_error_names(err, "variants", rule="not a registered env id")
    cfg = load_config("ppo_fast-generalist", {"hyperparameters.num_envs": 30})
    with pytest.raises(ConfigError) as err:
        make_training_env(cfg, IDS[0])
    assert_error_names(err, "num_envs", 30, "multiple")


def test_generalist_trains_and_its_controller_rebuilds_the_training_observation(tmp_path):
    """A tiny generalist run: the actor reads the plant columns, and on each variant the
    learned controller rebuilds the mixture's row from the base observation and its
    context's nominal parameters, bit for bit (SI base columns, as the env sees them)."""
    from pneumatic_env.agents.learned import LearnedActor, LearnedController, pure_current
    from pneumatic_env.agents.ppo import train
    from pneumatic_env.agents.ppo_setup import row_deadband_a

    s = train(
        "ppo_fast-generalist",
        out=tmp_path,
        minutes=10.0,
        total_steps=2 * 256,
        overrides=TINY,
        log=lambda *a, **k: None,
    )
    assert s["inputs"][-2:] == ["param:tube_length_m", "param:bore_diameter_m"]
    assert s["steps"] == 512 and s["best"] is not None
    actor = LearnedActor(tmp_path / "actor.npz")
    assert actor.meta["variants"] == IDS
    options = {**actor.meta["env_options"], "normalize_observation": False}
    mix = MixtureVectorEnv([gym.make_vec(i, num_envs=2, **options) for i in IDS])
    obs, _ = mix.reset(seed=3)
    base_dim = observation_dim(20)
    ctrls = []
    for env in mix.envs:
        actor.meta["env_options"]["normalize_observation"] = False
        ctrl = LearnedController(ControllerContext.from_env(env), actor)
        ctrl.reset()
        ctrls.append(ctrl)
    rows0, rows1 = slice(0, 2), slice(2, 4)
    deadband = row_deadband_a(mix)
    for k in range(20):
        us = []
        for ctrl, rows in zip(ctrls, (rows0, rows1)):
            us.append(ctrl.act(obs[rows, :base_dim]))
            assert np.array_equal(ctrl.last_inputs, obs[rows]), (k, rows)
        current = np.concatenate(us)
        policy = np.concatenate([actor.action(obs[r, ctrls[0].index]) for r in (rows0, rows1)])
        # the trainer's current for the same actions (dead-band step per variant)
        assert np.array_equal(current, pure_current(policy, 1.3, deadband, 0.02, 2.0))
        obs, _, _, _, info = mix.step(current[:, None])
        assert np.array_equal(info["coil_current_a"], current), k


@pytest.mark.parametrize("variant", ["Numatics-0.5m", "Airpel-2m"])
def test_pure_action_map_steps_over_the_valve_dead_band(variant):
    """A small action (0.05) moves the force only with the dead-band step: 1.3 A x 0.05
    alone lies inside the dead band (Eqs. 43-46), where the chambers stay sealed. Zero
    action is zero current; the map is odd, increasing and within the coil limit."""
    from pneumatic_env.agents.base import valve_currents
    from pneumatic_env.agents.learned import pure_current

    env = gym.make_vec(f"pneumatic_env/ForceTrack-{variant}-v0", num_envs=2)
    i_db = valve_currents(env.unwrapped.base_params)[0]
    a = np.linspace(-1, 1, 2001)
    u = pure_current(a, 1.3, i_db, 0.02, 2.0)
    assert u[1000] == 0 and np.all(np.diff(u) > 0) and np.allclose(u, -u[::-1])
    assert np.abs(u).max() <= 2.0
    currents = np.array(
        [pure_current(0.05, 1.3, i_db, 0.0, 2.0), pure_current(0.05, 1.3, i_db, 0.02, 2.0)]
    )
    assert currents[0] < i_db < currents[1]
    env.reset(seed=0)
    obs, *_ = env.step(np.zeros((2, 1)))
    f0 = obs[:, 3].copy()
    for _ in range(100):
        obs, *_ = env.step(currents[:, None])
    moved = np.abs(obs[:, 3] - f0) / env.unwrapped.force_scale_n
    assert moved[0] < 1e-3 and moved[1] > 0.05, moved


def test_shipped_generalist_runs_every_variant_and_is_near_the_sliding_mode():
    """``ppo_generalist`` is one actor (``agents/policies/ppo_generalist-all.npz``) for all
    eight variants: it builds on each from the context alone, and on each of the four suite
    variants its mean RMS error is within issue 19's 10 % of the sliding mode's (target 2's
    threshold)."""
    from pneumatic_env.agents.bench import resolve_controller
    from pneumatic_env.ids import CYLINDER_IDS, TUBE_LENGTHS_M

    for variant in [f"{c}-{t}m" for c in CYLINDER_IDS for t in TUBE_LENGTHS_M]:
        spec = resolve_controller("ppo_generalist", variant)
        env = gym.make(f"pneumatic_env/ForceTrack-{variant}-v0", **spec.env_options)
        ctrl = spec.build(ControllerContext.from_env(env))
        obs, _ = env.reset(seed=0)
        ctrl.reset()
        for _ in range(30):
            current = ctrl.act(obs)
            assert np.all(np.isfinite(current)) and np.all(np.abs(current) <= 1.3), variant
            obs = env.step(current)[0]
    for variant in ("Numatics-0.5m", "Numatics-2m", "Airpel-0.5m", "Airpel-2m"):
        learned = np.mean(list(suite_rms_pct("ppo_generalist", variant).values()))
        base = np.mean(list(suite_rms_pct("sliding_mode", variant).values()))
        assert learned <= 1.1 * base, variant
