"""The virtual rig with several effects at once (studies/rig_multi_effect.py, issue 34)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pneumatic_env.identification.config import load_config
from pneumatic_env.params import load_parameters
from pneumatic_env.recording import read_recording
from pneumatic_env.studies.rig_multi_effect import parse_effects, run_rig_effects
from pneumatic_env.studies.rig_plants import _two_lags
from pneumatic_env.studies.rig_plants_closed_loop import rig_plant
from pneumatic_env.studies.virtual_rig import run_rig

SHORT = dict(seed=3, duration_s=0.25, experiment=1, excitation_kind="steps")


@pytest.mark.parametrize(
    "effect, rig",
    [
        ("none", {}),
        ("heat_transfer", {}),
        ("supply_droop", {}),
        ("leakage", {}),
        ("coil_lag", {}),
        ("spool_friction", {}),
        ("pressure_sensor_lag", {}),
        ("channel_time_skew", {}),
        ("tube_waves", {"tube_length_m": 2.0}),
        ("lugre", {"piston": "spring"}),
    ],
)
def test_one_effect_on_the_closed_loop_plant_is_the_single_effect_rig(effect, rig):
    """Driven open loop, the closed-loop plant with one effect is the single-effect rig bit
    for bit: the same forms, stepped in the same order (the coil's filter in one chunk,
    the line from the same rest), the same sensors and draws; the truth names the same
    parameters with the same values."""
    single = run_rig(effect=effect, **SHORT, **rig)
    multi = run_rig_effects({} if effect == "none" else {effect: 1.0}, **SHORT, **rig)
    for channel, samples in single.channels.items():
        np.testing.assert_array_equal(multi.channels[channel], samples, err_msg=channel)
    assert multi.truth["parameters"] == single.truth["parameters"]
    assert multi.rig == single.rig


def test_three_effects_at_once_change_the_recording_and_the_truth_lists_them():
    """Wall heat and spool friction on top of the tube's segmented line move the recorded
    pressures (beyond the sensor noise of 1 kPa); the truth lists every effect with its
    strength and nearest kernel form."""
    effects = parse_effects("tube_waves,heat_transfer,spool_friction=2")
    assert effects == {"tube_waves": 1.0, "heat_transfer": 1.0, "spool_friction": 2.0}
    rig = dict(SHORT, tube_length_m=2.0)
    three = run_rig_effects(effects, **rig)
    line = run_rig_effects({"tube_waves": 1.0}, **rig)
    assert np.max(np.abs(three.channels["p1"] - line.channels["p1"])) > 5e3
    truth = three.truth
    assert truth["effect"] == "tube_waves+heat_transfer+spool_friction"
    assert truth["effects"] == effects
    cfg = load_config()
    friction = 2.0 * cfg.number("virtual_rig", "effects", "spool_friction")
    assert truth["parameters"]["spool_coulomb_friction_n"] == pytest.approx(friction)
    assert truth["parameters"]["wall_heat_transfer_w_per_k"] > 0.0
    assert truth["parameters"]["tube_volume_fraction"] == 0.0


def test_sensor_lag_in_the_closed_loop_is_the_rigs_two_lags_a_chunk_at_a_time():
    """The closed loop's pressure-sensor lag, run a control period at a time, gives the
    recording's two lags (``_two_lags`` on the whole record) to rounding, and lags the true
    pressure."""
    cfg = load_config()
    p = load_parameters("numatics", tube_length_m=0.5, piston_mode="fixed")
    plant = rig_plant(p, "numatics", {"pressure_sensor_lag": 1.0}, 1e-3, 1e-4, 10, cfg)
    command = np.random.default_rng(0).uniform(-1.0, 1.0, 30)
    first = plant.outputs()[[0, 1]].copy()
    true_rows, measured = [first], [plant.measured()[[0, 1]]]
    for current in command:
        true_rows.append(plant.rollout(np.full(10, current))[:, [0, 1]])
        measured.append(plant.measured()[[0, 1]])
    true_p = np.vstack([first[None, :], *true_rows[1:]])
    tau = cfg.number("virtual_rig", "effects", "pressure_sensor_lag")
    whole = np.column_stack([_two_lags(true_p[:, ch].copy(), tau, 1e-4) for ch in (0, 1)])
    np.testing.assert_allclose(np.array(measured), whole[::10], rtol=1e-12)
    assert np.max(np.abs(whole[::10] - true_p[::10])) > 1e3  # the lag is there


def test_rig_cli_records_a_multi_effect_campaign(tmp_path):
    from pneumatic_env.cli import main

    out = tmp_path / "rig"
    args = ["rig", "--campaign", "small", "--effects", "leakage,coil_lag=0.5", "--seed", "2"]
    assert main([*args, "--out", str(out)]) == 0
    csvs = sorted(out.glob("*.csv"))
    assert len(csvs) == 3
    for csv in csvs:
        assert read_recording(csv).warnings == []
        truth = json.loads(csv.with_suffix(".truth.json").read_text())
        assert truth["effects"] == {"leakage": 1.0, "coil_lag": 0.5}
    both = ["rig", "--effect", "leakage", "--effects", "coil_lag,leakage", "--out", str(out)]
    assert main(both) == 2


def test_multi_effect_refusals():
    with pytest.raises(ValueError, match="not allowed"):
        parse_effects("tube_waves,valve_null_leak")
    with pytest.raises(ValueError, match="twice"):
        parse_effects("leakage,leakage=2")
    with pytest.raises(ValueError, match="compose"):
        run_rig_effects({"tube_waves": 1.0, "leakage": 1.0}, **SHORT)


def test_the_closed_loop_controller_sees_the_lagged_pressures():
    """With pressure_sensor_lag the sliding mode (which reads the chamber pressures) is fed
    the lagged pressures: its currents change, while the first step (the plant at rest,
    where lagged and true pressures agree) does not."""
    import dataclasses

    from pneumatic_env.agents.suite import load_suite
    from pneumatic_env.studies.rig_closed_loop import RigSpec, rig_closed_loop

    suite = load_suite()
    task = dataclasses.replace(suite.task_named("sine_10hz"), duration_s=0.1)
    suite = dataclasses.replace(suite, tasks=(task,))
    runs = [
        rig_closed_loop("sliding_mode", RigSpec(effects, seed=None), "Numatics-0.5m", suite)
        for effects in ((), (("pressure_sensor_lag", 1.0),))
    ]
    plain, lagged = (r["traces"]["current_a"][:, 0] for r in runs)
    assert plain[0] == lagged[0]
    assert np.max(np.abs(plain - lagged)) > 1e-3
