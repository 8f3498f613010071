"""The env's ``plant`` option (a model mismatch) and the robustness table built on it."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import pneumatic_env  # noqa: F401  (registers the ids)
from conftest import assert_error_names
from pneumatic_env.params import ConfigError, load_parameters

ENV_ID = "pneumatic_env/ForceTrack-Numatics-2m-v0"


def _rollout(currents, n_envs=3, **options):
    env = gym.make_vec(ENV_ID, num_envs=n_envs, **options)
    obs, _ = env.reset(seed=11)
    out = [obs]
    for u in currents:
        obs, *_ = env.step(np.full((n_envs, 1), u, dtype=np.float32))
        out.append(obs)
    core = env.unwrapped
    facts = (dict(core.base_params), core.reference_scale, core.force_scale_n)
    env.close()
    return np.array(out), facts


CURRENTS = np.r_[np.full(40, 0.6), np.full(40, -0.5)]


def test_an_empty_plant_is_the_nominal_env_bit_for_bit():
    nominal, facts = _rollout(CURRENTS)
    same, same_facts = _rollout(CURRENTS, plant={})
    assert np.array_equal(nominal, same)
    assert facts == same_facts


def test_a_perturbed_plant_changes_the_dynamics_but_not_what_the_controller_knows():
    """A 20 % lower supply: the measured channels are those of an env whose model has
    that supply, while base_params, the reference and force scales stay nominal."""
    nominal, facts = _rollout(CURRENTS)
    ps = load_parameters("numatics")["supply_pressure_pa"]
    weak, weak_facts = _rollout(CURRENTS, plant={"supply_pressure_pa": 0.8 * ps})
    assert weak_facts == facts  # what a controller may know is unchanged
    assert not np.allclose(weak[:, :, :4], nominal[:, :, :4])
    # [p1, p2, x, f] (not normalised here) are the plant's
    model, model_facts = _rollout(CURRENTS, supply_pressure_pa=0.8 * ps)
    assert np.array_equal(weak[:, :, :4], model[:, :, :4])
    assert model_facts[1] < facts[1]  # ... whose own force scale would shrink


@pytest.mark.parametrize(
    "plant, field, value",
    [
        ({"supply_pressure_pa": -1.0}, "supply_pressure_pa", -1.0),
        ({"no_such_parameter": 1.0}, "no_such_parameter", None),
    ],
)
def test_a_bad_plant_names_the_field(plant, field, value):
    with pytest.raises((ValueError, ConfigError)) as err:
        gym.make(ENV_ID, plant=plant)
    if value is None:
        assert_error_names(err, field)
    else:
        assert_error_names(err, field, value)


def test_a_plant_that_is_not_a_dict_is_refused():
    with pytest.raises(ValueError) as err:
        gym.make(ENV_ID, plant=[1.0])
    assert_error_names(err, "plant", [1.0], "dict")


def test_perturbed_plants_scale_the_nominal_values_and_check_their_keys():
    from pneumatic_env.agents.robustness import NOMINAL, perturbed_plants

    nominal = load_parameters("numatics", tube_length_m=2.0)
    config = {
        "perturbations": {
            "cd": {"factor": {"discharge_coefficient": 0.8}},
            "lag": {"set": {"coil_time_constant_s": 3e-3}},
        }
    }
    plants = perturbed_plants(config, "Numatics-2m")
    assert plants[NOMINAL] == {}
    assert plants["cd"] == {"discharge_coefficient": 0.8 * nominal["discharge_coefficient"]}
    assert plants["lag"] == {"coil_time_constant_s": 3e-3}
    with pytest.raises(ValueError) as err:
        perturbed_plants({"perturbations": {"x": {"scale": {}}}}, "Numatics-2m")
    assert_error_names(err, "scale", rule=("factor", "set"))


def test_robustness_rows_keep_the_nominal_tuning():
    """The PID on a plant whose discharge coefficient is 20 % lower: its nominal row is the
    benchmark's, and the perturbed one differs (the same gains on another plant)."""
    from pneumatic_env.agents.bench import run_suite
    from pneumatic_env.agents.robustness import robustness_markdown, robustness_rows

    plants = {"nominal": {}, "cd -20 %": {"discharge_coefficient": 0.2}}
    table = robustness_rows("Numatics-0.5m", ["pid"], plants, progress=lambda _: None)
    rows, _ = run_suite("pid", ["Numatics-0.5m"])
    assert table["pid"]["nominal"] == pytest.approx(np.mean([r["rms_error_pct"] for r in rows]))
    assert table["pid"]["cd -20 %"] != table["pid"]["nominal"]
    text = robustness_markdown("Numatics-0.5m", table)
    assert "| pid |" in text and "worst ratio" in text


def test_seed_statistics_count_the_seeds_below_the_baseline():
    """``--seed-runs``: per plant the seeds' IQM and how many are below the baseline, and
    the worst ratios against the baseline's (a table written by hand)."""
    from pneumatic_env.agents.robustness import seed_markdown, worst_ratio

    table = {
        "pid": {"nominal": 5.0, "a": 6.0, "b": 9.0},
        "s1": {"nominal": 4.0, "a": 5.0, "b": 8.0},  # worst 2.0 > pid's 1.8
        "s2": {"nominal": 4.5, "a": 6.5, "b": 7.0},  # worst 1.56 <= 1.8
    }
    assert worst_ratio(table["pid"]) == pytest.approx(1.8)
    text = seed_markdown("V", "pid", table)
    lines = {r.split("|")[1].strip(): r for r in text.splitlines() if r.startswith("|")}
    assert lines["a"].split("|")[4].strip() == "1 of 2"
    assert lines["b"].split("|")[4].strip() == "2 of 2"
    assert lines["worst ratio"].split("|")[2].strip() == "1.80"
    assert lines["worst ratio"].split("|")[4].strip() == "1 of 2 at most"


def test_the_seed_actors_at_a_residual_gain(tmp_path, capsys):
    """``--residual-gain``: each seed's residual runs at that gain of its trained bound
    (the shipped actors are scaled already: rescaled from the trained bound, not
    compounded); without ``--seed-runs`` the option is refused by name."""
    from pneumatic_env.agents.learned import (
        LearnedActor,
        shipped_policy_path,
        trained_correction_fraction,
    )
    from pneumatic_env.agents.robustness import actors_at_gain, main

    shipped = [shipped_policy_path("ppo_adaptive", v) for v in ("Numatics-2m", "Airpel-2m")]
    for gain in (0.0, 0.9, 1.0):
        out = tmp_path / f"g{gain}"
        out.mkdir()
        paths = actors_at_gain(shipped, gain, out)
        assert [p.parent for p in paths] == [out, out] and paths[0] != paths[1]
        for src, path in zip(shipped, paths):
            trained = trained_correction_fraction(LearnedActor(src).meta)
            meta = LearnedActor(path).meta
            assert meta["residual"]["correction_fraction"] == pytest.approx(gain * trained)
            assert meta["residual_gain"]["gain"] == gain
    with pytest.raises(SystemExit):
        main(["--residual-gain", "0.9"])
    assert "--residual-gain 0.9 needs --seed-runs" in capsys.readouterr().err


def test_the_pid_retuned_per_plant_finds_the_tuned_gains_on_the_nominal_plant():
    """``pid_retuned_per_plant`` searches the tuning grid on each plant: on the nominal one
    it finds the gains tune_pid wrote to configs/agents/pid-numatics-2m.yaml (a grid cut to
    the neighbours of those gains), and on the plant with the tube's whole air volume, a
    slower plant, a higher proportional gain."""
    from pneumatic_env.agents.config import load_agent_config
    from pneumatic_env.agents.registry import classical_gains
    from pneumatic_env.agents.robustness import pid_retuned_for

    tuned = classical_gains("pid", "Numatics-2m")
    tuning = load_agent_config("tuning", raw=("references",))
    grid = {k: [tuned[k]] for k in tuning["pid"]["grid"]}
    grid["kp_a_per_n"] = [0.004, 0.006, 0.008]
    grid["reference_lead_s"] = [0.012, 0.016, 0.018]
    tuning["pid"] = {**tuning["pid"], "grid": grid}

    nominal = pid_retuned_for("Numatics-2m", {}, tuning)
    assert nominal == {**tuning["pid"]["fixed"], **{k: tuned[k] for k in grid}}
    tube_air = pid_retuned_for("Numatics-2m", {"tube_volume_fraction": 1.0}, tuning)
    assert tube_air["kp_a_per_n"] > nominal["kp_a_per_n"]
