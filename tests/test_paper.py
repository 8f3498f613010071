"""The paper's experiments (pneumatic_env.studies.paper) against the facts the paper states."""

import json
import math

import numpy as np
import pytest

from pneumatic_env.cli import main
from pneumatic_env.params import load_parameters
from pneumatic_env.studies.paper import (
    clamped_step_runs,
    step_metrics,
    tube_response,
    valve_flow_vs_current,
    valve_flow_vs_downstream,
    valve_numbers,
)

P = load_parameters("numatics-0750D02-03A")


def _choked_flow(area_m2, upstream_pa):
    """Eq. 39 with Eq. 40 (corrected exponents), written out independently of the package."""
    k, gas = P["heat_capacity_ratio"], P["gas_constant_j_per_kg_k"]
    c1 = math.sqrt(k / gas * (2 / (k + 1)) ** ((k + 1) / (k - 1)))
    assert abs(c1 - 0.040418) < 1e-6  # the paper's C1
    return P["discharge_coefficient"] * area_m2 * upstream_pa * c1 / math.sqrt(P["temperature_k"])


@pytest.fixture(scope="module")
def step():
    return step_metrics(clamped_step_runs(duration_s=0.15))


@pytest.mark.parametrize("coupling", ["command", "literal"])
def test_long_tube_adds_its_acoustic_delay(step, coupling):
    c = math.sqrt(P["heat_capacity_ratio"] * P["gas_constant_j_per_kg_k"] * P["temperature_k"])
    expected = (2.0 - 0.5) / c
    assert abs(expected - 4.37e-3) < 0.01e-3
    assert abs(step[coupling]["extra_delay_s"] - expected) < 0.3e-3


@pytest.mark.parametrize("coupling", ["command", "literal"])
def test_long_tube_more_than_doubles_the_time_to_final_force(step, coupling):
    times = step[coupling]["time_to_final_force_s"]
    assert np.isfinite(times["0.5"]) and np.isfinite(times["2.0"])
    assert step[coupling]["final_force_time_ratio"] > 2.0


def test_literal_coupling_oscillates_near_supply_with_the_long_tube(step):
    cmd = step["command"]["p1_oscillation_amplitude_pa"]
    lit = step["literal"]["p1_oscillation_amplitude_pa"]
    assert cmd["0.5"] < 100.0 and cmd["2.0"] < 100.0  # the default coupling settles
    assert lit["2.0"] > 20e3 and lit["2.0"] > 5.0 * lit["0.5"]


def test_steady_spool_displacement_is_eq46(step):
    expected = P["coil_force_n_per_a"] * 0.5 / (2.0 * P["spool_spring_n_per_m"])
    assert math.isclose(valve_numbers(P)["spool_displacement_at_step_m"], expected, rel_tol=1e-12)
    # The simulated spool (Eq. 38 integrated by the kernel) settles there.
    assert math.isclose(step["command"]["spool_position_at_end_m"], expected, rel_tol=1e-6)


def test_valve_flow_is_monotone_in_current_and_saturates_at_the_choked_value():
    currents = np.linspace(0.0, 2.0, 401)
    flows = valve_flow_vs_current(P, currents)
    one = flows["chamber1_kg_s"]
    per_amp = 2.0 * P["spool_spring_n_per_m"] / P["coil_force_n_per_a"]  # A per m of spool
    dead_band_a = (P["spool_half_width_m"] - P["hole_radius_m"]) * per_amp
    full_a = (P["spool_half_width_m"] + P["hole_radius_m"]) * per_amp
    assert np.all(np.diff(one) >= 0.0)
    opening = (currents > dead_band_a) & (currents < full_a)
    assert np.all(np.diff(one[opening]) > 0.0)
    assert np.all(one[currents <= dead_band_a] == 0.0)
    full_area = P["holes_per_path"] * math.pi * P["hole_radius_m"] ** 2
    choked = _choked_flow(full_area, P["supply_pressure_pa"])
    np.testing.assert_allclose(one[currents >= full_a], choked, rtol=1e-9)
    assert abs(choked - 10.8e-3) < 0.05e-3  # the reference set's "about 10.8 g/s"
    numbers = valve_numbers(P)
    assert math.isclose(numbers["choked_flow_full_open_kg_s"], choked, rel_tol=1e-9)
    assert math.isclose(numbers["full_open_area_m2"], full_area, rel_tol=1e-9)
    # The other path mirrors it: supply -> chamber 2 opens for negative currents.
    mirrored = valve_flow_vs_current(P, -currents)
    np.testing.assert_array_equal(mirrored["chamber2_kg_s"], one)
    assert np.all(mirrored["chamber1_kg_s"] == 0.0)


def test_valve_flow_vs_downstream_pressure():
    downstream = np.linspace(P["ambient_pressure_pa"], P["supply_pressure_pa"], 300)
    flow = valve_flow_vs_downstream(P, 0.8, downstream)
    assert np.all(np.diff(flow) <= 0.0) and flow[-1] == 0.0
    choked_region = downstream / P["supply_pressure_pa"] <= 0.528
    assert np.ptp(flow[choked_region]) == 0.0 and flow[0] > 0.0
    assert np.all(flow[~choked_region][:-1] < flow[0])


def test_tube_wave_solution_matches_eq31_in_the_laminar_limit():
    """Without turbulence R_t is constant and Eq. 31 should hold: delay L/c, attenuation phi."""
    laminar = dict(P, reynolds_turbulent=1e30)
    r = tube_response(laminar, duration_s=0.08)
    assert r["amplitude_ratio_eq31"] == pytest.approx(r["phi_laminar"], rel=1e-4)
    assert r["amplitude_ratio_wave"] == pytest.approx(r["phi_laminar"], rel=0.01)
    t, wave, eq31 = r["t"], r["outlet_wave_kg_s"], r["outlet_eq31_kg_s"]
    assert np.all(wave[t < r["delay_s"] - 1e-9] == 0.0)
    assert np.abs(wave - eq31).max() < 0.05 * 6e-3
    # With the Reynolds-dependent resistance the attenuation is stronger (turbulent R_t).
    turbulent = tube_response(P, duration_s=0.08)
    assert turbulent["amplitude_ratio_wave"] < 0.9 * r["amplitude_ratio_wave"]
    assert turbulent["amplitude_ratio_eq31"] < turbulent["phi_laminar"]


def test_cli_writes_figures_and_table(tmp_path, capsys):
    out = tmp_path / "figs"
    assert main(["paper", "--out", str(out), "--quick"]) == 0
    assert "extra delay" in capsys.readouterr().out
    pngs = sorted(p.name for p in out.glob("*.png"))
    assert pngs == [
        "clamped_step.png",
        "free_sine.png",
        "tube_outlet_flow.png",
        "valve_flow_vs_current.png",
        "valve_flow_vs_downstream.png",
    ]
    for name in pngs:
        assert (out / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    table = json.loads((out / "table.json").read_text())
    assert table["step"]["command"]["final_force_time_ratio"] > 2.0
    md = (out / "table.md").read_text()
    assert md.startswith("| quantity | value | unit |") and "extra delay of the 2 m tube" in md
