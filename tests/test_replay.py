"""Replay of recordings (pneumatic_env.replay, ``pneumatic-env simulate``)."""

import json
import math

import numpy as np
import pytest

from conftest import assert_error_names
from pneumatic_env.cli import main
from pneumatic_env.params import load_numerics, load_parameters, parameter_array, save_parameters
from pneumatic_env.recording import RecordingError, read_recording, write_recording
from pneumatic_env.replay import predict_to_recording, simulate_recording, substeps_for
from pneumatic_env.simulator import BatchSimulator

pytestmark = pytest.mark.filterwarnings("ignore::pneumatic_env.recording.RecordingWarning")

CHANNELS = ("p1", "p2", "x", "f", "v", "x_s")

RIGS = {
    "fixed": (
        {
            "cylinder": "numatics",
            "tube_length_m": 2.0,
            "piston": {"mode": "fixed", "position_m": 0.01},
        },
        dict(piston_mode=0, fixed_position_m=0.01),
        None,
    ),
    "free": (
        {
            "cylinder": "airpel-E16D3.0N",
            "tube_length_m": 0.5,
            "supply_pressure_pa": 6.0e5,
            "piston": {"mode": "free", "load_mass_kg": 0.2, "load_force_n": 1.5},
            "initial": {"p1": 2.0e5, "p2": 1.5e5, "x": -0.01},
        },
        dict(piston_mode=1, load_mass_kg=0.2, load_force_n=1.5, supply_pressure_pa=6.0e5),
        {"p1": 2.0e5, "p2": 1.5e5, "x": -0.01},
    ),
    "spring": (
        {
            "cylinder": "numatics-0750D02-03A",
            "tube_length_m": 1.0,
            "piston": {
                "mode": "spring",
                "stiffness_n_per_m": 2000.0,
                "rest_position_m": -0.005,
                "load_mass_kg": 0.1,
            },
        },
        dict(
            piston_mode=2,
            spring_stiffness_n_per_m=2000.0,
            spring_rest_position_m=-0.005,
            load_mass_kg=0.1,
        ),
        None,
    ),
}


def _command(n, dt):
    t = np.arange(n) * dt
    return 0.9 * np.sin(2 * np.pi * 4.0 * t) + 0.4 * (t > 0.12) - 0.3 * (t > 0.2)


def _known_simulation(cylinder, overrides, initial, n, dt, substeps):
    """Run the simulator step by step: row k is the state at t_k, i_c[k] acts on [t_k, t_k+1)."""
    params = load_parameters(cylinder, **overrides)
    sim = BatchSimulator(parameter_array([params]), control_dt_s=dt, n_substeps=substeps)
    sim.reset(initial=initial)
    i_c = _command(n, dt)
    rows = [sim.outputs[:, 0].copy()]
    for k in range(n - 1):
        rows.append(sim.step(np.array([i_c[k]]))[:, 0].copy())
    rows = np.array(rows)
    channels = {"i_c": i_c}
    for j, name in enumerate(CHANNELS):  # OUTPUT_NAMES order: p1 p2 x f v x_s
        channels[name] = rows[:, j]
    return np.arange(n) * dt, channels


@pytest.mark.parametrize("mode", sorted(RIGS))
def test_replay_reproduces_a_known_simulation(tmp_path, mode):
    rig, overrides, initial = RIGS[mode]
    cylinder = rig["cylinder"]
    dt, n, substeps = 1e-3, 300, 20
    t, channels = _known_simulation(
        cylinder, dict(overrides, tube_length_m=rig["tube_length_m"]), initial, n, dt, substeps
    )
    write_recording(tmp_path / "known", t, channels, rig)
    predicted = simulate_recording(tmp_path / "known.csv", substeps=substeps)
    np.testing.assert_array_equal(predicted["t"], t)
    for name in CHANNELS:
        scale = max(np.abs(channels[name]).max(), 1e-12)
        np.testing.assert_allclose(
            predicted[name], channels[name], rtol=0, atol=1e-9 * scale, err_msg=name
        )
    # The run is not trivial: the command moved the spool and changed the pressures.
    assert np.ptp(channels["p1"]) > 1e4 and np.ptp(channels["x_s"]) > 1e-4
    if mode != "fixed":
        assert np.ptp(channels["x"]) > 1e-3


def test_default_substeps_keep_the_default_substep():
    numerics = load_numerics()
    h = numerics["control_dt_s"] / numerics["substeps"]
    assert substeps_for(numerics["control_dt_s"]) == numerics["substeps"]
    assert substeps_for(2 * h) == 2
    assert substeps_for(2.5 * h) == 3
    assert substeps_for(0.3 * h) == 1
    assert substeps_for(3e-3, max_substep_s=5e-5) == 60
    with pytest.raises(ValueError) as exc:
        substeps_for(-1e-3)
    assert_error_names(exc, "control_dt_s", -0.001, "finite number > 0 s")


def test_replay_uses_default_substeps_for_the_sample_step(tmp_path):
    rig, overrides, initial = RIGS["fixed"]
    dt = 5e-4
    t, channels = _known_simulation(
        "numatics", dict(overrides, tube_length_m=2.0), None, 200, dt, substeps_for(dt)
    )
    write_recording(tmp_path / "half", t, channels, rig)
    predicted = simulate_recording(tmp_path / "half")
    np.testing.assert_allclose(predicted["p1"], channels["p1"], rtol=1e-12)


def test_missing_coil_current_is_the_readers_error(tmp_path):
    (tmp_path / "noic.csv").write_text("t,p1\n0.0,101325.0\n0.001,101400.0\n0.002,101500.0\n")
    rig = dict(RIGS["fixed"][0], format="pneumatic-measurement", version=1)
    (tmp_path / "noic.json").write_text(json.dumps(rig))
    with pytest.raises(RecordingError) as exc:
        simulate_recording(tmp_path / "noic.csv")
    assert_error_names(exc, ("noic.csv", "'i_c'"), rule="missing required column")


def _write_fixed(tmp_path, name="rec", n=120):
    rig, overrides, _ = RIGS["fixed"]
    t, channels = _known_simulation(
        "numatics", dict(overrides, tube_length_m=2.0), None, n, 1e-3, substeps_for(1e-3)
    )
    write_recording(tmp_path / name, t, channels, rig)
    return tmp_path / f"{name}.csv", channels


def test_cli_writes_a_readable_predicted_recording(tmp_path, capsys):
    rec, channels = _write_fixed(tmp_path)
    out = tmp_path / "pred.csv"
    assert main(["simulate", str(rec), "-o", str(out)]) == 0
    line = capsys.readouterr().out.strip()
    assert line.count("\n") == 0 and "120 rows" in line and "RMS" in line
    for name in ("p1", "p2", "x", "f", "v", "x_s"):
        assert f" {name} " in line
    pred = read_recording(out)
    assert pred.rig["notes"].startswith("simulated by pneumatic_env ")
    assert str(rec) in pred.rig["notes"]
    assert pred.rig["tube_length_m"] == 2.0 and pred.rig["piston"]["mode"] == "fixed"
    np.testing.assert_array_equal(pred.i_c, channels["i_c"])
    for name in CHANNELS:
        np.testing.assert_allclose(
            pred.channels[name],
            channels[name],
            rtol=0,
            atol=1e-9 * max(np.abs(channels[name]).max(), 1e-12),
        )


@pytest.mark.parametrize("target", ["rec.csv", "rec.json", "rec"])
def test_refuses_to_write_over_the_input(tmp_path, capsys, target):
    rec, _ = _write_fixed(tmp_path)
    before = (rec.read_bytes(), rec.with_suffix(".json").read_bytes())
    code = main(["simulate", str(rec), "-o", str(tmp_path / target), "--overwrite"])
    assert code == 2
    assert "is the input recording's file" in capsys.readouterr().err
    assert (rec.read_bytes(), rec.with_suffix(".json").read_bytes()) == before
    with pytest.raises(ValueError) as exc:
        predict_to_recording(rec, tmp_path / target, overwrite=True)
    assert_error_names(exc, str(rec.with_suffix("")), rule="never overwritten")


def test_existing_output_is_kept_unless_overwrite(tmp_path, capsys):
    rec, _ = _write_fixed(tmp_path)
    out = tmp_path / "pred.csv"
    assert main(["simulate", str(rec), "-o", str(out)]) == 0
    first = out.read_bytes()
    assert main(["simulate", str(rec), "-o", str(out)]) == 2
    assert "exists" in capsys.readouterr().err
    assert out.read_bytes() == first
    assert main(["simulate", str(rec), "-o", str(out), "--overwrite", "--substeps", "40"]) == 0


def test_params_file_is_applied_but_the_rig_wins(tmp_path):
    rec, channels = _write_fixed(tmp_path)
    fitted = tmp_path / "fitted.yaml"
    # A fitted file made on another rig (0.5 m tube): its tube length must not apply here.
    save_parameters(fitted, {"discharge_coefficient": 0.3, "tube_length_m": 0.5}, notes="test")
    predicted = simulate_recording(rec, params=fitted)
    _, expected = _known_simulation(
        "numatics",
        dict(RIGS["fixed"][1], tube_length_m=2.0, discharge_coefficient=0.3),
        None,
        120,
        1e-3,
        substeps_for(1e-3),
    )
    np.testing.assert_allclose(predicted["p1"], expected["p1"], rtol=1e-12)
    assert np.abs(predicted["p1"] - channels["p1"]).max() > 1e3
    assert math.isclose(predicted["x"][0], 0.01)
