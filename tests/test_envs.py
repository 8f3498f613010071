"""Acceptance tests of the Gymnasium environments (pneumatic_env/envs).

Single env (gym.make) and native vector env (gym.make_vec) of every registered id:
Gymnasium's env checker, exact single/vector equality through same-step autoreset,
seeding, action and keyword validation, parameter overrides, rendering, reward bounds.
"""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest

import pneumatic_env
from conftest import areas, assert_check_env_passes
from pneumatic_env.params import ConfigError, load_parameters, save_parameters
from pneumatic_env.physics import layout as L

FORCE_ID = "pneumatic_env/ForceTrack-Numatics-0.5m-v0"
POSITION_ID = "pneumatic_env/PositionTrack-Airpel-2m-v0"
EPISODE = 50  # short episodes so a few hundred steps cross several truncations
SHORT = dict(max_episode_steps=EPISODE)
RANDOMIZED = dict(
    domain_randomization={
        "supply_pressure_pa": 0.2,
        "tube_length_m": (0.5, 3.0),
        "dynamic_friction_n": 0.5,
    },
    sensor_noise={"p1": 1000.0, "p2": 1000.0, "x": 1e-4, "f": 0.5},
    sensor_lag_s=2e-3,
)


def _actions(n_steps, shape, seed=0, low=-2.5, high=2.5):
    """Random currents, some beyond the +-2 A range (they must be clipped)."""
    return (
        np.random.default_rng(seed).uniform(low, high, size=(n_steps,) + shape).astype(np.float32)
    )


# --------------------------------------------------------------------------- env checker


@pytest.mark.parametrize("env_id", pneumatic_env.registered_ids())
def test_check_env_passes(env_id):
    env = gym.make(env_id)
    assert_check_env_passes(env)
    env.close()


def test_registered_ids_cover_tasks_cylinders_tubes():
    ids = pneumatic_env.registered_ids()
    assert len(ids) == len(set(ids)) == 2 * 2 * 4
    for env_id in ids:
        spec = gym.spec(env_id)
        assert spec.vector_entry_point is not None
        env = gym.make(env_id)
        base = env.unwrapped.base_params
        assert base["tube_length_m"] == spec.kwargs["tube_length_m"]
        assert base["piston_mode"] == (0.0 if "ForceTrack" in env_id else 1.0)
        env.close()


# --------------------------------------------------------------------------- single == vector


@pytest.mark.parametrize("env_id", [FORCE_ID, POSITION_ID])
@pytest.mark.parametrize("extra", [{}, RANDOMIZED], ids=["plain", "randomized-noisy"])
def test_vector_env_equals_single_envs(env_id, extra):
    """make_vec(num_envs=4) seeded s == four gym.make envs seeded s + i, through two
    truncations with same-step autoreset (final_obs holds the last observation)."""
    n, seed, n_steps = 4, 11, 2 * EPISODE + 10
    venv = gym.make_vec(env_id, num_envs=n, **SHORT, **extra)
    envs = [gym.make(env_id, **SHORT, **extra) for _ in range(n)]
    vobs, _ = venv.reset(seed=seed)
    obs = np.stack([e.reset(seed=seed + i)[0] for i, e in enumerate(envs)])
    assert np.array_equal(vobs, obs)
    truncations = 0
    for action in _actions(n_steps, (n, 1)):
        vobs, vrew, vterm, vtrunc, vinfo = venv.step(action)
        for i, env in enumerate(envs):
            o, r, term, trunc, info = env.step(action[i])
            assert r == vrew[i]
            assert (term, trunc) == (bool(vterm[i]), bool(vtrunc[i]))
            assert info["tracking_error"] == vinfo["tracking_error"][i]
            assert info["action_clipped"] == vinfo["action_clipped"][i]
            if trunc or term:
                truncations += 1
                assert vinfo["_final_obs"][i]
                assert np.array_equal(vinfo["final_obs"][i], o)
                o, _ = env.reset()
            assert np.array_equal(vobs[i], o)
    assert truncations == 2 * n
    venv.close()


def test_parallel_task_kernel_equals_the_serial_one(numba_threads):
    """The threaded task step and observation (chosen for N >= simulator.PARALLEL_MIN_ENVS
    on more than one thread) give the serial ones' observations, rewards and infos bit for
    bit, through a truncation."""
    n, seed = 6, 3
    serial = gym.make_vec(FORCE_ID, num_envs=n, **SHORT, **RANDOMIZED)
    threaded = gym.make_vec(FORCE_ID, num_envs=n, **SHORT, **RANDOMIZED)
    threaded.unwrapped.core.sim.parallel = True
    assert not serial.unwrapped.core.sim.parallel
    assert np.array_equal(serial.reset(seed=seed)[0], threaded.reset(seed=seed)[0])
    for action in _actions(EPISODE + 5, (n, 1)):
        one, many = serial.step(action), threaded.step(action)
        for a, b in zip(one[:4], many[:4]):
            assert np.array_equal(a, b)
        assert np.array_equal(one[4]["tracking_error"], many[4]["tracking_error"])
        # the observation the task step fills is the one TaskCore.observation builds
        assert np.array_equal(many[0], threaded.unwrapped.core.observation())
    serial.close()
    threaded.close()


def test_vector_env_equals_single_envs_given_only_max_episode_steps():
    venv = gym.make_vec(FORCE_ID, num_envs=2, max_episode_steps=EPISODE)
    envs = [gym.make(FORCE_ID, max_episode_steps=EPISODE) for _ in range(2)]
    vobs, _ = venv.reset(seed=3)
    assert np.array_equal(vobs, np.stack([e.reset(seed=3 + i)[0] for i, e in enumerate(envs)]))


def test_vector_env_references_over_several_blocks_are_the_single_envs():
    """An autoreset generates references in blocks (tasks.REFERENCE_BLOCK_ENVS); across
    blocks, at reset and after a partial autoreset, env i's reference is the single env's
    with seed 11 + i."""
    from pneumatic_env.envs.tasks import REFERENCE_BLOCK_ENVS

    n = 2 * REFERENCE_BLOCK_ENVS + 3
    venv = gym.make_vec(FORCE_ID, num_envs=n, max_episode_steps=3)
    venv.reset(seed=11)
    core = venv.unwrapped.core
    single = gym.make(FORCE_ID)
    sampled = [0, REFERENCE_BLOCK_ENVS - 1, REFERENCE_BLOCK_ENVS, n - 1]
    for env in sampled:
        single.reset(seed=11 + env)
        assert np.array_equal(venv.unwrapped.references[env], single.unwrapped.references)
    core.step_count[0::2] = 2  # only the even envs end their episode in the next step
    before = core.references.copy()
    _, _, _, truncated, _ = venv.step(np.zeros((n, 1), np.float32))
    assert np.array_equal(truncated, np.arange(n) % 2 == 0)
    assert np.array_equal(core.references[1::2], before[1::2])
    for env in sampled:  # the second episode of the even envs
        single.reset(seed=11 + env)
        if env % 2 == 0:
            single.reset()
        assert np.array_equal(venv.unwrapped.references[env], single.unwrapped.references)
    venv.close()


# --------------------------------------------------------------------------- seeding


@pytest.mark.parametrize("env_id", [FORCE_ID, POSITION_ID])
def test_same_seed_same_episode(env_id):
    runs = []
    for _ in range(2):
        env = gym.make(env_id, **RANDOMIZED)
        obs = [env.reset(seed=5)[0]]
        rewards = []
        for a in _actions(200, (1,), seed=3):
            o, r, *_ = env.step(a)
            obs.append(o)
            rewards.append(r)
        runs.append((np.array(obs), np.array(rewards)))
    assert np.array_equal(runs[0][0], runs[1][0])
    assert np.array_equal(runs[0][1], runs[1][1])


def _references(env_id, seeds):
    env = gym.make(env_id, **SHORT)
    out = []
    for s in seeds:
        env.reset(seed=s)
        out.append(env.unwrapped.references.copy())
    return out


@pytest.mark.parametrize("env_id", [FORCE_ID, POSITION_ID])
def test_seeds_change_the_reference(env_id):
    refs = _references(env_id, range(10))
    distinct = {r.tobytes() for r in refs}
    assert len(distinct) >= 3


@pytest.mark.parametrize("env_id", [FORCE_ID, POSITION_ID])
def test_different_seeds_give_different_references(env_id):
    refs = _references(env_id, range(10))
    assert len({r.tobytes() for r in refs}) == len(refs)


# --------------------------------------------------------------------------- actions


def test_bad_actions_single_env():
    env = gym.make(FORCE_ID)
    env.reset(seed=0)
    for bad, shown in ((np.nan, "nan"), (np.inf, "inf"), (-np.inf, "-inf")):
        with pytest.raises(ValueError) as err:
            env.step(np.array([bad], dtype=np.float32))
        assert str(err.value) == (
            f"action contains {shown}: the coil current must be finite, in [-2.0, 2.0] A"
        )
    with pytest.raises(ValueError) as err:
        env.step(np.zeros(2, dtype=np.float32))
    assert str(err.value) == (
        "action has shape (2,), expected (1, 1) or (1,): one coil current (A) per environment"
    )


def test_bad_actions_vector_env():
    venv = gym.make_vec(FORCE_ID, num_envs=3)
    venv.reset(seed=0)
    with pytest.raises(ValueError) as err:
        venv.step(np.zeros((3, 2), dtype=np.float32))
    assert str(err.value) == (
        "action has shape (3, 2), expected (3, 1) or (3,): one coil current (A) per environment"
    )
    with pytest.raises(ValueError) as err:
        venv.step(np.array([[0.1], [np.nan], [0.0]], dtype=np.float32))
    assert str(err.value) == (
        "action contains nan: the coil current must be finite, in [-2.0, 2.0] A"
    )


def test_out_of_range_actions_are_clipped_and_reported():
    clipped, exact = gym.make(FORCE_ID), gym.make(FORCE_ID)
    clipped.reset(seed=1)
    exact.reset(seed=1)
    for over, limit in ((5.0, 2.0), (-3.0, -2.0), (2.0, 2.0), (0.3, 0.3)):
        o1, r1, _, _, info1 = clipped.step(np.array([over], dtype=np.float32))
        o2, r2, _, _, info2 = exact.step(np.array([limit], dtype=np.float32))
        assert np.array_equal(o1, o2) and r1 == r2
        assert info1["action_clipped"] == (over != limit)
        assert not info2["action_clipped"]
        assert info1["coil_current_a"] == float(np.float32(limit))
    venv = gym.make_vec(FORCE_ID, num_envs=3)
    venv.reset(seed=0)
    *_, info = venv.step(np.array([[2.5], [-1.0], [-9.0]], dtype=np.float32))
    assert info["action_clipped"].tolist() == [True, False, True]
    assert info["coil_current_a"].tolist() == [2.0, -1.0, -2.0]


# --------------------------------------------------------------------------- keyword validation


@pytest.mark.parametrize(
    "make", [gym.make, lambda i, **kw: gym.make_vec(i, num_envs=2, **kw)], ids=["single", "vector"]
)
def test_bad_keyword_arguments(make):
    with pytest.raises(ConfigError) as err:
        make(FORCE_ID, supply_presure_pa=5e5)
    assert str(err.value) == (
        "override 'supply_presure_pa' is not a known parameter; did you mean 'supply_pressure_pa'?"
    )
    with pytest.raises(
        ConfigError,
        match=r"^override 'supply_pressure_pa' = -1\.0 is not "
        r"allowed: must be in ",
    ):
        make(FORCE_ID, supply_pressure_pa=-1.0)
    with pytest.raises(ValueError) as err:
        make(FORCE_ID, reference_steps=0)
    assert str(err.value) == "reference_steps = 0 is not allowed: must be an integer >= 1"
    with pytest.raises(ValueError) as err:
        make(FORCE_ID, sensor_noise={"q": 1.0})
    assert str(err.value) == (
        "sensor_noise key = 'q' is not allowed: must be one of ['p1', 'p2', 'x', 'f']"
    )
    with pytest.raises(ValueError) as err:
        make(FORCE_ID, sensor_noise={"f": -1.0})
    assert str(err.value) == (
        "sensor_noise['f'] = -1.0 is not allowed: must be a finite number >= 0"
    )
    with pytest.raises(ValueError) as err:
        make(FORCE_ID, effort_weight=np.nan)
    assert str(err.value) == "effort_weight = nan is not allowed: must be a finite number >= 0"
    with pytest.raises(ValueError) as err:
        make(FORCE_ID, task="Balance")
    assert str(err.value) == (
        "task = 'Balance' is not known: allowed ['ForceTrack', 'PositionTrack']"
    )
    with pytest.raises(
        ValueError,
        match=r"^domain_randomization\['supply_pressure_pa'\] = 1\.5 "
        r"is not allowed: ",
    ):
        make(FORCE_ID, domain_randomization={"supply_pressure_pa": 1.5})


def test_bad_max_episode_steps_vector_env():
    with pytest.raises(ValueError) as err:
        gym.make_vec(FORCE_ID, num_envs=2, max_episode_steps=0)
    assert str(err.value) == "max_episode_steps = 0 is not allowed: must be an integer >= 1"


def test_bad_render_mode_single_env():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # gym.make's own warning about the unknown mode
        with pytest.raises(ValueError) as err:
            gym.make(FORCE_ID, render_mode="bogus")
    assert str(err.value) == "render_mode = 'bogus' is not allowed: use 'rgb_array' or None"


def test_bad_render_mode_vector_env():
    with pytest.raises(ValueError, match=r"^render_mode = 'bogus' is not allowed"):
        gym.make_vec(FORCE_ID, num_envs=2, render_mode="bogus")


# --------------------------------------------------------------------------- parameters


def _steady_force(env, n_steps=300, current=1.0):
    env.reset(seed=0)
    for _ in range(n_steps):
        obs, *_ = env.step(np.array([current], dtype=np.float32))
    return float(obs[3])


def _clamped_steady_force(param):
    """Rod clamped, valve open: P1 = P_s, P2 = P_a, so F = P_s A1 - P_a A2 - P_a A_r."""
    a1, _, _ = areas(param)
    return (param["supply_pressure_pa"] - param["ambient_pressure_pa"]) * a1


def test_parameter_override_changes_the_steady_force():
    default = _steady_force(gym.make(FORCE_ID))
    lowered = _steady_force(gym.make(FORCE_ID, supply_pressure_pa=5e5))
    assert default == pytest.approx(_clamped_steady_force(load_parameters()), rel=1e-3)
    assert lowered == pytest.approx(
        _clamped_steady_force(load_parameters(supply_pressure_pa=5e5)), rel=1e-3
    )


def test_params_file_from_save_parameters(tmp_path):
    path = tmp_path / "fitted.yaml"
    save_parameters(
        path, {"supply_pressure_pa": 5.0e5, "dynamic_friction_n": 0.6}, notes="test fit"
    )
    env = gym.make(FORCE_ID, params=str(path))
    base = env.unwrapped.base_params
    assert base["supply_pressure_pa"] == 5.0e5 and base["dynamic_friction_n"] == 0.6
    assert base["tube_length_m"] == 0.5 and base["piston_mode"] == 0.0  # the id's own settings
    force = _steady_force(env)
    assert force == pytest.approx(
        _steady_force(gym.make(FORCE_ID, supply_pressure_pa=5e5)), rel=1e-12
    )
    assert force == pytest.approx(_clamped_steady_force(base), rel=1e-3)


# --------------------------------------------------------------------------- rendering


def test_render_rgb_array_changes_with_the_state():
    env = gym.make(FORCE_ID, render_mode="rgb_array")
    env.reset(seed=0)
    first = env.render()
    assert first.ndim == 3 and first.shape[2] == 3 and first.dtype == np.uint8
    for _ in range(50):
        env.step(np.array([2.0], dtype=np.float32))
    second = env.render()
    assert second.shape == first.shape and second.dtype == np.uint8
    assert not np.array_equal(first, second)
    env.close()


# --------------------------------------------------------------------------- reward, observation


@pytest.mark.parametrize("env_id", [FORCE_ID, POSITION_ID])
def test_reward_formula_and_bounds(env_id):
    w_effort, w_chatter = 0.3, 0.2
    env = gym.make(env_id, effort_weight=w_effort, chatter_weight=w_chatter)
    env.reset(seed=2)
    e = env.unwrapped
    i_max, scale, base = e.coil_current_max_a, e.reference_scale, e.base_params
    span = base["supply_pressure_pa"] - base["ambient_pressure_pa"]
    if "ForceTrack" in env_id:  # a force both chambers can hold: (P_s - P_a) A2
        a1, a2, _ = areas(base)
        assert scale == pytest.approx(span * min(a1, a2), rel=1e-12)
    else:
        assert scale == pytest.approx(0.5 * base["stroke_m"], rel=1e-12)
    previous, rewards = 0.0, []
    for a in _actions(400, (1,), seed=4, low=-3.0, high=3.0):
        _, r, _, _, info = env.step(a)
        applied = info["coil_current_a"]
        expected = (
            -min(abs(info["tracking_error"]) / scale, 1.0)
            - w_effort * (applied / i_max) ** 2
            - w_chatter * ((applied - previous) / (2 * i_max)) ** 2
        )
        assert r == pytest.approx(expected, rel=1e-9, abs=1e-12)
        previous = applied
        rewards.append(r)
    rewards = np.array(rewards)
    assert np.all(rewards <= 0.0) and np.all(rewards >= -1.0 - w_effort - w_chatter)
    assert rewards.min() < -0.5  # the bound is not trivially met


@pytest.mark.parametrize(
    "env_id",
    [
        FORCE_ID,
        POSITION_ID,
    ],
)
def test_normalized_observation(env_id):
    """normalize_observation=True: O(1) values, the SI observation mapped by
    (p - P_a)/(P_s - P_a), x/(L/2), f/((P_s - P_a) min(A1, A2)), ref/scale."""
    raw_env = gym.make(env_id)
    norm_env = gym.make(env_id, normalize_observation=True)
    raw, norm = [raw_env.reset(seed=3)[0]], [norm_env.reset(seed=3)[0]]
    for a in _actions(300, (1,), seed=6):
        raw.append(raw_env.step(a)[0])
        norm.append(norm_env.step(a)[0])
    raw, norm = np.array(raw, dtype=np.float64), np.array(norm, dtype=np.float64)
    base = raw_env.unwrapped.base_params
    pa = base["ambient_pressure_pa"]
    span = base["supply_pressure_pa"] - pa
    a1, a2, _ = areas(base)
    expected = np.empty_like(raw)
    expected[:, :2] = (raw[:, :2] - pa) / span
    expected[:, 2] = raw[:, 2] / (0.5 * base["stroke_m"])
    expected[:, 3] = raw[:, 3] / (span * min(a1, a2))
    # the reference in the tracked channel's scale
    expected[:, 4:] = raw[:, 4:] / raw_env.unwrapped.reference_scale
    assert np.abs(norm).max() < 2.0
    np.testing.assert_allclose(norm, expected, rtol=1e-5, atol=1e-5)
    assert np.abs(norm).max() > 0.3  # not all near zero either
    assert np.abs(raw[:, :2]).max() > 1e5  # the raw observation is in SI units


def test_fitted_load_cell_compliance_becomes_a_force_tracking_env(tmp_path):
    """A parameter file with the rod on a spring (identification's load_cell_compliance) is a
    ForceTrack env on that spring, not silently a rigid clamp; a rod mode the task cannot
    use is refused by keyword and overridden with a warning from a file."""
    from pneumatic_env.ids import MODE_FIXED, MODE_FREE, MODE_SPRING

    path = tmp_path / "rig.yaml"
    save_parameters(
        path,
        {
            "piston_mode": 2,
            "spring_stiffness_n_per_m": 5e5,
            "spring_rest_position_m": 0.0,
            "static_friction_n": 0.0,
            "dynamic_friction_n": 0.0,
        },
        notes="fitted load cell",
    )
    env = gym.make(FORCE_ID, params=str(path))
    assert env.unwrapped.base_params["piston_mode"] == MODE_SPRING
    f = _steady_force(env)
    x = float(env.unwrapped.core.sim.outputs[L.O_X, 0])
    assert x > 0.0 and f == pytest.approx(5e5 * x, rel=1e-5)  # the cell reads k x
    # valve open, at rest: the pressures and so the force are the rigid clamp's
    assert f == pytest.approx(_steady_force(gym.make(FORCE_ID)), rel=1e-3)
    with pytest.raises(
        ValueError,
        match=r"piston_mode = 'free' is not allowed for "
        r"ForceTrack: allowed \['fixed', 'spring'\]",
    ):
        gym.make(FORCE_ID, piston_mode="free")
    with pytest.warns(UserWarning, match="does not fit PositionTrack"):
        position = gym.make(POSITION_ID, params=str(path))
    assert position.unwrapped.base_params["piston_mode"] == MODE_FREE
    silent = tmp_path / "no_rod.yaml"  # a file that says nothing of the rod: no warning
    save_parameters(silent, {"supply_pressure_pa": 5.5e5}, notes="fit")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert (
            gym.make(POSITION_ID, params=str(silent)).unwrapped.base_params["piston_mode"]
            == MODE_FREE
        )
    assert gym.make(FORCE_ID).unwrapped.base_params["piston_mode"] == MODE_FIXED


# --------------------------------------------------------------------------- reset(options)

SINE = {"kind": "sine", "amplitude": 30.0, "frequency_hz": 7.0, "offset": 5.0}
STEPS = {"kind": "random_step", "amplitude": 40.0, "hold_min_s": 0.01, "hold_max_s": 0.02}


def _rollout(env, n_steps=60, seed=0):
    out = []
    for a in _actions(n_steps, (1,), seed=seed):
        obs, r, *_ = env.step(a)
        out.append(np.append(obs, r))
    return np.array(out)


@pytest.mark.parametrize("spec", [SINE, STEPS], ids=["sine", "random_step"])
def test_reset_reference_option_is_the_reference_keyword_for_one_episode(spec):
    """reset(options={"reference": spec}) gives the episode of gym.make(reference=spec) with
    that seed (a random spec draws from the env's generator where the default would); the
    next reset without it goes back to the env's own reference."""
    given = gym.make(FORCE_ID, reference=spec)
    env = gym.make(FORCE_ID)
    own = gym.make(FORCE_ID)
    obs_given, _ = given.reset(seed=5)
    obs, _ = env.reset(seed=5, options={"reference": spec})
    assert np.array_equal(obs, obs_given)
    assert np.array_equal(env.unwrapped.references, given.unwrapped.references)
    assert np.array_equal(_rollout(env), _rollout(given))
    env.reset(seed=6)
    own.reset(seed=6)
    assert np.array_equal(env.unwrapped.references, own.unwrapped.references)
    assert not np.array_equal(env.unwrapped.references, given.unwrapped.references)


def test_reset_reference_option_takes_samples():
    env = gym.make(FORCE_ID, preview_steps=3)
    samples = np.array([0.0, 10.0, 20.0, 15.0])
    obs, _ = env.reset(seed=0, options={"reference": samples})
    refs = env.unwrapped.references
    assert np.array_equal(refs[:4], samples) and np.all(refs[4:] == 15.0)  # held at its end
    assert np.array_equal(obs[4:], samples.astype(np.float32))
    _, _, _, _, info = env.step(np.zeros(1, np.float32))
    assert info["reference"] == 10.0


def test_vector_reset_reference_option_equals_single_envs():
    """Per-env references (a spec, the env's own, samples; or one 2-D array) give env i the
    single env's episode with that reference and seed; autoresets use the env's own."""
    n_steps = EPISODE + 5
    samples = np.linspace(-20.0, 20.0, 30)
    venv = gym.make_vec(FORCE_ID, num_envs=3, **SHORT)
    vobs, _ = venv.reset(seed=[4, 5, 6], options={"reference": [STEPS, None, samples]})
    envs = [gym.make(FORCE_ID, **SHORT) for _ in range(3)]
    obs = [
        env.reset(seed=s, options=o)[0]
        for env, s, o in zip(envs, (4, 5, 6), ({"reference": STEPS}, None, {"reference": samples}))
    ]
    assert np.array_equal(vobs, np.stack(obs))
    for action in _actions(n_steps, (3, 1)):
        vobs, vrew, _, vtrunc, _ = venv.step(action)
        for i, env in enumerate(envs):
            o, r, _, trunc, _ = env.step(action[i])
            if trunc:
                o, _ = env.reset()  # the env's own reference again
            assert r == vrew[i] and np.array_equal(vobs[i], o)
    rows = np.stack([samples, -samples])
    venv2 = gym.make_vec(FORCE_ID, num_envs=2)
    venv2.reset(seed=0, options={"reference": rows})
    for i in range(2):
        env = gym.make(FORCE_ID)
        env.reset(seed=i, options={"reference": rows[i]})
        assert np.array_equal(venv2.unwrapped.references[i], env.unwrapped.references)
    venv2.reset(seed=0, options={"reference": SINE})  # one spec for every env
    assert np.array_equal(venv2.unwrapped.references[0], venv2.unwrapped.references[1])


@pytest.mark.parametrize(
    "options,field,rule",
    [
        ({"referense": SINE}, "options key = 'referense'", "must be one of ['reference']"),
        (
            {"reference": {"kind": "sine", "amplitude": 1.0}},
            "options['reference']",
            "missing key(s) ['frequency_hz']",
        ),
        ({"reference": [1.0, np.nan]}, "options['reference']", "finite samples"),
        ({"reference": "sine"}, "options['reference']", "reference spec"),
        ([("reference", SINE)], "options", "a dict with keys from ['reference']"),
    ],
)
def test_reset_options_errors_single_env(options, field, rule):
    env = gym.make(FORCE_ID)
    with pytest.raises(ValueError) as err:
        env.reset(seed=0, options=options)
    message = str(err.value)
    assert message.startswith(field) and "is not allowed" in message and rule in message


@pytest.mark.parametrize(
    "reference,field,rule",
    [
        ([SINE, SINE, SINE], "options['reference'] (3 entries)", "num_envs = 2"),
        (np.zeros(5), "options['reference'] (shape (5,))", "a 2-D array (2, n_samples)"),
        (np.zeros((3, 5)), "options['reference'] (shape (3, 5))", "num_envs = 2"),
        ([SINE, {"kind": "wave"}], "options['reference'][1]", "unknown reference kind 'wave'"),
        ([None, [0.0, np.inf]], "options['reference'][1]", "finite samples"),
    ],
)
def test_reset_options_errors_vector_env(reference, field, rule):
    venv = gym.make_vec(FORCE_ID, num_envs=2)
    venv.reset(seed=1)
    before = venv.unwrapped.references.copy()
    with pytest.raises(ValueError) as err:
        venv.reset(seed=2, options={"reference": reference})
    message = str(err.value)
    assert message.startswith(field) and "is not allowed" in message and rule in message
    assert np.array_equal(venv.unwrapped.references, before)  # nothing was reset


# --------------------------------------------------------------------------- properties


@pytest.mark.parametrize(
    "make", [gym.make, lambda i, **kw: gym.make_vec(i, num_envs=3, **kw)], ids=["single", "vector"]
)
@pytest.mark.parametrize("env_id", [FORCE_ID, POSITION_ID])
def test_env_properties_are_the_task_core_values(make, env_id):
    env = make(env_id, preview_steps=7, normalize_observation=True, supply_pressure_pa=6e5)
    env.reset(seed=1)
    e, core = env.unwrapped, env.unwrapped.core
    assert dict(e.base_params) == core.base_params
    assert e.base_params["supply_pressure_pa"] == 6e5
    assert e.control_dt_s == core.dt == 1e-3
    assert e.coil_current_max_a == core.i_max
    assert e.force_scale_n == core.force_scale
    assert e.reference_scale == core.scale
    assert e.reference_scale == (
        core.force_scale if "Force" in env_id else 0.5 * core.base_params["stroke_m"]
    )
    assert e.preview_steps == 7 and e.normalize_observation is True
    assert e.task is core.task and e.reference_spec is core.reference_spec
    assert e.observation_scales.supply_pa == 6e5
    refs = e.references
    assert np.array_equal(refs, core.references[0] if refs.ndim == 1 else core.references)
    with pytest.raises(TypeError):
        e.base_params["supply_pressure_pa"] = 1.0
    with pytest.raises(ValueError, match="read-only"):
        refs[0] = 1.0
    with pytest.raises(AttributeError):
        e.control_dt_s = 2e-3


def test_controller_inverts_the_env_normalisation():
    """Controller.observation_si undoes normalize_observation (one definition of the scales)."""
    from pneumatic_env.agents.base import ControllerContext, ZeroController

    raw_env, norm_env = gym.make(FORCE_ID), gym.make(FORCE_ID, normalize_observation=True)
    raw, norm = [raw_env.reset(seed=2)[0]], [norm_env.reset(seed=2)[0]]
    for a in _actions(100, (1,), seed=1):
        raw.append(raw_env.step(a)[0])
        norm.append(norm_env.step(a)[0])
    ctrl = ZeroController(ControllerContext.from_env(norm_env))
    si = ctrl.observation_si(np.array(norm, dtype=np.float64))
    np.testing.assert_allclose(si, np.array(raw, dtype=np.float64), rtol=1e-6, atol=1e-9)


# --------------------------------------------------------------------------- ids, public API


def test_env_id_and_parse_env_id_round_trip():
    from pneumatic_env.ids import EnvId, env_id, parse_env_id

    for name in pneumatic_env.registered_ids():
        parts = parse_env_id(name)
        assert env_id(*parts) == parts.id == name
        spec = gym.spec(name)
        assert spec.kwargs == {
            "task": parts.task,
            "cylinder": parts.cylinder_id,
            "tube_length_m": parts.tube_length_m,
        }
    assert parse_env_id("ForceTrack-Airpel-0.5m-v0") == EnvId("ForceTrack", "Airpel", "0.5")
    assert env_id("PositionTrack", "airpel-E16D3.0N", 2.0) == POSITION_ID
    assert env_id("ForceTrack", "NUMATICS", "0.5") == FORCE_ID
    assert pneumatic_env.make("ForceTrack", "numatics", 0.5).spec.id == FORCE_ID


@pytest.mark.parametrize(
    "call,field",
    [
        (lambda: pneumatic_env.env_id("Balance", "Numatics", 2), "task = 'Balance'"),
        (lambda: pneumatic_env.env_id("ForceTrack", "festo", 2), "cylinder = 'festo'"),
        (lambda: pneumatic_env.env_id("ForceTrack", "Numatics", 1.5), "tube = 1.5"),
        (
            lambda: pneumatic_env.ids.parse_env_id("pneumatic_env/ForceTrack-Numatics-2m-v1"),
            "env id = 'pneumatic_env/ForceTrack-Numatics-2m-v1'",
        ),
        (
            lambda: pneumatic_env.ids.parse_env_id("ForceTrack-Numatics-7m-v0"),
            "env id = 'ForceTrack-Numatics-7m-v0'",
        ),
    ],
)
def test_bad_ids_are_refused(call, field):
    with pytest.raises(ValueError) as err:
        call()
    assert str(err.value).startswith(field + " is not allowed: use ")


def test_public_api_resolves_and_is_documented():
    import pydoc

    assert len(pneumatic_env.__all__) == len(set(pneumatic_env.__all__))
    for name in pneumatic_env.__all__:
        assert getattr(pneumatic_env, name) is not None, name
    assert (
        pneumatic_env.PneumaticTrackingVectorEnv
        is gym.make_vec(FORCE_ID, num_envs=2).unwrapped.__class__
    )
    text = pydoc.render_doc(pneumatic_env, renderer=pydoc.plaintext)
    for name in pneumatic_env.__all__:
        assert f"\n    {name}(" in text or f"class {name}" in text, name
    with pytest.raises(AttributeError, match="no attribute 'nonexistent'"):
        pneumatic_env.nonexistent  # noqa: B018


def test_importing_the_package_loads_no_heavy_dependency():
    import subprocess
    import sys

    heavy = ("torch", "matplotlib", "stable_baselines3")
    code = (
        "import sys, pneumatic_env; pneumatic_env.registered_ids(); "
        f"print([m for m in {heavy!r} if m in sys.modules])"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_env_docstrings_state_spaces_reward_options_and_episode_end():
    for cls in (pneumatic_env.PneumaticTrackingEnv, pneumatic_env.PneumaticTrackingVectorEnv):
        doc = cls.__doc__
        for section in (
            "## Description",
            "## Action Space",
            "## Observation Space",
            "## Rewards",
            "## Starting State",
            "## Episode End",
            "## Arguments",
            "## Version History",
        ):
            assert section in doc, (cls.__name__, section)
        assert 'options={"reference"' in doc and "terminated`` is always False" in doc
