"""Learned control (issue 19): observation features, residual wrappers, the fast trainer, the
exported actors and the shipped policies, the tuner and the multi-seed statistics."""

from __future__ import annotations

import csv
import json
import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest

from conftest import SMALL, assert_check_env_passes, assert_error_names, suite_rms_pct
from pneumatic_env.agents.base import ControllerContext
from pneumatic_env.agents.registry import resolve_controller
from pneumatic_env.envs.features import FeatureConfig, FeatureState, normalize_base_observation
from pneumatic_env.envs.observation import observation_dim

ID = "pneumatic_env/ForceTrack-Numatics-2m-v0"
FEATURES = dict(action_history=3, measurement_history=2, tracking_error=True, relative_preview=True)
PREVIEW = 20


def _actions(n_steps, n_envs, seed=0):
    return np.random.default_rng(seed).uniform(-1.5, 1.5, size=(n_steps, n_envs, 1))


# --------------------------------------------------------------------------- features


@pytest.mark.parametrize("normalize", [False, True])
def test_feature_env_single_equals_vector_and_spaces(normalize):
    kw = dict(preview_steps=6, normalize_observation=normalize, **FEATURES)
    n, steps = 3, 12
    venv = gym.make_vec(ID, num_envs=n, max_episode_steps=5, **kw)
    dim = observation_dim(6) + 3 + 4 * 2 + 2 + 7
    assert venv.single_observation_space.shape == (dim,)
    assert len(venv.unwrapped.observation_columns) == dim
    assert venv.unwrapped.observation_columns[-1] == "rel_ref+6"
    acts = _actions(steps, n)
    vobs, _ = venv.reset(seed=10)
    vrec = [vobs]
    for a in acts:
        vobs, *_ = venv.step(a)
        vrec.append(vobs)
    for i in range(n):
        env = gym.make(ID, max_episode_steps=5, **kw)
        assert env.observation_space.shape == (dim,)
        o, _ = env.reset(seed=10 + i)
        assert np.array_equal(o, vrec[0][i])
        for k in range(steps):  # the vector env resets in the step that truncates
            o, _, _, truncated, _ = env.step(acts[k, i])
            if truncated:
                o, _ = env.reset()
            assert np.array_equal(o, vrec[k + 1][i]), (i, k)


def test_feature_options_leave_the_base_layout_alone_and_default_is_off():
    plain = gym.make_vec(ID, num_envs=2, preview_steps=5, normalize_observation=True)
    feat = gym.make_vec(ID, num_envs=2, preview_steps=5, normalize_observation=True, **FEATURES)
    assert plain.single_observation_space.shape == (observation_dim(5),)
    assert plain.unwrapped.observation_columns == ["p1", "p2", "x", "f"] + [
        f"ref+{j}" for j in range(6)
    ]
    o1, _ = plain.reset(seed=3)
    o2, _ = feat.reset(seed=3)
    for a in _actions(8, 2):
        assert np.array_equal(o1, o2[:, : o1.shape[1]])
        o1, *_ = plain.step(a)
        o2, *_ = feat.step(a)


def test_check_env_with_features():
    env = gym.make(ID, preview_steps=4, **FEATURES)
    assert_check_env_passes(env)


@pytest.mark.parametrize(
    "env_id,tracked", [(ID, "f"), ("pneumatic_env/PositionTrack-Airpel-1m-v0", "x")]
)
def test_env_features_equal_the_controller_side_rebuild(env_id, tracked):
    """The features of the env (through an autoreset) are those a controller rebuilds from
    the base observation and the currents it applied, bit for bit."""
    n, base_dim = 3, observation_dim(PREVIEW)
    feat_env = gym.make_vec(
        env_id,
        num_envs=n,
        max_episode_steps=7,
        preview_steps=PREVIEW,
        error_integral_tau_s=0.05,
        **FEATURES,
    )
    ctx = ControllerContext.from_env(feat_env)
    cfg = FeatureConfig(error_integral_tau_s=0.05, **FEATURES)
    state = FeatureState(cfg, n, PREVIEW, ctx.observation_scales, ctx.dt_s, tracked)
    obs, _ = feat_env.reset(seed=1)
    state.reset(np.arange(n), obs[:, :base_dim])
    assert np.array_equal(state.values, obs[:, base_dim:])
    for k, a in enumerate(_actions(16, n, seed=2)):
        obs, _, _, trunc, info = feat_env.step(a)
        applied = info["coil_current_a"]
        seen = obs.copy()  # what a controller sees: the final observations where truncated
        if trunc.any():
            seen[trunc] = np.stack(list(info["final_obs"][trunc]))
        state.update(seen[:, :base_dim], applied)
        assert np.array_equal(state.values, seen[:, base_dim:]), k
        if trunc.any():  # then the new episodes' first observations
            state.reset(np.flatnonzero(trunc), obs[trunc, :base_dim])
            assert np.array_equal(state.values, obs[:, base_dim:]), k
    assert k > 7  # an autoreset happened


def test_feature_values_by_hand():
    kw = dict(
        preview_steps=3,
        action_history=2,
        tracking_error=True,
        relative_preview=True,
        error_integral_leaky=False,
        error_integral_tau_s=0.5,
    )
    env = gym.make(ID, **kw)
    normalized = gym.make(ID, normalize_observation=True, **kw)
    cols = env.unwrapped.observation_columns
    o, _ = env.reset(seed=0)
    on, _ = normalized.reset(seed=0)
    scale, dt = env.unwrapped.reference_scale, env.unwrapped.control_dt_s
    integral = 0.0
    for u in (0.7, -0.4, 0.2):
        integral += dt / 0.5 * float(o[3] / scale - o[4] / scale)  # plain integral of e_n
        o, *_ = env.step(np.array([u]))
        on, *_ = normalized.step(np.array([u]))
    integral += dt / 0.5 * float(o[3] / scale - o[4] / scale)
    v = dict(zip(cols, o.astype(float)))
    assert (v["u-1"], v["u-2"]) == (np.float32(0.2), np.float32(-0.4))
    assert v["e"] == pytest.approx(v["f"] / scale - v["ref+0"] / scale, rel=1e-5, abs=1e-7)
    assert v["e_int"] == pytest.approx(10 * integral, rel=1e-5, abs=1e-7)
    for j in range(4):
        assert v[f"rel_ref+{j}"] == pytest.approx(
            (v[f"ref+{j}"] - v["f"]) / scale, rel=1e-5, abs=1e-7
        )
    # the features do not depend on normalize_observation; the base columns do, and the
    # numpy normalisation of the SI row is the env's
    assert np.array_equal(on[8:], o[8:])
    np.testing.assert_allclose(
        normalize_base_observation(o[None, :8], env.unwrapped.observation_scales)[0],
        on[:8],
        rtol=1e-6,
        atol=1e-7,
    )


@pytest.mark.parametrize(
    "kwargs,field,value,rule",
    [
        ({"action_history": -1}, "action_history", -1, "an integer >= 0"),
        ({"measurement_history": 1.5}, "measurement_history", 1.5, "an integer >= 0"),
        ({"tracking_error": "yes"}, "tracking_error", "yes", "True or False"),
        ({"error_integral_tau_s": 0.0}, "error_integral_tau_s", 0.0, "finite number > 0"),
    ],
)
def test_bad_feature_options(kwargs, field, value, rule):
    with pytest.raises(ValueError) as err:
        gym.make(ID, **kwargs)
    assert_error_names(err, field, value, rule)


def test_start_step_option_shifts_the_episode():
    venv = gym.make_vec(ID, num_envs=2, max_episode_steps=6, preview_steps=2)
    o0, _ = venv.reset(seed=5)
    o1, _ = venv.reset(seed=5, options={"start_step": [0, 4]})
    refs = venv.unwrapped.references
    assert np.array_equal(o1[0], o0[0]) and o1[1, 4] == np.float32(refs[1, 4])
    truncs = [venv.step(np.zeros((2, 1)))[3] for _ in range(6)]
    assert [t.tolist() for t in truncs[1:3]] == [[False, True], [False, False]]
    assert truncs[5].tolist() == [True, False]
    for bad in ([0, 6], [0], 1.5):
        with pytest.raises(ValueError) as err:
            venv.reset(options={"start_step": bad})
        assert_error_names(err, "options['start_step']", bad, "max_episode_steps = 6")
    with pytest.raises(ValueError, match=r"must be one of \['reference'\]"):
        gym.make(ID).reset(options={"start_step": 1})


# --------------------------------------------------------------------------- residual


@pytest.mark.parametrize("base", ["sliding_mode", "pid"])
def test_zero_correction_is_the_classical_controller_bit_for_bit(base):
    from pneumatic_env.agents.residual_env import ResidualVectorWrapper

    kw = dict(preview_steps=PREVIEW, max_episode_steps=40)
    venv = gym.make_vec(ID, num_envs=3, **kw)
    ctrl = resolve_controller(base, "Numatics-2m").build(ControllerContext.from_env(venv))
    obs, _ = venv.reset(seed=4)
    ctrl.reset()
    ref, cur = [], []
    for _ in range(90):
        u = ctrl.act(obs)
        obs, _, _, trunc, info = venv.step(u.reshape(3, 1))
        ctrl.reset(np.flatnonzero(trunc))
        ref.append(obs)
        cur.append(info["coil_current_a"])
    wrapped = ResidualVectorWrapper(gym.make_vec(ID, num_envs=3, **kw), base=base, gate_floor=0.1)
    assert wrapped.single_observation_space.shape == (observation_dim(PREVIEW) + 2,)
    obs, _ = wrapped.reset(seed=4)
    for k in range(90):
        obs, _, _, trunc, info = wrapped.step(np.zeros((3, 1)))
        assert np.array_equal(obs[:, :-2], ref[k]), k
        assert np.array_equal(info["base_current_a"], info["coil_current_a"])
        assert np.array_equal(info["coil_current_a"], cur[k])
        if trunc.any():
            assert info["final_obs"][np.flatnonzero(trunc)[0]].shape == obs.shape[1:]


def test_single_residual_wrapper_and_registered_ids():
    from pneumatic_env.agents.residual_env import ResidualWrapper, residual_env_id

    env = gym.make(ID, preview_steps=PREVIEW)
    ctrl = resolve_controller("sliding_mode", "Numatics-2m").build(ControllerContext.from_env(env))
    o, _ = env.reset(seed=2)
    ctrl.reset()
    us = []
    for _ in range(30):
        u = ctrl.act(o)
        o, *_ = env.step(u)
        us.append(u[0])
    w = ResidualWrapper(gym.make(ID, preview_steps=PREVIEW), correction_fraction=0.1)
    w.reset(seed=2)
    for k in range(30):
        _, _, _, _, info = w.step(np.zeros(1))
        assert info["coil_current_a"] == us[k]
    # a full action moves the current by the bound (0.1 x 2 A) from the classical one
    _, _, _, _, info = w.step(np.array([1.0]))
    assert info["coil_current_a"] == pytest.approx(np.clip(info["base_current_a"] + 0.2, -2, 2))
    rid = residual_env_id(ID)
    assert rid == "pneumatic_env/ResidualForceTrack-Numatics-2m-v0"
    single = gym.make(f"pneumatic_env.agents.residual_env:{rid}", correction_fraction=0.1)
    assert single.observation_space.shape == (observation_dim(PREVIEW) + 2,)
    assert single.action_space == gym.spaces.Box(-1, 1, (1,), np.float32)
    vec = gym.make_vec(f"pneumatic_env.agents.residual_env:{rid}", num_envs=2)
    assert vec.reset(seed=0)[0].shape == (2, observation_dim(PREVIEW) + 2)
    with pytest.raises(ValueError) as err:
        ResidualWrapper(gym.make(ID, preview_steps=PREVIEW), base="lqr")
    assert_error_names(err, "base", "lqr", "['sliding_mode', 'pid']")


def test_residual_envs_work_with_stable_baselines3():
    from stable_baselines3 import PPO
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    from pneumatic_env.agents.residual_env import ResidualVectorWrapper, residual_env_id
    from pneumatic_env.agents.sb3 import SB3VecEnv

    sb3_check_env(gym.make(f"pneumatic_env.agents.residual_env:{residual_env_id(ID)}"))
    venv = SB3VecEnv(
        ResidualVectorWrapper(
            gym.make_vec(ID, num_envs=4, max_episode_steps=16, preview_steps=PREVIEW)
        )
    )
    model = PPO("MlpPolicy", venv, n_steps=16, batch_size=32, n_epochs=1, device="cpu")
    model.learn(64)
    assert model.num_timesteps == 64


def test_sliding_mode_peek_and_applied_hooks():
    venv = gym.make_vec(ID, num_envs=2, preview_steps=PREVIEW)
    sm = resolve_controller("sliding_mode", "Numatics-2m").build(ControllerContext.from_env(venv))
    twin = resolve_controller("sliding_mode", "Numatics-2m").build(ControllerContext.from_env(venv))
    obs, _ = venv.reset(seed=0)
    for _ in range(5):
        u = sm.act(obs)
        twin.act(obs)
        obs, *_ = venv.step(u.reshape(2, 1))
    peeked, error = sm.peek(obs, np.arange(2))
    assert np.array_equal(sm.pending, twin.pending)  # peek changes nothing
    assert np.array_equal(peeked, sm.act(obs)) and np.array_equal(peeked, twin.act(obs))
    assert np.array_equal(error, sm.last_error)
    sm.applied(obs, peeked + 0.3, rows=[])
    assert np.array_equal(sm.pending, twin.pending)
    sm.applied(obs, peeked + 0.3, rows=[1])  # another current in flight: another rate
    slot = (sm.head - 1) % sm.d
    assert np.array_equal(sm.pending[0], twin.pending[0])
    assert sm.pending[1, slot] != twin.pending[1, slot]


# --------------------------------------------------------------------------- fast trainer


def _config_extending(tmp_path, text: str):
    from pneumatic_env.agents.config import agent_config_path

    path = tmp_path / "typo.yaml"
    path.write_text(f"extends: {agent_config_path('ppo_fast-numatics-2m')}\n{text}")
    return path


def test_a_typo_in_a_ppo_fast_config_key_is_refused_naming_the_key_file_and_allowed_keys(
    tmp_path,
):
    from pneumatic_env.agents.config import ConfigError
    from pneumatic_env.agents.ppo_config import load_config

    path = _config_extending(
        tmp_path, "hyperparameters:\n  gama: {value: 0.9, unit: '-', source: test}\n"
    )
    with pytest.raises(ConfigError) as err:
        load_config(path)
    assert_error_names(err, ["hyperparameters.gama", str(path)], rule=["gamma", "gae_lambda"])
    path = _config_extending(tmp_path, "rewrad: {}\n")
    with pytest.raises(ConfigError) as err:
        load_config(path)
    assert_error_names(err, ["rewrad", str(path)], rule=["reward", "hyperparameters"])
    with pytest.raises(ConfigError) as err:
        load_config("ppo_fast-numatics-2m", {"training.stager": False})
    assert_error_names(err, "training.stager", rule="stagger")


@pytest.mark.parametrize(
    "key, value", [("hyperparameters.num_envs", 2.5), ("training.stagger", "yes")]
)
def test_a_ppo_fast_setting_of_the_wrong_type_is_refused_naming_it(key, value):
    from pneumatic_env.agents.config import ConfigError
    from pneumatic_env.agents.ppo_config import load_config

    with pytest.raises(ConfigError) as err:
        load_config("ppo_fast-numatics-2m", {key: value})
    assert_error_names(err, key, value)


def test_ppo_fast_configs_round_trip_with_their_units_and_sources(tmp_path):
    """Every ppo_fast config: typed settings, and its tree (units, sources) written back
    reads as the same config; an override keeps its entry's unit."""
    from pneumatic_env.agents.config import agent_config_dir, write_agent_config
    from pneumatic_env.agents.ppo_config import load_config

    names = sorted(p.stem for p in agent_config_dir().glob("ppo_fast-*.yaml"))
    names.remove("ppo_fast-references")
    assert len(names) >= 10
    for name in names:
        cfg = load_config(name)
        write_agent_config(tmp_path / "copy.yaml", cfg.to_tree())
        again = load_config(tmp_path / "copy.yaml")
        assert again == cfg and again.to_tree() == cfg.to_tree(), name
        assert isinstance(cfg.hyperparameters.num_envs, int) and cfg.mode in ("pure", "residual")
    cfg = load_config("ppo_fast-numatics-2m", {"hyperparameters.gamma": 0.9})
    assert cfg.hyperparameters.gamma == 0.9 and cfg.unit("hyperparameters.gamma") == (
        "per control period"
    )
    assert cfg.to_tree()["hyperparameters"]["gamma"]["source"].startswith("override")
    assert cfg.unit("training.minutes") == "min of wall time" and cfg.unit("mode") is None


@pytest.fixture(scope="module")
def fast_run(tmp_path_factory):
    from pneumatic_env.agents.ppo import train

    out = tmp_path_factory.mktemp("ppo_fast")
    summary = train(
        "ppo_fast-numatics-2m",
        seed=1,
        out=out,
        minutes=10.0,  # ends by steps (3 updates of 32 x 8), not by the machine's load
        total_steps=3 * 256,
        overrides={**SMALL, "training.residual_gains": [1.0, 0.0]},
        log=lambda *a, **k: None,
    )
    return out, summary


def test_fast_trainer_writes_actor_curve_and_throughput(fast_run):
    out, s = fast_run
    for name in (
        "actor.npz",
        "actor_best.npz",
        "progress.csv",
        "train.json",
        "learning_curve.png",
        "checkpoint.pt",
    ):
        assert (out / name).is_file(), name
    rows = list(csv.DictReader(open(out / "progress.csv")))
    assert len(rows) == s["updates"] >= 2
    assert all(float(r["steps"]) == 32 * 8 * int(r["update"]) for r in rows)
    assert any(r["val_rms_pct"] != "" for r in rows)
    info = json.loads((out / "train.json").read_text())
    assert info["env_only_steps_per_s"] > 0 and 0 < info["env_share"] < 1
    assert info["inputs"][-2:] == ["base_current", "base_error"]
    assert len(info["inputs"]) == 3 + 1 + 21 + 12 + 16 + 1 + 2


def test_fast_trainer_ends_by_choosing_the_residual_gain(fast_run):
    """A residual config that lists gains: the best actor is rewritten at the gain with
    the lowest validation score (agents.residual_gain), the trained one kept beside it."""
    from pneumatic_env.agents.learned import LearnedActor

    out, s = fast_run
    scores = s["residual_gain"]["scores"]
    assert [r["gain"] for r in scores] == [1.0, 0.0]
    best = min(scores, key=lambda r: r["score_rms_pct"])
    assert json.loads((out / "train.json").read_text())["residual_gain"]["gain"] == best["gain"]
    trained = LearnedActor(out / "actor_best_unscaled.npz").meta["residual"]
    chosen = LearnedActor(out / "actor_best.npz").meta["residual"]
    assert chosen["correction_fraction"] == best["gain"] * trained["correction_fraction"]


def test_fast_trainer_resumes_from_its_checkpoint(fast_run, tmp_path):
    import shutil

    from pneumatic_env.agents.ppo import train

    out, s = fast_run
    shutil.copytree(out, tmp_path / "run")
    s2 = train(
        "ppo_fast-numatics-2m",
        seed=1,
        out=tmp_path / "run",
        minutes=10.0,
        total_steps=5 * 256,
        overrides=SMALL,
        resume=True,
        log=lambda *a, **k: None,
    )
    assert s2["updates"] > s["updates"] and s2["steps"] == s2["updates"] * 256
    rows = list(csv.DictReader(open(tmp_path / "run" / "progress.csv")))
    assert [int(r["update"]) for r in rows] == list(range(1, s2["updates"] + 1))


def test_numpy_actor_equals_the_torch_actor(fast_run):
    import torch

    from pneumatic_env.agents.learned import LearnedActor
    from pneumatic_env.agents.ppo_networks import Agent

    out, _ = fast_run
    actor = LearnedActor(out / "actor.npz")
    agent = Agent(actor.obs_dim, [64, 64], [64, 64], -2.0, zero_init=True)
    agent.load_state_dict(torch.load(out / "checkpoint.pt", weights_only=False)["agent"])
    x = np.random.default_rng(0).normal(size=(50, actor.obs_dim)) * 3
    xn = np.clip((x - actor.obs_mean) / actor.obs_std, -10, 10)
    with torch.no_grad():
        t32 = agent.actor(torch.from_numpy(xn.astype(np.float32))).numpy()[:, 0]
        t64 = agent.double().actor(torch.from_numpy(xn)).numpy()[:, 0]
    np.testing.assert_allclose(actor.action(x), np.clip(t64, -1, 1), rtol=0, atol=1e-12)
    np.testing.assert_allclose(actor.action(x), np.clip(t32, -1, 1), rtol=0, atol=1e-5)


def test_numpy_tanh_equals_torch_tanh_in_value_and_gradient():
    import torch

    from pneumatic_env.agents.policy import actor_layers
    from pneumatic_env.agents.ppo_networks import NumpyTanh, mlp

    for dtype, tol in ((torch.float32, 1e-6), (torch.float64, 1e-15)):
        x = torch.linspace(-12.0, 12.0, 2001, dtype=dtype).reshape(-1, 3).requires_grad_()
        x_ref = x.detach().clone().requires_grad_()
        y, y_ref = NumpyTanh()(x), torch.tanh(x_ref)
        assert y.dtype == dtype
        torch.testing.assert_close(y, y_ref, rtol=0, atol=tol)
        w = torch.linspace(-1.0, 1.0, x.numel(), dtype=dtype).reshape(x.shape)
        (y * w).sum().backward()
        (y_ref * w).sum().backward()
        torch.testing.assert_close(x.grad, x_ref.grad, rtol=0, atol=4 * tol)
    x = torch.randn(7, 4, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(NumpyTanh(), (x,))
    # the exported actor names it Tanh, which agents.learned evaluates with np.tanh
    assert [a for _, _, a in actor_layers(list(mlp(4, [8, 8], 1, 0.01)))] == [
        "Tanh",
        "Tanh",
        "Identity",
    ]


def test_learned_controller_rebuilds_the_training_observation(fast_run):
    """From the base observation alone the controller rebuilds the training env's
    observation (features and residual columns) and acts as the policy on it, bit for bit
    (here with SI base columns, so that the env and the controller see the same floats)."""
    from pneumatic_env.agents.learned import LearnedActor, LearnedController
    from pneumatic_env.agents.registry import make_base_controller
    from pneumatic_env.agents.residual_env import ResidualVectorWrapper

    out, _ = fast_run
    actor = LearnedActor(out / "actor.npz")
    actor.meta["env_options"]["normalize_observation"] = False
    env = ResidualVectorWrapper(
        gym.make_vec(ID, num_envs=2, **actor.meta["env_options"]), **actor.meta["residual"]
    )
    context = ControllerContext.from_env(env)
    base = make_base_controller(actor.residual_config.base, context, "Numatics-2m")
    ctrl = LearnedController(context, actor, base)
    obs, _ = env.reset(seed=0)
    ctrl.reset()
    base_dim = observation_dim(PREVIEW)
    for k in range(25):
        u = ctrl.act(obs[:, :base_dim])
        assert np.array_equal(ctrl.last_inputs, obs), k
        action = actor.action(obs[:, ctrl.index])
        obs, _, _, _, info = env.step(action[:, None])
        assert np.array_equal(info["coil_current_a"], u), k


def test_pure_mode_trains_and_runs_as_a_controller(tmp_path):
    from pneumatic_env.agents.bench import closed_loop, make_env
    from pneumatic_env.agents.ppo import train
    from pneumatic_env.agents.ppo_config import load_config

    cfg = load_config("ppo_fast-pure-numatics-2m")
    assert cfg.mode == "pure" and cfg.hyperparameters.num_envs == 2048  # extends
    s = train(
        "ppo_fast-pure-numatics-2m",
        out=tmp_path,
        minutes=10.0,
        total_steps=256,
        overrides=SMALL,
        log=lambda *a, **k: None,
    )
    assert "base_current" not in s["inputs"] and s["steps"] > 0
    spec = resolve_controller(str(tmp_path / "actor.npz"), "Numatics-2m")
    env = make_env("Numatics-2m", 2, 30, **spec.env_options)
    ctrl = spec.build(ControllerContext.from_env(env))
    tr = closed_loop(
        env, ctrl, [{"kind": "sine", "amplitude": 0.3, "frequency_hz": 5.0}] * 2, [1, 2], 30
    )
    assert np.all(np.abs(tr["current_a"]) <= 1.3)  # action_scale_a


@pytest.mark.parametrize("variant", ["Numatics-2m", "Airpel-2m"])
def test_shipped_policy_beats_the_sliding_mode_where_the_delay_hurts(variant):
    """The shipped residual on a 2 m variant: a lower mean RMS error than the sliding mode
    it corrects, and at least 20 % lower on the 10 and 20 Hz sines and the chirp (issue
    19's target 1; the thresholds are the issue's)."""
    learned = suite_rms_pct("ppo_residual", variant)
    base = suite_rms_pct("sliding_mode", variant)
    assert np.mean(list(learned.values())) < np.mean(list(base.values()))
    for task in ("sine_10hz", "sine_20hz", "chirp"):
        assert learned[task] <= 0.8 * base[task], task


@pytest.mark.parametrize("variant", ["Numatics-0.5m", "Airpel-0.5m", "Numatics-2m", "Airpel-2m"])
def test_shipped_taught_pure_policy_is_within_10_percent_of_the_sliding_mode(variant):
    """The shipped pure policy (no classical controller inside; trained with the sliding
    mode as its teacher, agents/teacher.py) on each variant: its mean RMS error is at
    most 1.1 x the sliding mode's (issue 19's target 2; the threshold is the issue's)."""
    from pneumatic_env.agents.learned import LearnedActor, shipped_policy_path

    actor = LearnedActor(shipped_policy_path("ppo_pure", variant))
    assert actor.residual_config is None  # pure: the network sets the current
    learned = list(suite_rms_pct("ppo_pure", variant).values())
    base = list(suite_rms_pct("sliding_mode", variant).values())
    assert np.mean(learned) <= 1.1 * np.mean(base)


@pytest.mark.parametrize("variant", ["Numatics-2m", "Airpel-2m", "Numatics-0.5m", "Airpel-0.5m"])
def test_shipped_adaptive_policy_keeps_its_lead_off_its_model(variant):
    """The shipped adaptive residual (``ppo_adaptive``: a residual on the PID trained over a
    mixture of plants, configs/agents/ppo_fast-adaptive-mixture-*.yaml, on the 2 m variants
    with a critic that sees each episode's plant, ppo_fast-adaptive-privileged-critic-*.yaml;
    its gain chosen on validation data, agents/residual_gain.py) on the robustness table,
    against issue 35's target 3 and its thresholds: on the 2 m variants its error is below
    the PID's in every perturbed cell; on the 0.5 m variants its worst ratio to its own
    nominal error is at most the PID's. (The target asks for both on every variant: the
    worst ratio of Numatics-2m is missed, 2.06 against the PID's 1.90, its nominal error
    being 1.2 points lower than the PID's; docs/benchmark.md.)"""
    from pneumatic_env.agents.config import load_agent_config
    from pneumatic_env.agents.robustness import (
        NOMINAL,
        perturbed_plants,
        robustness_rows,
        worst_ratio,
    )

    plants = perturbed_plants(load_agent_config("robustness"), variant)
    del plants["friction x2"]  # ForceTrack clamps the rod: the nominal plant again
    table = robustness_rows(variant, ["pid", "ppo_adaptive"], plants, progress=print)
    assert table["ppo_adaptive"][NOMINAL] < table["pid"][NOMINAL], table
    if variant.endswith("-2m"):
        for name in plants:
            assert table["ppo_adaptive"][name] < table["pid"][name], (name, table)
    else:
        worst = {c: worst_ratio(cells) for c, cells in table.items()}
        assert worst["ppo_adaptive"] <= worst["pid"], worst


def test_a_variant_without_a_shipped_actor_is_named():
    with pytest.raises(ValueError) as err:
        resolve_controller("ppo_residual", "Numatics-1m")
    assert_error_names(err, "controller", "ppo_residual", ["Numatics-1m", "numatics-2m"])


def test_bench_list_prints_every_accepted_name():
    out = subprocess.run(
        [sys.executable, "-m", "pneumatic_env.cli", "bench", "--list"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout.split()
    assert out[:3] == ["pid", "sliding_mode", "zero"] and "ppo_residual" in out
    for name in out:
        resolve_controller(name, "Numatics-2m")


# --------------------------------------------------------------------------- tuning


def _tiny_tune_files(tmp_path):
    from pneumatic_env.agents.config import agent_config_path

    base = tmp_path / "base.yaml"
    base.write_text(
        f"extends: {agent_config_path('ppo_fast-numatics-2m')}\n"
        "hyperparameters:\n"
        "  num_envs: {value: 16, unit: envs, source: test}\n"
        "  rollout_steps: {value: 4, unit: steps, source: test}\n"
        "  minibatches: {value: 1, unit: '-', source: test}\n"
        "training:\n"
        "  validation_steps: {value: 40, unit: steps, source: test}\n"
        "  episode_steps: {value: 40, unit: steps, source: test}\n"
    )
    space = tmp_path / "space.yaml"
    space.write_text(
        f"algo: ppo_fast\nbase_config: {base}\n"
        "budget:\n"
        "  trials: {value: 2, unit: trials, source: test}\n"
        "  minutes_per_trial: {value: 0.02, unit: min, source: test}\n"
        "  slices: {value: 2, unit: '-', source: test}\n"
        "sampler: {n_startup_trials: {value: 1, unit: '-', source: test}}\n"
        "pruner:\n"
        "  n_startup_trials: {value: 1, unit: '-', source: test}\n"
        "  n_warmup_steps: {value: 0, unit: '-', source: test}\n"
        "search_space:\n"
        "  hyperparameters.learning_rate:\n"
        "    value: {type: float, low: 1.0e-4, high: 1.0e-3, log: true}\n"
        "    unit: '-'\n    source: test\n"
        "  hyperparameters.epochs:\n"
        "    value: {type: categorical, choices: [1, 2]}\n"
        "    unit: epochs per update\n    source: test\n"
    )
    return space


def _tune_args(tmp_path, space, **changes):
    """``pneumatic-env tune``'s arguments for a tiny study in ``tmp_path/out``."""
    import argparse

    args = dict(
        space=str(space),
        env=None,
        trials=1,
        minutes_per_trial=None,
        steps_per_trial=None,
        storage=None,
        study_name="tiny",
        seed=0,
        out=str(tmp_path / "out"),
        ray_address=None,
    )
    return argparse.Namespace(**{**args, **changes})


def test_tune_tiny_budget_runs_and_resumes(tmp_path):
    import optuna

    from pneumatic_env.agents import tune

    args = _tune_args(tmp_path, _tiny_tune_files(tmp_path))
    assert tune.run(args) == 0
    args.trials = 2  # the same storage and name: continues with one more trial
    assert tune.run(args) == 0
    study = optuna.load_study(
        study_name="tiny", storage=f"sqlite:///{tmp_path / 'out' / 'study.db'}"
    )
    assert len(study.trials) == 2
    best = json.loads((tmp_path / "out" / "best.json").read_text())
    assert set(best["params"]) == {"hyperparameters.learning_rate", "hyperparameters.epochs"}
    from pneumatic_env.agents.ppo_config import load_config

    tuned = load_config(tmp_path / "out" / "ppo_fast-tuned.yaml")
    assert tuned.hyperparameters.epochs == best["params"]["hyperparameters.epochs"]
    assert tuned.hyperparameters.num_envs == 16


def test_tune_with_a_step_budget_evaluates_at_fixed_steps_and_scores_chatter(tmp_path):
    """``--steps-per-trial``: every trial ends at the step budget with its validations at
    the slices' step counts (not by wall time), and ``objective.chatter_pct_per_a`` adds
    the chatter to the score each trial reports."""
    import csv

    import optuna

    from pneumatic_env.agents import tune

    space = _tiny_tune_files(tmp_path)
    space.write_text(
        space.read_text()
        + "objective:\n  chatter_pct_per_a: {value: 20.0, unit: '%/A', source: test}\n"
    )
    batch = 16 * 4  # num_envs x rollout_steps of the tiny base config
    args = _tune_args(
        tmp_path,
        space,
        trials=2,
        minutes_per_trial=10.0,  # a cap only
        steps_per_trial=6 * batch,
        study_name="steps",
    )
    assert tune.run(args) == 0
    study = optuna.load_study(
        study_name="steps", storage=f"sqlite:///{tmp_path / 'out' / 'study.db'}"
    )
    for trial in study.trials:
        rows = list(
            csv.DictReader(open(tmp_path / "out" / f"trial-{trial.number:03d}" / "progress.csv"))
        )
        evaluated = [int(r["steps"]) for r in rows if r["val_rms_pct"] != ""]
        assert evaluated == [3 * batch, 6 * batch], evaluated
        last = rows[-1]
        expect = float(last["val_rms_pct"]) + 20.0 * float(last["val_chatter_a"])
        assert trial.value == pytest.approx(expect, rel=1e-4)
        assert float(last["val_chatter_a"]) > 0.0
    tuned = (tmp_path / "out" / "ppo_fast-tuned.yaml").read_text()
    assert "20 %/A x validation chatter" in tuned
    # a tuned value the base file does not set takes its unit from the search space
    from pneumatic_env.config_files import read_yaml

    entry = read_yaml(tmp_path / "out" / "ppo_fast-tuned.yaml")["hyperparameters"]["epochs"]
    assert entry["unit"] == "epochs per update"


def test_tune_never_prunes_a_trial_at_its_warmup_evaluations(tmp_path, monkeypatch):
    """With ``pruner.n_warmup_steps`` = 1 the median pruner judges a trial from its second
    evaluation on: later trials that are worse at every slice are pruned there, never at
    the first (a stand-in for training reports the slices)."""
    import optuna

    from pneumatic_env.agents import tune

    spec = tune.load_space(_tiny_tune_files(tmp_path))
    spec["pruner"] = {"n_startup_trials": 1, "n_warmup_steps": 1}

    def fake_trial(params, spec_, env_id, seed, out, minutes, report, steps=None):
        for slice_ in (1, 2, 3):
            report(10.0 + seed, slice_)  # each trial worse than the ones before
        return 10.0 + seed

    monkeypatch.setattr(tune, "_train_trial", fake_trial)
    study = tune._study(spec, "sqlite:///" + str(tmp_path / "s.db"), "warmup", seed=0)
    study.optimize(tune.objective(spec, "unused", 0, tmp_path, 1.0), n_trials=4)
    pruned = [t for t in study.trials if t.state == optuna.trial.TrialState.PRUNED]
    assert len(pruned) == 3
    assert all(sorted(t.intermediate_values) == [0, 1] for t in pruned)


def test_tune_refuses_a_step_budget_that_is_not_positive(tmp_path):
    from pneumatic_env.agents import tune

    args = _tune_args(tmp_path, _tiny_tune_files(tmp_path), steps_per_trial=-5.0)
    with pytest.raises(SystemExit) as err:
        tune.run(args)
    assert "--steps-per-trial (budget.steps_per_trial) = -5.0" in str(err.value)
    assert "> 0" in str(err.value)


def test_tune_search_space_errors(tmp_path):
    from pneumatic_env.agents.config import ConfigError
    from pneumatic_env.agents.tune import load_space

    bad = tmp_path / "bad.yaml"
    bad.write_text(
        "search_space:\n  x.y:\n    value: {type: float, low: 2, high: 1}\n"
        "    unit: '-'\n    source: test\n"
    )
    with pytest.raises(ConfigError) as err:
        load_space(bad)
    assert_error_names(err, "search_space.x.y", rule="low < high")


@pytest.mark.slow
def test_tune_on_a_local_ray_instance(tmp_path):
    pytest.importorskip("ray")
    from pneumatic_env.agents import tune

    args = _tune_args(
        tmp_path, _tiny_tune_files(tmp_path), trials=2, study_name="ray", ray_address="local"
    )
    assert tune.run(args) == 0
    assert (tmp_path / "out" / "best.json").is_file()


def test_ray_path_is_optional(tmp_path):
    code = (
        "import sys; sys.modules['ray'] = None; import argparse; "
        "from pneumatic_env.agents import tune; "
        "a = argparse.Namespace(space='tune-ppo_fast', env=None, trials=1, "
        "minutes_per_trial=None, steps_per_trial=None, storage=None, study_name='x', seed=0, "
        "out=sys.argv[1], ray_address='auto'); tune.run(a)"
    )
    res = subprocess.run(
        [sys.executable, "-c", code, str(tmp_path)], capture_output=True, text=True
    )
    assert res.returncode != 0 and "pneumatic_env[distributed]" in res.stderr


# --------------------------------------------------------------------------- seed statistics


def _rows(values, chatter, air):
    tasks = ["sine_10hz", "sine_20hz", "chirp", "step_up"]
    return [
        {"task": t, "rms_error_pct": v, "chatter_rms_a": c, "air_mg": a}
        for t, v, c, a in zip(tasks, values, chatter, air)
    ]


def test_seed_statistics_by_hand():
    from pneumatic_env.agents.evaluate_seeds import seeds_markdown, summarize_variant

    base = _rows([4.0, 8.0, 4.0, 5.0], [0.02] * 4, [100, 100, 100, 1])
    seeds = [
        _rows([2.0, 4.0, 2.0, 5.0], [0.03] * 4, [100, 100, 100, 2]),
        _rows([3.0, 6.0, 3.0, 5.0], [0.02] * 4, [100, 100, 100, 1]),
    ]
    s = summarize_variant(seeds, base, reps=200)
    assert s["paired_ratio"]["value"] == pytest.approx(
        np.mean([(0.5 * 3 + 1) / 4, (0.75 * 3 + 1) / 4])
    )
    assert s["beats"] is None and s["paired_ratio"]["high"] < 1  # 2 seeds: no verdict
    three = summarize_variant([*seeds, seeds[0]], base, reps=200)
    assert three["beats"] is True
    assert s["probability_of_improvement"]["value"] == pytest.approx((3 * 1 + 0.5) / 4)
    assert s["task_ratios"]["sine_20hz"]["value"] == pytest.approx(0.625)
    assert s["mean_rms_pct"]["value"] == pytest.approx(np.mean([13 / 4, 17 / 4]))
    assert s["worst_chatter_ratio"] == {"ratio": pytest.approx(1.25), "task": "sine_10hz"}
    assert s["worst_air_ratio"] == {"ratio": pytest.approx(1.5), "task": "step_up"}
    table = seeds_markdown(
        {
            "baseline": "sliding_mode",
            "suite_version": "v1",
            "actors": ["a", "b"],
            "variants": {"Numatics-2m": s},
        }
    )
    assert "| Numatics-2m | 2 | 3.75 [" in table and "| - (< 3 seeds) |" in table


def test_evaluate_seeds_runs_the_suite_per_seed(tmp_path):
    from pneumatic_env.agents.evaluate_seeds import main
    from pneumatic_env.agents.learned import shipped_policy_path

    suite = tmp_path / "suite.yaml"
    suite.write_text(
        "version: t\ntask: ForceTrack\nvariants: [Numatics-2m]\nenv: {preview_steps: 20}\n"
        "metrics: {bandwidth_task: chirp, bandwidth_bins_per_octave: 6, "
        "bandwidth_level: 0.7071}\n"
        "tasks:\n"
        "  - {name: sine_10hz, seed: 1, duration_s: 0.2, "
        "reference: {kind: sine, amplitude: 0.3, frequency_hz: 10.0}}\n"
        "  - {name: chirp, seed: 2, duration_s: 0.2, reference: {kind: chirp, amplitude: 0.3,"
        " f0_hz: 5.0, f1_hz: 30.0, duration_s: 0.2}}\n"
    )
    actor = shipped_policy_path("ppo_residual", "Numatics-2m")
    assert (
        main(
            [
                str(actor),
                str(actor),
                "--suite",
                str(suite),
                "--reps",
                "50",
                "--out",
                str(tmp_path / "seeds.md"),
            ]
        )
        == 0
    )
    result = json.loads((tmp_path / "seeds.json").read_text())["variants"]["Numatics-2m"]
    assert (
        result["n_seeds"] == 2 and result["paired_ratio"]["low"] == result["paired_ratio"]["high"]
    )  # identical seeds: no spread
