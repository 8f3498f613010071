"""The critic's privileged plant inputs (training.critic_plant_inputs,
agents.ppo_setup.PlantInputs): the drawn plant of each lane's episode, scaled over the
randomisation's ranges, seen by the critic only."""

import numpy as np
import pytest
import torch

from conftest import assert_error_names, small_run
from pneumatic_env.agents.config import ConfigError
from pneumatic_env.agents.learned import LearnedActor
from pneumatic_env.agents.ppo_config import load_config
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
