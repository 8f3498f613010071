"""The closed loop on the virtual rig's own plant (studies/rig_closed_loop.py, issue 35)."""

import dataclasses

import numpy as np
import pytest

from pneumatic_env.agents.bench import run_suite
from pneumatic_env.agents.suite import load_suite
from pneumatic_env.identification.config import load_config
from pneumatic_env.params import load_numerics, load_parameters
from pneumatic_env.studies.rig_closed_loop import RigSpec, rig_closed_loop
from pneumatic_env.studies.rig_plants_closed_loop import rig_plant
from pneumatic_env.studies.segmented_line import (
    line_constants,
    line_rows,
    segmented_line_advance,
    segmented_line_rest,
)

VARIANT = "Numatics-2m"


def _suite(*names, duration_s=None):
    suite = load_suite()
    tasks = [suite.task_named(n) for n in names]
    if duration_s is not None:
        tasks = [dataclasses.replace(t, duration_s=duration_s) for t in tasks]
    return dataclasses.replace(suite, tasks=tuple(tasks))


@pytest.fixture(scope="module")
def two_tasks():
    return _suite("step_up", "sine_10hz")


@pytest.mark.parametrize("controller", ["pid", "sliding_mode"])
def test_rig_plant_matches_the_env_on_the_default_plant(controller, two_tasks):
    """No effect, nominal parameters, no noise: at the env's own step (control period,
    numerics' substeps) the rig's kernel plant is the env's simulator, so the closed loops
    agree to rounding; at the rig's 10x finer step (10 RK4 substeps of 10 us) they differ
    by the env's discretisation error, which numerics.yaml bounds by 0.1 % of full scale
    against the reference solution (measured here: 0.007 N of 139 N, 5e-5)."""
    _, traces = run_suite(controller, [VARIANT], two_tasks)
    env = traces[VARIANT]
    numerics = load_numerics()
    same_step = RigSpec(
        seed=None, plant_dt_s=numerics["control_dt_s"], plant_substeps=numerics["substeps"]
    )
    rig = rig_closed_loop(controller, same_step, VARIANT, two_tasks)["traces"]
    scale = env["scale_n"]
    for key in ("force_n", "reference_n", "current_a"):
        np.testing.assert_allclose(rig[key], env[key], rtol=0, atol=1e-9 * scale)
    np.testing.assert_allclose(rig["exhaust_kg"], env["exhaust_kg"], rtol=1e-9, atol=1e-15)
    fine = rig_closed_loop(controller, RigSpec(seed=None), VARIANT, two_tasks)
    np.testing.assert_allclose(fine["traces"]["force_n"], env["force_n"], atol=1e-3 * scale)
    assert np.max(np.abs(fine["traces"]["force_n"] - env["force_n"])) > 0.0  # another plant


def test_effects_change_the_closed_loop_and_compose():
    """The segmented line (tube_waves) moves PID's error on the 2 m tube; with wall heat
    exchange and spool friction on top the loop runs, stays finite and moves again."""
    suite = _suite("sine_10hz", duration_s=0.4)
    base = rig_closed_loop("pid", RigSpec(seed=None), VARIANT, suite)["rows"][0]
    line = rig_closed_loop("pid", RigSpec((("tube_waves", 1.0),), seed=None), VARIANT, suite)[
        "rows"
    ][0]
    three = rig_closed_loop(
        "pid",
        RigSpec(RigSpec.parse_effects("tube_waves,heat_transfer,spool_friction"), seed=3),
        VARIANT,
        suite,
    )["rows"][0]
    assert abs(line["rms_error_pct"] - base["rms_error_pct"]) > 0.5
    assert all(np.isfinite(v) for k, v in three.items() if k != "task")
    assert abs(three["rms_error_pct"] - line["rms_error_pct"]) > 0.05
    assert three["air_mg"] > 0.0


def test_spool_friction_holds_the_current_across_control_periods():
    """The stick-slip play keeps its state between control periods: a command that
    returns inside the breakaway band leaves the plant where it was (no reset to 0)."""
    cfg = load_config()
    p = load_parameters("numatics", tube_length_m=0.5, piston_mode="fixed")
    plant = rig_plant(p, "numatics", {"spool_friction": 1.0}, 1e-3, 1e-4, 10, cfg)
    plant.advance(0.5)
    (held,) = plant.command_filters
    band = held.band_a
    assert held.state[0] == pytest.approx(0.5 - band)
    plant.advance(0.5 - 0.5 * band)  # back inside the band: stuck
    assert held.state == [pytest.approx(0.5 - band), 0.0]


@pytest.mark.parametrize(
    "effects",
    [
        {"supply_ripple": 1.0, "supply_droop": 1.0},
        {"tube_waves": 1.0, "leakage": 1.0},
        {"lugre": 1.0},
    ],
)
def test_effects_that_do_not_compose_are_refused(effects):
    p = load_parameters("numatics", tube_length_m=2.0, piston_mode="fixed")
    with pytest.raises(ValueError, match="twice|compose|moving piston"):
        rig_plant(p, "numatics", effects, 1e-3, 1e-4, 10, load_config())


def test_segmented_line_chambers_exchange_heat_with_the_wall():
    """With the wall exchange on, the chambers' gas heats on charging (air enters with
    the enthalpy of the wall's temperature) and relaxes back to the wall while held (hA =
    1 W/K: a time constant m c_v / hA of about 0.1 s here); the pressure stays at supply."""
    p = load_parameters("numatics", tube_length_m=0.5, piston_mode="fixed")
    n, rows = 4, line_rows(4)
    density_ref = (
        0.5
        * (p["supply_pressure_pa"] + p["ambient_pressure_pa"])
        / (p["gas_constant_j_per_kg_k"] * p["temperature_k"])
    )
    c = line_constants(p, n, (1.0, density_ref, 2.0 / 3.0))
    y = segmented_line_rest(c, n)
    segmented_line_advance(c, n, y, np.full(100, 1.0), 1e-4, 10)  # 10 ms charge
    assert y[rows["t1"]] > p["temperature_k"] + 30.0
    segmented_line_advance(c, n, y, np.full(20000, 1.0), 1e-4, 10)  # held 2 s
    assert y[rows["t1"]] == pytest.approx(p["temperature_k"], abs=2.0)
    assert y[rows["p1"]] == pytest.approx(p["supply_pressure_pa"], rel=1e-3)


def test_coil_lag_a_control_period_at_a_time_is_the_rigs_coil():
    """The closed loop's coil (a chunk of plant steps per control period) gives the open-loop
    rig's coil (``_coil_plant`` on the whole command) to rounding."""
    from pneumatic_env.studies.rig_plants import _coil_plant

    cfg = load_config()
    p = load_parameters("numatics", tube_length_m=0.5, piston_mode="fixed")
    plant = rig_plant(p, "numatics", {"coil_lag": 1.0}, 1e-3, 1e-4, 10, cfg)
    (coil,) = plant.command_filters
    command = np.repeat(np.random.default_rng(0).uniform(-1.0, 1.0, 50), 10)
    chunked = np.concatenate([coil(command[k : k + 10]) for k in range(0, command.size, 10)])
    whole = _coil_plant(
        command,
        cfg.number("virtual_rig", "effects", "coil_lag"),
        1e-4,
        cfg.number("virtual_rig", "coil_amplifier_period_s"),
        cfg.number("virtual_rig", "coil_force_lag_share"),
    )
    np.testing.assert_allclose(chunked, whole, rtol=0, atol=1e-12)
    assert np.max(np.abs(chunked - command)) > 0.1  # the lag is there


def test_sensor_noise_is_drawn_from_the_rigs_seed():
    """The rig's sensor noise and quantisation reach the controller: the loop moves, and the
    same rig (seed) gives the same run."""
    suite = _suite("sine_10hz", duration_s=0.2)
    runs = [
        rig_closed_loop("pid", RigSpec(seed=1, noise=noise), VARIANT, suite)["traces"]["current_a"]
        for noise in (True, True, False)
    ]
    np.testing.assert_array_equal(runs[0], runs[1])
    assert np.max(np.abs(runs[0] - runs[2])) > 1e-4
