"""Domain randomisation (env option ``domain_randomization``, envs.randomization): the
draws per episode, the ``one_of`` alternatives (a switch such as ``tube_waves`` on in a
share of the episodes) and the refusals."""

import gymnasium as gym
import numpy as np
import pytest

import pneumatic_env  # noqa: F401  (registers the ids)
from pneumatic_env.envs.randomization import Randomization
from pneumatic_env.physics import layout as L

ID_2M = "pneumatic_env/ForceTrack-Numatics-2m-v0"
TUBE_FORMS = {
    "discharge_coefficient": 0.2,
    "one_of": [
        {"probability": 0.25, "ranges": {"tube_waves": [1, 1]}},
        {"probability": 0.75, "ranges": {"tube_volume_fraction": [0.0, 1.0]}},
    ],
}


def test_ranges_alone_draw_as_before():
    """Without alternatives a draw is the ranges' uniform numbers in order, nothing else."""
    ranges = {"supply_pressure_pa": (4e5, 6e5), "coil_time_constant_s": (0.0, 4e-3)}
    drawn = Randomization(ranges).draw(np.random.default_rng(3))
    rng = np.random.default_rng(3)
    assert drawn == {n: rng.uniform(lo, hi) for n, (lo, hi) in ranges.items()}


def test_one_of_switches_tube_waves_per_episode():
    """A quarter of the episodes get the transmission line, the rest a tube air volume in
    [0, 1]; never both, and the discharge coefficient is drawn in every one."""
    n = 64
    venv = gym.make_vec(ID_2M, num_envs=n, domain_randomization=TUBE_FORMS)
    venv.reset(seed=0)
    params = venv.unwrapped.core.sim.params
    waves = params[L.P_TUBE_WAVES] == 1.0
    volume = params[L.P_TUBE_VOLUME_FRACTION]
    assert 0.1 < waves.mean() < 0.45  # binomial(64, 0.25): 16 +- 3.5
    assert np.all(volume[waves] == 0.0)
    assert np.all((volume[~waves] >= 0.0) & (volume[~waves] <= 1.0))
    assert np.unique(volume[~waves]).size == (~waves).sum()
    nominal = venv.unwrapped.core.plant_params["discharge_coefficient"]
    cd = params[L.P_DISCHARGE_COEFFICIENT]
    assert np.all(np.abs(cd / nominal - 1.0) <= 0.2) and np.unique(cd).size == n
    venv.step(np.zeros((n, 1), dtype=np.float32))  # both tube forms in one batch step
    venv.close()


def test_one_of_is_seeded():
    a, b = (gym.make_vec(ID_2M, num_envs=8, domain_randomization=TUBE_FORMS) for _ in range(2))
    a.reset(seed=5)
    b.reset(seed=5)
    assert np.array_equal(a.unwrapped.core.sim.params, b.unwrapped.core.sim.params)


@pytest.mark.parametrize(
    "spec, message",
    [
        (
            {
                "tube_volume_fraction": [0.0, 1.0],
                "one_of": [{"probability": 1.0, "ranges": {"tube_waves": [1, 1]}}],
            },
            r"the high ends of \['tube_volume_fraction', 'tube_waves'\] together",
        ),
        (
            {"one_of": [{"probability": 0.5, "ranges": {"tube_waves": [1, 1]}}]},
            "the probabilities must sum to 1",
        ),
        ({"one_of": [{"probability": 1.0}]}, "exactly probability and ranges"),
        ({"one_of": []}, "must be a non-empty list"),
    ],
)
def test_one_of_refusals(spec, message):
    with pytest.raises(ValueError, match=message):
        gym.make(ID_2M, domain_randomization=spec)
