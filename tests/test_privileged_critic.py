"""The critic's privileged plant inputs (training.critic_plant_inputs,
agents.ppo_setup.PlantInputs): the drawn plant of each lane's episode, scaled over the
randomisation's ranges, seen by the critic only."""

import csv
import dataclasses

import numpy as np
import pytest
import torch

from conftest import assert_error_names, small_run
from pneumatic_env.agents.config import ConfigError
from pneumatic_env.agents.learned import LearnedActor
from pneumatic_env.agents.ppo_config import load_config
from pneumatic_env.agents.ppo_networks import Agent
from pneumatic_env.agents.ppo_rollout import RolloutBuffer, ppo_update
from pneumatic_env.agents.ppo_setup import PlantInputs, make_training_env

CONFIG = "configs/agents/ppo_fast-adaptive-tube-air-numatics-2m.yaml"
ENV = "pneumatic_env/ForceTrack-Numatics-2m-v0"
NAMES = ("supply_pressure_pa", "tube_volume_fraction", "tube_waves")


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_plant_inputs_are_each_lanes_drawn_plant_scaled_over_the_ranges(seed):
    cfg = load_config(CONFIG, {"hyperparameters.num_envs": 16})
    env = make_training_env(cfg, ENV, seed)
    env.reset(seed=seed)
    plant = PlantInputs(env, NAMES)
    x = plant()
    assert x.shape == (16, 3) and x.dtype == np.float32
    assert np.all(np.abs(x) <= 1.0 + 1e-6)
    # supply +-20 % of the nominal value: the scaled input is the relative deviation / 0.2
    nominal = env.unwrapped.core.base_params["supply_pressure_pa"]
    ps = env.unwrapped.core.sim.params[plant.rows[0]]
    assert np.allclose(x[:, 0], (ps / nominal - 1.0) / 0.2, atol=1e-5)
    # a line holds its own air: never both at once (the mixture's alternatives)
    line, air = x[:, 2] > 0, x[:, 1] > -1.0
    assert not np.any(line & air)
    env.step(np.zeros((16, 1)))  # a step within the episode keeps the plant
    assert np.array_equal(plant(), x)
    env.close()


def test_a_plant_input_that_is_not_drawn_is_refused():
    cfg = load_config(CONFIG, {"hyperparameters.num_envs": 2})
    env = make_training_env(cfg, ENV, 0)
    with pytest.raises(ConfigError) as err:
        PlantInputs(env, ("supply_pressure_pa", "kp_a_per_n"))
    assert_error_names(err, "training.critic_plant_inputs", "kp_a_per_n", ["tube_volume_fraction"])
    env.close()


def test_the_critic_sees_the_plant_and_the_exported_actor_does_not(tmp_path):
    overrides = {"training.critic_plant_inputs": list(NAMES), "training.residual_gains": None}
    summary = small_run(CONFIG, tmp_path, 2, **overrides)
    state = torch.load(tmp_path / "checkpoint.pt", weights_only=False)["agent"]
    n_actor = state["actor.0.weight"].shape[1]
    assert state["critic.0.weight"].shape[1] == n_actor + len(NAMES)
    assert len(LearnedActor(tmp_path / "actor_best.npz").meta["inputs"]) == n_actor
    assert summary["updates"] == 2


def _update_buffer(rng, T: int, N: int, D: int, P: int) -> RolloutBuffer:
    """A rollout whose privileged inputs are a fixed smooth function of the observation."""
    buf = RolloutBuffer.zeros(T, N, D, P)
    buf.obs[:] = rng.normal(size=(T, N, D))
    mix = rng.normal(size=(D, P)) / np.sqrt(D)
    buf.plant[:] = np.tanh(buf.obs @ mix)
    buf.act[:] = rng.normal(size=(T, N))
    buf.logp[:] = -0.5 * buf.act**2 - 0.5 * np.log(2 * np.pi)  # the initial policy's
    return buf


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_the_actors_plant_head_learns_the_plant_from_the_actors_inputs(seed):
    """With ``plant_weight`` > 0 the head's mean square error on the plant falls well below
    the plant's own mean square; with 0 the head gets no gradient and stays as it was."""
    rng = np.random.default_rng(seed)
    torch.manual_seed(seed)
    buf = _update_buffer(rng, 8, 64, 6, 3)
    adv = rng.normal(size=buf.act.shape).astype(np.float32)
    hp = load_config(CONFIG).hyperparameters
    hp = dataclasses.replace(hp, epochs=4, minibatches=2, target_kl=None)
    results = {}
    for weight in (0.0, 1.0):
        agent = Agent(6, (16, 16), (16,), 0.0, zero_init=True, n_privileged=3, plant_head=True)
        head0 = agent.plant_head.weight.detach().clone()
        opt = torch.optim.Adam(agent.parameters(), lr=1e-2)
        for _ in range(20):
            *_, mse = ppo_update(agent, opt, buf, adv, hp, None, weight)
        results[weight] = (mse, torch.equal(agent.plant_head.weight, head0))
    plant_ms = float(np.mean(buf.plant**2))
    assert results[1.0][0] < 0.2 * plant_ms
    assert results[0.0][1] and not results[1.0][1]


def test_the_plant_head_is_trained_logged_and_not_exported(tmp_path):
    summary = small_run(
        "configs/agents/ppo_fast-adaptive-plant-head-numatics-2m.yaml",
        tmp_path,
        2,
        **{"training.residual_gains": None},
    )
    state = torch.load(tmp_path / "checkpoint.pt", weights_only=False)["agent"]
    cfg = load_config("configs/agents/ppo_fast-adaptive-plant-head-numatics-2m.yaml")
    n_plant = len(cfg.training.critic_plant_inputs)
    assert state["plant_head.weight"].shape == (n_plant, cfg.hyperparameters.hidden_pi[-1])
    actor = LearnedActor(tmp_path / "actor_best.npz")
    assert len(actor.layers) == len(cfg.hyperparameters.hidden_pi) + 1
    assert actor.layers[-1][0].shape[0] == 1  # the action alone
    with open(tmp_path / "progress.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == summary["updates"] == 2
    assert all(np.isfinite(float(r["plant_mse"])) for r in rows)


@pytest.mark.parametrize(
    "overrides",
    [
        {"training.actor_plant_prediction": 0.5},  # no plant named for the critic
        {"training.actor_plant_prediction": -0.1, "training.critic_plant_inputs": list(NAMES)},
    ],
)
def test_a_plant_prediction_weight_without_a_plant_or_below_zero_is_refused(overrides):
    with pytest.raises(ConfigError) as err:
        load_config(CONFIG, overrides)
    assert_error_names(
        err, "training.actor_plant_prediction", overrides["training.actor_plant_prediction"]
    )
