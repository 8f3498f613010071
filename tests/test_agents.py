"""Tests of the agents package: controllers, SB3 adapter, policy export, PPO smoke run."""

from __future__ import annotations

import copy
import math
import warnings

import gymnasium as gym
import numpy as np
import pytest

import pneumatic_env
from conftest import PID_TEST_GAINS
from pneumatic_env.agents.base import ControllerContext, ZeroController, valve_currents
from pneumatic_env.agents.bench import closed_loop, make_env, resolve_controller
from pneumatic_env.agents.config import ConfigError, load_agent_config
from pneumatic_env.agents.pid import PIDController
from pneumatic_env.agents.sliding_mode import force_rate, invert_force_rate, model_constants
from pneumatic_env.envs.tasks import force_scale
from pneumatic_env.params import load_parameters

ID_05 = pneumatic_env.env_id("ForceTrack", "Numatics", "0.5")


# --------------------------------------------------------------------------- controllers


def _pid(ctx, **over):
    gains = dict(PID_TEST_GAINS)
    gains.update(over)
    return PIDController(ctx, **gains)


@pytest.mark.parametrize("controller", ["pid", "sliding_mode"])
@pytest.mark.parametrize("cylinder", ["Numatics", "Airpel"])
def test_step_reaches_target_on_short_tube(controller, cylinder):
    """A step to half the force scale is tracked within 5 % of scale 0.2 s after the step."""
    variant = f"{cylinder}-0.5m"
    spec = resolve_controller(controller, variant)
    n = 1000
    env = make_env(variant, 2, n, **spec.env_options)
    ctrl = spec.build(ControllerContext.from_env(env))
    step_time = 0.1
    refs = [
        {"kind": "step", "amplitude": 0.5, "step_time_s": step_time},
        {"kind": "step", "amplitude": -0.5, "step_time_s": step_time},
    ]
    tr = closed_loop(env, ctrl, refs, [0, 1], n)
    scale = env.unwrapped.reference_scale
    t = (np.arange(n) + 1) * env.unwrapped.control_dt_s
    settled = t >= step_time + 0.2
    err = np.abs(tr["force_n"] - tr["reference_n"])[settled]
    assert np.all(err < 0.05 * scale), f"max |e| {err.max():.2f} N, scale {scale:.1f} N"
    # the step really happened: the force moved by half the scale in both directions
    assert tr["force_n"][-1, 0] > 0.45 * scale and tr["force_n"][-1, 1] < -0.45 * scale


def test_batched_controller_equals_separate_runs():
    """Each row of a batched PID keeps its own state: a batch of two = two runs of one."""
    refs = [
        {"kind": "sine", "amplitude": 0.3, "frequency_hz": 5.0},
        {"kind": "random_step", "amplitude": 0.5, "hold_min_s": 0.05, "hold_max_s": 0.1},
    ]
    n = 200
    env = make_env("Numatics-0.5m", 2, n, preview_steps=20)
    both = closed_loop(env, _pid(ControllerContext.from_env(env)), refs, [3, 4], n)
    for i in range(2):
        env1 = make_env("Numatics-0.5m", 1, n, preview_steps=20)
        one = closed_loop(env1, _pid(ControllerContext.from_env(env1)), [refs[i]], [3 + i], n)
        np.testing.assert_allclose(both["force_n"][:, i], one["force_n"][:, 0], rtol=0, atol=1e-9)
        np.testing.assert_allclose(both["current_a"][:, i], one["current_a"][:, 0], atol=1e-12)


def test_controller_act_shapes_and_errors():
    env = gym.make(ID_05, max_episode_steps=10, preview_steps=20)
    ctx = ControllerContext.from_env(env)
    obs, _ = env.reset(seed=0)
    pid = _pid(ctx)
    assert pid.act(obs).shape == (1,)
    assert pid.act(np.stack([obs, obs, obs])).shape == (3,)
    with pytest.raises(ValueError, match=r"observation has shape \(7,\), expected \(n, 25\)"):
        pid.act(obs[:7])
    with pytest.raises(ValueError, match="reference_lead_s = 0.05 needs 51 preview steps"):
        _pid(ctx, reference_lead_s=0.05)
    with pytest.raises(ValueError, match="kp_a_per_n = -1.0 is not allowed"):
        _pid(ctx, kp_a_per_n=-1.0)


def test_normalised_observation_gives_the_same_current():
    """A classical controller acts the same on the normalised and on the SI observation."""
    cur = []
    for normalize in (False, True):
        env = gym.make(
            ID_05, max_episode_steps=50, preview_steps=20, normalize_observation=normalize
        )
        ctrl = _pid(ControllerContext.from_env(env))
        obs, _ = env.reset(seed=7)
        out = []
        for _ in range(50):
            a = ctrl.act(obs)
            out.append(a[0])
            obs, *_ = env.step(a)
        cur.append(out)
    np.testing.assert_allclose(cur[0], cur[1], rtol=1e-5, atol=1e-6)


def test_pid_back_calculation_bounds_the_integrator():
    """An unreachable reference winds the integrator up only without anti-windup."""
    n = 300
    integrals = {}
    for tt in (0.02, 1e9):
        env = make_env("Numatics-0.5m", 1, n, preview_steps=20)
        ctrl = _pid(ControllerContext.from_env(env), antiwindup_tracking_s=tt)
        closed_loop(env, ctrl, [{"kind": "step", "amplitude": 2.0}], [0], n)
        integrals[tt] = abs(float(ctrl.integral[0]))
    _, i_full = valve_currents(load_parameters("numatics"))
    # with back-calculation: the saturation plus ki * e * T_t (about 0.2 A here)
    assert integrals[0.02] < i_full + 0.5
    # without: ki * e * t grows past 3 A in 0.3 s
    assert integrals[1e9] > 3.0


def test_zero_controller_keeps_the_valve_closed():
    env = make_env("Airpel-2m", 1, 100, preview_steps=20)
    tr = closed_loop(
        env,
        ZeroController(ControllerContext.from_env(env)),
        [{"kind": "sine", "amplitude": 0.3, "frequency_hz": 5.0}],
        [0],
        100,
    )
    assert np.all(tr["current_a"] == 0) and np.all(np.abs(tr["force_n"]) < 1e-6)


# --------------------------------------------------------------------------- sliding mode model


def test_force_rate_matches_choked_flow_by_hand():
    """Valve fully open, both chambers at ambient: Fdot from Eqs. 14, 30, 39 (choked) by hand."""
    p = load_parameters("numatics", tube_length_m=2.0, piston_mode="fixed")
    m = model_constants(p)
    pa, ps, T, R = (
        p["ambient_pressure_pa"],
        p["supply_pressure_pa"],
        p["temperature_k"],
        p["gas_constant_j_per_kg_k"],
    )
    rh, nh = p["hole_radius_m"], p["holes_per_path"]
    a_open = nh * math.pi * rh**2  # Eq. 44 past full opening
    c1 = 0.040418  # paper, Eq. 40
    mdot = p["discharge_coefficient"] * a_open * ps / math.sqrt(T) * c1  # Eq. 39, choked
    mu, d = p["air_viscosity_pa_s"], p["tube_inner_diameter_m"]
    re = 4 * mdot / (math.pi * d * mu)
    assert re > 2300  # turbulent: Eq. 35
    r_t = 0.158 * mu * re**0.75 / d**2
    tau = p["tube_length_m"] / math.sqrt(1.4 * R * T)
    phi = math.exp(-r_t * R * T * tau / (2 * pa))  # Eq. 30 at the chamber end (P1 = Pa)
    a1 = math.pi * p["bore_diameter_m"] ** 2 / 4
    v1 = p["dead_volume_cap_m3"] + a1 * p["stroke_m"] / 2  # mid-stroke, Eq. 15
    expected = a1 * R * T / v1 * p["alpha_in"] * mdot * phi  # Eq. 14, dV = 0; chamber 2 idle
    got = force_rate(m, pa, pa, 0.0, p["spool_half_width_m"] + rh + 1e-4)
    assert got == pytest.approx(expected, rel=2e-3)
    # closed inside the overlap; the mirror spool fills chamber 2 (negative force rate)
    assert force_rate(m, pa, pa, 0.0, 0.5 * (p["spool_half_width_m"] - rh)) == 0.0
    assert force_rate(m, pa, pa, 0.0, -(p["spool_half_width_m"] + rh)) < 0.0


def test_inversion_hits_the_wanted_force_rate():
    p = load_parameters("airpel", tube_length_m=0.5, piston_mode="fixed")
    m = model_constants(p)
    n = 6
    p1 = np.array([2e5, 3e5, 4e5, 2e5, 3e5, 5e5])
    p2 = np.array([3e5, 2e5, 4e5, 5e5, 3e5, 2e5])
    want = np.array([3000.0, -3000.0, 1000.0, 8000.0, -6000.0, -500.0])
    spool, rate = np.empty(n), np.empty(n)
    invert_force_rate(
        m, p1, p2, np.zeros(n), want, np.linspace(0, 2 * p["hole_radius_m"], 25), 200.0, spool, rate
    )
    np.testing.assert_allclose(rate, want, rtol=0.03)
    assert np.all(np.sign(spool) == np.sign(want))
    for i in range(n):  # the reported rate is the model's at the returned spool position
        assert rate[i] == pytest.approx(force_rate(m, p1[i], p2[i], 0.0, spool[i]), rel=1e-12)


# --------------------------------------------------------------------------- configs


def test_agent_config_refuses_bare_numbers(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text("controller: pid\ngains:\n  kp_a_per_n: 0.01\n")
    with pytest.raises(ConfigError, match=r"gains\.kp_a_per_n = 0\.01 is not allowed"):
        load_agent_config(path)
    path.write_text("gains:\n  kp_a_per_n: {value: 0.01, unit: A/N}\n")
    with pytest.raises(ConfigError, match="missing 'source'"):
        load_agent_config(path)


def test_shipped_controller_configs_load():
    for variant in ("Numatics-0.5m", "Numatics-2m", "Airpel-0.5m", "Airpel-2m"):
        for name in ("pid", "sliding_mode"):
            spec = resolve_controller(name, variant)
            assert spec.source.endswith(f"{name}-{variant.lower()}.yaml")


# --------------------------------------------------------------------------- SB3 adapter


def _adapter(n, steps, **kw):
    from pneumatic_env.agents.sb3 import make_sb3_vec_env

    return make_sb3_vec_env(ID_05, n, episode_steps=steps, **kw)


def test_adapter_rollout_equals_dummy_vec_env():
    """Same seeds and actions: the adapter and SB3's DummyVecEnv over single envs agree."""
    from stable_baselines3.common.vec_env import DummyVecEnv

    n, T = 3, 7
    a = _adapter(n, T, normalize_action=False)
    d = DummyVecEnv([lambda: gym.make(ID_05, max_episode_steps=T) for _ in range(n)])
    a.seed(5)
    d.seed(5)
    np.testing.assert_array_equal(a.reset(), d.reset())
    rng = np.random.default_rng(0)
    n_done = 0
    for _ in range(3 * T):
        act = rng.uniform(-1.5, 1.5, (n, 1)).astype(np.float32)
        oa, ra, da, ia = a.step(act)
        od, rd, dd, id_ = d.step(act)
        np.testing.assert_allclose(oa, od, rtol=1e-6)
        np.testing.assert_allclose(ra, rd, rtol=1e-6)
        np.testing.assert_array_equal(da, dd)
        for i in range(n):
            assert set(ia[i]) == set(id_[i])
            assert ia[i]["TimeLimit.truncated"] == id_[i]["TimeLimit.truncated"]
            if da[i]:
                n_done += 1
                np.testing.assert_allclose(
                    ia[i]["terminal_observation"], id_[i]["terminal_observation"], rtol=1e-6
                )
    assert n_done == 3 * n  # three episodes of T steps per env, all truncated


def test_adapter_action_repeat_holds_the_action_and_sums_the_reward():
    """action_repeat = 3 against single envs stepped three times with the same action."""
    from stable_baselines3.common.vec_env import DummyVecEnv

    n, T, k = 2, 9, 3
    a = _adapter(n, T, normalize_action=False, action_repeat=k)
    d = DummyVecEnv([lambda: gym.make(ID_05, max_episode_steps=T) for _ in range(n)])
    a.seed(7)
    d.seed(7)
    np.testing.assert_array_equal(a.reset(), d.reset())
    rng = np.random.default_rng(3)
    for step in range(2 * T // k):
        act = rng.uniform(-1.5, 1.5, (n, 1)).astype(np.float32)
        oa, ra, da, ia = a.step(act)
        total = np.zeros(n)
        for _ in range(k):
            od, rd, dd, id_ = d.step(act)
            total += rd
        np.testing.assert_allclose(oa, od, rtol=1e-6)
        np.testing.assert_allclose(ra, total, rtol=1e-5)
        np.testing.assert_array_equal(da, dd)
        assert da.all() == ((step + 1) % (T // k) == 0)
        for i in np.flatnonzero(da):
            assert ia[i]["TimeLimit.truncated"] is True
            np.testing.assert_allclose(
                ia[i]["terminal_observation"], id_[i]["terminal_observation"], rtol=1e-6
            )
    assert a.env_steps == 2 * T * n


def test_adapter_action_repeat_errors():
    with pytest.raises(ValueError, match=r"episode_steps = 10 .* action_repeat = 3"):
        _adapter(1, 10, action_repeat=3)
    with pytest.raises(ValueError, match=r"action_repeat = 0 is not allowed: an integer >= 1"):
        _adapter(1, 10, action_repeat=0)


def test_adapter_spaces_shapes_and_action_scaling():
    a = _adapter(4, 5)
    assert a.action_space.low.tolist() == [-1.0] and a.action_space.high.tolist() == [1.0]
    obs = a.reset()
    assert obs.shape == (4, a.observation_space.shape[0]) and obs.dtype == np.float32
    obs, rew, done, infos = a.step(np.array([[1.0], [-0.5], [0.0], [3.0]], dtype=np.float32))
    assert rew.shape == (4,) and rew.dtype == np.float32 and done.dtype == bool
    assert len(infos) == 4
    i_max = a.venv.unwrapped.coil_current_max_a
    np.testing.assert_allclose(
        [inf["coil_current_a"] for inf in infos], [i_max, -0.5 * i_max, 0.0, i_max]
    )  # 3.0 is clipped to 1
    assert a.get_attr("render_mode") == [None] * 4
    assert a.env_is_wrapped(gym.Wrapper) == [False] * 4


def test_adapter_seeding():
    a, b = _adapter(2, 50), _adapter(2, 50)
    a.seed(11)
    b.seed(11)
    np.testing.assert_array_equal(a.reset(), b.reset())
    b.seed(12)
    assert not np.array_equal(a.reset(), b.reset())
    # env i gets seed + i, like the single env
    a.seed(11)
    single = gym.make(ID_05, max_episode_steps=50)
    np.testing.assert_array_equal(a.reset()[1], single.reset(seed=12)[0])


def test_adapter_refuses_next_step_autoreset():
    from pneumatic_env.agents.sb3 import SB3VecEnv

    venv = gym.vector.SyncVectorEnv([lambda: gym.make(ID_05, max_episode_steps=5)])
    with pytest.raises(ValueError, match="autoreset_mode = SAME_STEP"):
        SB3VecEnv(venv)


def test_sb3_check_env_on_single_env():
    from stable_baselines3.common.env_checker import check_env

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # unbounded observations, [-2, 2] A action box
        check_env(gym.make(ID_05, max_episode_steps=20, normalize_observation=True))


# --------------------------------------------------------------------------- learning


@pytest.fixture(scope="module")
def ppo_run(tmp_path_factory):
    """A few thousand PPO steps on 0.1 s episodes holding half the force scale."""
    from pneumatic_env.agents.train import train

    cfg = copy.deepcopy(load_agent_config("ppo-numatics-2m"))
    scale = force_scale(load_parameters("numatics", tube_length_m=0.5))
    cfg.update(
        n_envs=8,
        episode_steps=100,
        env_kwargs={
            "normalize_observation": True,
            "preview_steps": 5,
            "reference": {"kind": "step", "amplitude": 0.5 * scale},
        },
    )
    cfg["hyperparameters"].update(n_steps=64, batch_size=128, n_epochs=5, learning_rate=1e-3)
    out = tmp_path_factory.mktemp("ppo")
    summary = train(
        "ppo",
        ID_05,
        cfg,
        timesteps=4096,
        seed=0,
        out=out,
        progress_bar=False,
        eval_seeds=(1, 2, 3, 4),
    )
    return out, summary


def test_ppo_smoke_beats_zero_current(ppo_run):
    out, s = ppo_run
    # zero current: |e| = half the scale on every step of the 100-step episode
    assert s["eval_return_zero_current"] == pytest.approx(-50.0, abs=1e-6)
    assert s["eval_return_mean"] > -40.0
    for name in ("model.zip", "model.npz", "train.json", "progress.csv"):
        assert (out / name).is_file(), name
    assert any(p.name.startswith("events.out.tfevents") for p in out.rglob("*"))


def test_exported_ppo_policy_matches_sb3_predict(ppo_run):
    from stable_baselines3 import PPO

    from pneumatic_env.agents.policy import NumpyPolicy

    out, _ = ppo_run
    model = PPO.load(out / "model.zip", device="cpu")
    policy = NumpyPolicy(out / "model.npz")
    obs = np.random.default_rng(0).normal(size=(32, policy.obs_dim)).astype(np.float32)
    expected, _ = model.predict(obs, deterministic=True)
    np.testing.assert_allclose(policy.normalized_action(obs), expected, atol=1e-5)
    np.testing.assert_allclose(policy(obs), expected * 2.0, atol=2e-5)


def test_exported_sac_policy_matches_sb3_predict(tmp_path):
    from stable_baselines3 import SAC

    from pneumatic_env.agents.policy import NumpyPolicy, export_policy

    env = _adapter(2, 20, normalize_observation=True)
    model = SAC(
        "MlpPolicy",
        env,
        seed=1,
        device="cpu",
        learning_starts=10,
        policy_kwargs={"net_arch": [16, 16]},
    )
    path = export_policy(
        model,
        tmp_path / "sac.npz",
        env_id=ID_05,
        preview_steps=10,
        normalize_observation=True,
        action_scale_a=2.0,
    )
    policy = NumpyPolicy(path)
    obs = np.random.default_rng(1).normal(size=(16, policy.obs_dim)).astype(np.float32)
    expected, _ = model.predict(obs, deterministic=True)
    np.testing.assert_allclose(policy.normalized_action(obs), expected, atol=1e-5)


def test_policy_controller_holds_a_repeated_action(tmp_path):
    """A policy exported with action_repeat = 4 decides every 4th period and holds it."""
    from stable_baselines3 import SAC

    from pneumatic_env.agents.base import ControllerContext
    from pneumatic_env.agents.policy import NumpyPolicy, PolicyController, export_policy

    env = _adapter(1, 20, normalize_observation=True)
    model = SAC("MlpPolicy", env, seed=2, device="cpu", policy_kwargs={"net_arch": [8]})
    ctx = ControllerContext.from_env(gym.make(ID_05, normalize_observation=True).unwrapped)
    path = export_policy(
        model,
        tmp_path / "sac.npz",
        env_id=ID_05,
        preview_steps=ctx.preview_steps,
        normalize_observation=True,
        action_scale_a=2.0,
        extra={"action_repeat": 4},
    )
    policy = NumpyPolicy(path)
    ctrl = PolicyController(ctx, policy)
    rng = np.random.default_rng(4)
    obs = rng.normal(size=(10, 3, policy.obs_dim))
    out = np.array([ctrl.act(o) for o in obs])
    for t in range(10):
        decided = 4 * (t // 4)
        np.testing.assert_allclose(out[t], policy(obs[decided])[:, 0], rtol=1e-12)
    ctrl.reset([1])  # a reset env decides at once
    after = ctrl.act(obs[0])
    np.testing.assert_allclose(after[1], policy(obs[0][1:2])[0, 0], rtol=1e-12)
    np.testing.assert_allclose(after[[0, 2]], out[9][[0, 2]], rtol=1e-12)
    bad = tmp_path / "bad.npz"
    export_policy(
        model,
        bad,
        env_id=ID_05,
        preview_steps=ctx.preview_steps,
        normalize_observation=True,
        action_scale_a=2.0,
        extra={"action_repeat": 1.5},
    )
    with pytest.raises(ValueError, match=r"action_repeat = 1.5 is not allowed"):
        NumpyPolicy(bad)
