"""Acceptance tests of the physics core (pneumatic_env/physics, BatchSimulator).

Each jitted sub-model is checked against values derived by hand from the paper's
equations (Richer & Hurmuzlu 2000, corrected as in docs/model.md), the whole model
against physical invariants, the paper's stated facts and the independent SciPy
reference solution (studies/reference_solution.py).
"""

from __future__ import annotations

import functools
import math

import numpy as np
import pytest
from scipy.integrate import quad

from conftest import areas, first_crossing_time, run_batch, volumes
from pneumatic_env.params import load_numerics, load_parameters, parameter_array
from pneumatic_env.physics import batch_path, kernel, vecmath
from pneumatic_env.physics import layout as L
from pneumatic_env.physics.flow import flow_constants, orifice_mass_flow, reduced_flow
from pneumatic_env.physics.tube import (
    reynolds_number,
    sound_speed,
    tube_attenuation,
    tube_resistance,
)
from pneumatic_env.physics.valve import orifice_area, steady_spool_position
from pneumatic_env.simulator import INITIAL_STATE_KEYS, BatchSimulator
from rollout_inputs import assert_batch_matches_general_path, random_currents

CYLINDERS = ("numatics", "airpel")
K_AIR, R_AIR = 1.4, 287.0


def _sound_speed(p):
    return math.sqrt(p["heat_capacity_ratio"] * p["gas_constant_j_per_kg_k"] * p["temperature_k"])


# --------------------------------------------------------------------------- flow (Eqs. 39, 40, 52)


@pytest.fixture(scope="module")
def flow_args():
    """Arguments of reduced_flow after the pressure ratio, with the default linearisation."""
    r_lin = load_parameters()["flow_linear_ratio"]
    c1, c2, p_cr = flow_constants(K_AIR, R_AIR)
    subsonic = c2 * r_lin ** (1 / K_AIR) * math.sqrt(1 - r_lin ** ((K_AIR - 1) / K_AIR))
    return K_AIR, c1, c2, p_cr, r_lin, subsonic / (1 - r_lin)


def test_flow_constants_are_the_papers():
    c1, c2, p_cr = flow_constants(K_AIR, R_AIR)
    assert abs(c1 - 0.040418) < 5e-7
    assert abs(c2 - 0.156174) < 5e-7
    assert abs(p_cr - 0.528) < 5e-4


def test_reduced_flow_branches_and_continuity(flow_args):
    k, c1, c2, p_cr, r_lin, slope = flow_args
    m_r = lambda r: reduced_flow(float(r), *flow_args)  # noqa: E731
    for r in np.linspace(0.0, p_cr, 7):  # choked: C1
        assert m_r(r) == c1
    for r in (0.6, 0.8, 0.9, 0.99):  # subsonic branch of Eq. 52, written out here
        assert m_r(r) == pytest.approx(
            c2 * r ** (1 / k) * math.sqrt(1 - r ** ((k - 1) / k)), rel=1e-12
        )
    eps = 1e-10
    assert m_r(p_cr + eps) == pytest.approx(c1, rel=1e-8)  # continuous at P_cr
    assert m_r(r_lin - eps) == pytest.approx(m_r(r_lin + eps), rel=1e-6)  # and at r_lin
    assert m_r(1.0) == 0.0
    assert m_r(0.5 * (1 + r_lin)) == pytest.approx(0.5 * m_r(r_lin), rel=1e-9)  # a straight line


def test_reduced_flow_non_increasing_above_critical_ratio(flow_args):
    p_cr = flow_args[3]
    r = np.linspace(p_cr, 1.0, 20001)
    m = np.array([reduced_flow(float(x), *flow_args) for x in r])
    assert np.all(np.diff(m) <= 1e-15)
    assert m[0] == pytest.approx(flow_args[1]) and m[-1] == 0.0


def _mass_flow(area, p_from, p_to, flow_args, cf=0.25, temperature=293.15):
    k, c1, c2, p_cr, r_lin, slope = flow_args
    return orifice_mass_flow(
        area, cf, p_from, p_to, 1 / math.sqrt(temperature), k, c1, c2, p_cr, r_lin, slope
    )


def test_orifice_mass_flow_choked_value_antisymmetry_and_zeros(flow_args, default_params):
    p = default_params
    full_area = p["holes_per_path"] * math.pi * p["hole_radius_m"] ** 2
    ps, pa = p["supply_pressure_pa"], p["ambient_pressure_pa"]
    # choked (P_a / P_s < P_cr): Eq. 39 gives C_f A P_u C1 / sqrt(T), about 10.8 g/s here
    expected = 0.25 * full_area * ps * flow_args[1] / math.sqrt(293.15)
    assert _mass_flow(full_area, ps, pa, flow_args) == pytest.approx(expected, rel=1e-12)
    assert expected == pytest.approx(10.8e-3, rel=0.01)
    rng = np.random.default_rng(0)
    for _ in range(50):
        a, b = rng.uniform(5e4, 8e5, 2)
        area = rng.uniform(1e-8, full_area)
        forward = _mass_flow(area, a, b, flow_args)
        assert _mass_flow(area, b, a, flow_args) == -forward
        assert np.sign(forward) == np.sign(a - b)
        assert _mass_flow(0.0, a, b, flow_args) == 0.0
        assert _mass_flow(area, a, a, flow_args) == 0.0


# --------------------------------------------------------------------------- valve (Eqs. 38, 41-46)


def _eq44_area(x_s, r_h, p_w, n_h):
    """The paper's Eq. 44 in its arctangent form, for p_w - R_h < x_s < p_w + R_h."""
    return n_h * (
        2 * r_h**2 * math.atan(math.sqrt((r_h - p_w + x_s) / (r_h + p_w - x_s)))
        - (p_w - x_s) * math.sqrt(r_h**2 - (p_w - x_s) ** 2)
    )


def test_orifice_area_matches_eq44_and_eq41(default_params):
    r_h, p_w = default_params["hole_radius_m"], default_params["spool_half_width_m"]
    n_h = default_params["holes_per_path"]
    for x_s in np.linspace(p_w - r_h, p_w + r_h, 13)[1:-1]:
        area = orifice_area(float(x_s), r_h, p_w, n_h)
        assert area == pytest.approx(_eq44_area(x_s, r_h, p_w, n_h), rel=1e-12)
        x_e = x_s - (p_w - r_h)  # Eq. 41: twice the integral of the half chord, per hole
        segment, _ = quad(
            lambda xi: math.sqrt(xi * (2 * r_h - xi)), 0.0, x_e, epsabs=0, epsrel=1e-12
        )
        assert area == pytest.approx(n_h * 2 * segment, rel=1e-9)


def test_orifice_area_closed_open_continuous_monotone(default_params):
    r_h, p_w = default_params["hole_radius_m"], default_params["spool_half_width_m"]
    n_h = default_params["holes_per_path"]
    area = lambda x: orifice_area(float(x), r_h, p_w, n_h)  # noqa: E731
    full = math.pi * n_h * r_h**2
    for x_s in (-2e-3, -(p_w - r_h), 0.0, 0.5 * (p_w - r_h), p_w - r_h):  # inside the overlap
        assert area(x_s) == 0.0
    for x_s in (p_w + r_h, p_w + r_h + 1e-6, 5e-3):
        assert area(x_s) == pytest.approx(full, rel=1e-15)
    eps = 1e-12
    assert area(p_w - r_h + eps) < 1e-9 * full
    assert area(p_w + r_h - eps) == pytest.approx(full, rel=1e-9)
    grid = np.linspace(-3e-3, 3e-3, 6001)
    values = np.array([area(x) for x in grid])
    assert np.all(np.diff(values) >= 0.0)
    assert values[0] == 0.0 and values[-1] == pytest.approx(full, rel=1e-15)


def test_steady_spool_position_eq46(default_params):
    k_s, k_fc = default_params["spool_spring_n_per_m"], default_params["coil_force_n_per_a"]
    for i in (-2.0, -0.3, 0.0, 0.8, 1.5):
        assert steady_spool_position(i, k_s, k_fc) == pytest.approx(
            k_fc * i / (2 * k_s), rel=1e-15, abs=0.0
        )


def test_simulated_spool_settles_at_eq46(default_params):
    currents = np.array([-1.5, -0.3, 0.05, 0.8, 2.0])
    out = run_batch([default_params] * len(currents), np.tile(currents, (200, 1)))
    expected = (
        default_params["coil_force_n_per_a"]
        * currents
        / (2 * default_params["spool_spring_n_per_m"])
    )
    np.testing.assert_allclose(out[-1, L.O_X_S], expected, rtol=1e-9)


def test_exhaust_path_is_the_supply_path_mirrored(default_params):
    """A_ex(x_s) = A_in(-x_s): with no rod (A2 = A1) at mid-stroke the actuator is symmetric,
    so a negative current does to chamber 2 what the positive one does to chamber 1."""
    p = load_parameters(rod_diameter_m=0.0, fixed_position_m=0.0)
    step = np.r_[np.full(30, 0.6), np.full(30, -0.2), np.full(40, 1.1)]
    out = run_batch([p, p], np.stack([step, -step], axis=1))
    np.testing.assert_allclose(out[:, L.O_P2, 1], out[:, L.O_P1, 0], rtol=1e-12)
    np.testing.assert_allclose(out[:, L.O_P1, 1], out[:, L.O_P2, 0], rtol=1e-12)
    np.testing.assert_allclose(out[:, L.O_X_S, 1], -out[:, L.O_X_S, 0], rtol=1e-12)
    assert out[:, L.O_P1, 0].max() > 3e5  # the step really charged the chamber


# --------------------------------------------------------------------------- tube (Eqs. 30-35)


def test_tube_resistance_laminar_turbulent_switch(default_params):
    d = default_params["tube_inner_diameter_m"]
    mu = default_params["air_viscosity_pa_s"]
    re_t = default_params["reynolds_turbulent"]
    assert re_t == 2300.0
    laminar = 32 * mu / d**2
    for re in (0.0, 100.0, 2000.0, float(np.nextafter(re_t, 0.0))):
        assert tube_resistance(re, d, mu, re_t) == pytest.approx(laminar, rel=1e-14)
    for re in (re_t, 5000.0, 4e4):
        assert tube_resistance(re, d, mu, re_t) == pytest.approx(
            0.158 * mu * re**0.75 / d**2, rel=1e-12
        )
    mdot = 5e-3
    assert reynolds_number(mdot, d, mu) == pytest.approx(4 * mdot / (math.pi * d * mu), rel=1e-14)
    assert reynolds_number(-mdot, d, mu) == reynolds_number(mdot, d, mu)


def test_tube_attenuation(default_params):
    p = default_params
    d, mu, re_t = p["tube_inner_diameter_m"], p["air_viscosity_pa_s"], p["reynolds_turbulent"]
    rt = p["gas_constant_j_per_kg_k"] * p["temperature_k"]
    assert tube_attenuation(5e-3, 4e5, rt, 0.0, d, mu, re_t) == 1.0  # zero length: no tube
    tau = 2.0 / _sound_speed(p)
    for mdot in (1e-5, 8e-3):  # laminar (Re about 0.2) and turbulent (Re about 176000)
        re = 4 * mdot / (math.pi * d * mu)
        r_t = 32 * mu / d**2 if re < re_t else 0.158 * mu * re**0.75 / d**2
        for pressure in (1.2e5, 6e5):
            expected = math.exp(-r_t * rt * tau / (2 * pressure))
            assert tube_attenuation(mdot, pressure, rt, tau, d, mu, re_t) == pytest.approx(
                expected, rel=1e-12
            )
            assert 0.0 < expected < 1.0
    assert sound_speed(K_AIR, R_AIR, 293.15) == pytest.approx(343.2, abs=0.05)


def test_tube_delay_is_length_over_sound_speed():
    """Rod clamped, 0.5 A step: the 2 m tube's first pressure rise lags the 0.5 m one by
    (1.5 m) / c = 4.37 ms (the paper's "about 5 ms")."""
    dt, n_sub = 1e-4, 2  # fine control period for timing; substep as the default 50 us
    params = [load_parameters(tube_length_m=length) for length in (0.5, 2.0)]
    out = run_batch(params, np.full(150, 0.5), control_dt_s=dt, substeps=n_sub)
    t = np.arange(1, 151) * dt
    pa = params[0]["ambient_pressure_pa"]
    rise = [first_crossing_time(t, out[:, L.O_P1, j], pa + 100.0) for j in range(2)]
    expected = 1.5 / _sound_speed(params[0])
    assert expected == pytest.approx(4.37e-3, abs=0.01e-3)
    assert rise[1] - rise[0] == pytest.approx(expected, abs=0.3e-3)


# --------------------------------------------------------------------------- chambers (Eq. 14)


@pytest.mark.parametrize("cylinder", CYLINDERS)
def test_closed_valve_moving_piston_is_polytropic(cylinder):
    """Valve closed (i = 0 is inside the overlap), no leakage: a load moves the piston and each
    chamber follows P V^alpha = const (Eq. 14 without flow)."""
    params = [
        load_parameters(cylinder, piston_mode="free", load_force_n=40.0),
        load_parameters(cylinder, piston_mode="free", load_force_n=-30.0, load_mass_kg=0.2),
        load_parameters(
            cylinder,
            piston_mode="spring",
            spring_stiffness_n_per_m=5000.0,
            spring_rest_position_m=0.02,
        ),
    ]
    p10, p20 = 3.0e5, 2.5e5
    out = run_batch(params, np.zeros(500), initial={"p1": p10, "p2": p20})
    for j, p in enumerate(params):
        assert p["leakage_area_m2"] == 0.0
        x = out[:, L.O_X, j]
        assert np.ptp(x) > 5e-3  # the piston really moved
        assert np.all(out[:, L.O_X_S, j] == 0.0)
        v1, v2 = volumes(p, x)
        v10, v20 = volumes(p, 0.0)
        alpha = p["alpha_motion"]
        np.testing.assert_allclose(out[:, L.O_P1, j] * v1**alpha, p10 * v10**alpha, rtol=1e-6)
        np.testing.assert_allclose(out[:, L.O_P2, j] * v2**alpha, p20 * v20**alpha, rtol=1e-6)


@pytest.mark.parametrize("cylinder,position", [("numatics", 0.01), ("airpel", -0.02)])
def test_leakage_conserves_mass_and_equalises(cylinder, position):
    """Closed valve, rod clamped, leakage between the chambers, alpha_in = alpha_out = 1:
    the air mass (P1 V1 + P2 V2) / (R T) is conserved and the pressures equalise."""
    p = load_parameters(
        cylinder, leakage_area_m2=5e-7, alpha_in=1.0, alpha_out=1.0, fixed_position_m=position
    )
    p10, p20 = 6e5, 1.5e5
    out = run_batch([p], np.zeros(500), initial={"p1": p10, "p2": p20})[:, :, 0]
    v1, v2 = volumes(p, position)
    mass = out[:, L.O_P1] * v1 + out[:, L.O_P2] * v2
    np.testing.assert_allclose(mass, p10 * v1 + p20 * v2, rtol=1e-12)
    assert out[0, L.O_P1] - out[0, L.O_P2] > 1e5  # not equal at once
    equal = (p10 * v1 + p20 * v2) / (v1 + v2)
    assert out[-1, L.O_P1] == pytest.approx(equal, rel=1e-9)
    assert out[-1, L.O_P2] == pytest.approx(equal, rel=1e-9)


# --------------------------------------------------------------------------- long random rollouts


def _all_configurations(coupling):
    sets = []
    for cyl in CYLINDERS:
        for length in (0.0, 0.5, 1.0, 2.0, 3.0):
            common = dict(tube_length_m=length, tube_coupling=coupling)
            sets += [
                load_parameters(cyl, piston_mode="fixed", fixed_position_m=0.02, **common),
                load_parameters(cyl, piston_mode="free", **common),
                load_parameters(
                    cyl,
                    piston_mode="spring",
                    spring_stiffness_n_per_m=3000.0,
                    spring_rest_position_m=-0.01,
                    **common,
                ),
            ]
    return sets


@pytest.mark.slow
@pytest.mark.parametrize("coupling", ["command", "literal"])
def test_random_rollouts_stay_physical(coupling):
    """Every cylinder x tube length x rod mode, 2 s of random currents in one batch: finite,
    pressures positive (never at the kernel's floor of 1e-3 P_a) and, with the default
    command coupling, below 1.5 P_s; the piston within the stroke.

    The literal coupling (Eq. 55 as printed) evaluates the valve flow with the chamber pressure
    of tau ago, so it can keep charging a chamber that is already above supply; with a moving
    piston its pressure peaks reach several times P_s (see model-notes), so only the
    numerical checks apply to it.
    """
    sets = _all_configurations(coupling)
    num = load_numerics()
    n_steps = int(round(2.0 / num["control_dt_s"]))
    currents = random_currents(np.random.default_rng(1), n_steps, len(sets))
    out = run_batch(sets, currents)
    assert np.all(np.isfinite(out))
    for j, p in enumerate(sets):
        pressures = out[:, [L.O_P1, L.O_P2], j]
        if coupling == "command":
            assert pressures.max() <= 1.5 * p["supply_pressure_pa"], j
        assert pressures.min() > 2e-3 * p["ambient_pressure_pa"], j
        x = out[:, L.O_X, j]
        assert np.all(np.abs(x) <= 0.5 * p["stroke_m"]), j
        if p["piston_mode"] == 0:
            assert np.all(x == p["fixed_position_m"])
        else:
            assert np.ptp(x) > 0.3 * p["stroke_m"], j  # the piston travelled


# --------------------------------------------------------------------------- the paper's facts


def test_long_tube_more_than_doubles_time_to_final_force():
    """Rod clamped at mid-stroke, 0.5 A step: the time to 95 % of the final force with the 2 m
    tube is more than twice that with the 0.5 m tube (paper Sec. 4)."""
    params = [load_parameters(tube_length_m=length, fixed_position_m=0.0) for length in (0.5, 2.0)]
    out = run_batch(params, np.full(300, 0.5))
    dt = load_numerics()["control_dt_s"]
    t = np.arange(1, 301) * dt
    f = out[:, L.O_F]
    a1 = areas(params[0])[0]
    p = params[0]
    for j in range(2):  # steady state: P1 = P_s, P2 = P_a, so F = (P_s - P_a) A1
        assert f[-1, j] == pytest.approx(
            (p["supply_pressure_pa"] - p["ambient_pressure_pa"]) * a1, rel=1e-4
        )
    t95 = [first_crossing_time(t, f[:, j], 0.95 * f[-1, j]) for j in range(2)]
    assert t95[1] > 2.0 * t95[0]


def test_literal_coupling_oscillates_near_supply():
    """tube_coupling = literal (Eq. 55 as printed) with the 2 m tube: the charged chamber keeps
    oscillating near supply pressure; the default command coupling settles."""
    params = [load_parameters(tube_length_m=2.0, tube_coupling=c) for c in ("command", "literal")]
    out = run_batch(params, np.full(300, 0.5))
    last = out[-50:, L.O_P1]
    swing = np.ptp(last, axis=0)
    ps = params[0]["supply_pressure_pa"]
    assert abs(last[:, 1].mean() - ps) < 0.05 * ps  # oscillation around supply
    assert swing[1] > 20e3
    assert swing[1] > 20 * swing[0] + 1e3


# --------------------------------------------------------------------------- the reference solution

SINE_CURRENT = 0.5 * np.sin(2 * np.pi * 5.0 * np.arange(400) * 1e-3)  # 5 Hz, 0.5 A, 0.4 s at 1 ms

CLAMPED = (("fixed_position_m", 0.0),)
FREE = (("piston_mode", "free"),)
REFERENCE_CASES = [
    pytest.param("numatics", CLAMPED + (("tube_length_m", 0.5),), "step", id="step-0.5m"),
    pytest.param("numatics", CLAMPED + (("tube_length_m", 2.0),), "step", id="step-2m"),
    pytest.param("numatics", FREE, "sine", id="sine-free-numatics"),
    pytest.param("airpel", FREE, "sine", id="sine-free-airpel"),
]


def _kernel_and_reference(cylinder, overrides, command):
    """(params, kernel outputs[step, O_*], reference dict) at the control-step ends."""
    pytest.importorskip("pneumatic_env.studies.reference_solution")
    return _solve_both(cylinder, overrides, command)


@functools.cache
def _solve_both(cylinder, overrides, command):
    from pneumatic_env.studies.reference_solution import simulate_reference

    num = load_numerics()
    assert num["control_dt_s"] == 1e-3
    p = load_parameters(cylinder, **dict(overrides))
    currents = np.full(100, 0.5) if command == "step" else SINE_CURRENT
    ref = simulate_reference(p, currents, num["control_dt_s"])
    out = run_batch([p], currents)[:, :, 0]
    return p, out, {k: np.asarray(v)[1:] for k, v in ref.items()}


def _errors(p, out, ref, mask=slice(None)):
    """Max errors as fractions of full scale: pressures (P_s - P_a), force (largest |f|),
    position (stroke)."""
    span = p["supply_pressure_pa"] - p["ambient_pressure_pa"]
    force_scale = np.abs(ref["f"]).max()
    return {
        "p1": np.abs(out[mask, L.O_P1] - ref["p1"][mask]).max() / span,
        "p2": np.abs(out[mask, L.O_P2] - ref["p2"][mask]).max() / span,
        "f": np.abs(out[mask, L.O_F] - ref["f"][mask]).max() / force_scale,
        "x": np.abs(out[mask, L.O_X] - ref["x"][mask]).max() / p["stroke_m"],
    }


@pytest.mark.parametrize("cylinder,overrides,command", REFERENCE_CASES)
def test_kernel_matches_reference_solution(cylinder, overrides, command):
    """Kernel at the default substeps vs the adaptive SciPy solution: within 0.1 % of full scale."""
    p, out, ref = _kernel_and_reference(cylinder, overrides, command)
    if command == "step":  # full scale of the force: the final force
        assert np.abs(ref["f"]).max() == pytest.approx(abs(ref["f"][-1]), rel=0.01)
    errors = _errors(p, out, ref)
    assert max(errors.values()) < 1e-3, errors


@pytest.mark.parametrize("cylinder", CYLINDERS)
def test_free_piston_matches_reference_away_from_end_stops(cylinder):
    """The 5 Hz free-piston run outside the 10 ms after each arrival at an end stop."""
    p, out, ref = _kernel_and_reference(cylinder, FREE, "sine")
    at_stop = np.abs(ref["x"]) >= 0.5 * p["stroke_m"]
    arrivals = np.flatnonzero(at_stop & ~np.r_[False, at_stop[:-1]])
    assert len(arrivals) >= 2  # the run does hit the stops
    mask = np.ones(len(at_stop), dtype=bool)
    for k in arrivals:
        mask[k : k + 10] = False
    errors = _errors(p, out, ref, mask)
    assert max(errors.values()) < 1e-3, errors


# --------------------------------------------------------------------------- determinism, batches


def _mixed_sets():
    return [
        load_parameters("numatics", tube_length_m=0.5),
        load_parameters("airpel", tube_length_m=2.0, piston_mode="free"),
        load_parameters(
            "numatics",
            tube_length_m=3.0,
            piston_mode="spring",
            spring_stiffness_n_per_m=4000.0,
            tube_coupling="literal",
        ),
        load_parameters("airpel", tube_length_m=0.0, leakage_area_m2=1e-7, fixed_position_m=-0.01),
        load_parameters(
            "numatics",
            tube_length_m=1.0,
            piston_mode="free",
            load_force_n=20.0,
            supply_pressure_pa=5e5,
        ),
    ]


def test_kernel_is_deterministic_and_batches_are_independent():
    sets = _mixed_sets()
    currents = random_currents(np.random.default_rng(7), 400, len(sets))
    batch = run_batch(sets, currents)
    assert np.array_equal(batch, run_batch(sets, currents))  # same inputs, same results
    for j, p in enumerate(sets):  # each env alone (its own, shorter delay buffer)
        alone = run_batch([p], currents[:, j])
        assert np.array_equal(alone[:, :, 0], batch[:, :, j]), j


@pytest.mark.slow
def test_step_by_step_serial_and_parallel_equal_rollout(numba_threads):
    sets = _mixed_sets()
    currents = random_currents(np.random.default_rng(8), 200, len(sets))
    rolled = run_batch(sets, currents)
    num = load_numerics()
    for parallel in (False, True):
        sim = BatchSimulator(
            parameter_array(sets), num["control_dt_s"], num["substeps"], parallel=parallel
        )
        stepped = np.stack([sim.step(np.ascontiguousarray(c)).copy() for c in currents])
        assert np.array_equal(stepped, rolled), parallel


def test_reset_restores_the_initial_run():
    sets = _mixed_sets()
    currents = random_currents(np.random.default_rng(9), 100, len(sets))
    num = load_numerics()
    sim = BatchSimulator(parameter_array(sets), num["control_dt_s"], num["substeps"])
    first = sim.rollout(currents)
    sim.reset()
    assert np.array_equal(sim.rollout(currents), first)


def test_reset_of_some_envs_restarts_them_and_leaves_the_others():
    """reset(envs) puts those columns (state, delay history, outputs, clock) where a fresh
    batch starts them and does not touch the other environments."""
    sets = _mixed_sets()
    currents = random_currents(np.random.default_rng(10), 60, len(sets))
    num = load_numerics()
    fresh = BatchSimulator(parameter_array(sets), num["control_dt_s"], num["substeps"])
    sim = BatchSimulator(parameter_array(sets), num["control_dt_s"], num["substeps"])
    sim.rollout(currents)
    before = {name: getattr(sim, name).copy() for name in ("state", "history", "outputs", "time_s")}
    chosen, others = [1, 3], [0, 2, 4]
    sim.reset(chosen)
    for name, old in before.items():
        new, start = getattr(sim, name), getattr(fresh, name)
        assert np.array_equal(new[..., others], old[..., others]), name
        assert np.array_equal(new[..., chosen], start[..., chosen]), name
        assert not np.array_equal(old[..., chosen], start[..., chosen]), name


# --------------------------------------------------------------------------- BatchSimulator errors


def test_batch_simulator_rejects_bad_params(default_params):
    good = parameter_array([default_params])
    with pytest.raises(ValueError) as err:
        BatchSimulator(good[:-1])
    assert str(err.value) == (
        f"params has {L.N_PARAMS - 1} rows, expected {L.N_PARAMS} "
        "(one per name in pneumatic_env.physics.layout.PARAMETER_NAMES)"
    )
    bad = np.repeat(good, 3, axis=1)
    bad[L.P_SUPPLY_PRESSURE_PA, 2] = np.nan
    with pytest.raises(ValueError) as err:
        BatchSimulator(bad)
    assert str(err.value) == "params[supply_pressure_pa] of environment 2 is nan, must be finite"
    bad[L.P_SUPPLY_PRESSURE_PA, 2] = default_params["supply_pressure_pa"]
    bad[L.P_TUBE_LENGTH_M, 1] = np.inf
    with pytest.raises(
        ValueError,
        match=r"^params\[tube_length_m\] of environment 1 is inf, "
        r"must be finite$",
    ):
        BatchSimulator(bad)
    with pytest.raises(ValueError, match=r"^control_dt_s = 0\.0 is not allowed: must be > 0$"):
        BatchSimulator(good, control_dt_s=0.0)
    with pytest.raises(
        ValueError,
        match=r"^n_substeps = 0 is not allowed: must be an integer "
        r">= 1$",
    ):
        BatchSimulator(good, n_substeps=0)
    sim = BatchSimulator(np.repeat(good, 2, axis=1))
    with pytest.raises(ValueError, match=r"^coil_current_a has shape \(5, 3\), expected \(5, 2\) "):
        sim.rollout(np.zeros((5, 3)))


def test_batch_simulator_rejects_bad_initial_state(default_params):
    sim = BatchSimulator(parameter_array([default_params]))
    with pytest.raises(ValueError) as err:
        sim.reset(initial={"p3": 2e5, "p1": 2e5})
    assert str(err.value) == (
        f"initial state key(s) ['p3'] not known; allowed: {list(INITIAL_STATE_KEYS)}"
    )
    with pytest.raises(ValueError) as err:
        sim.reset(initial={"p1": np.nan})
    assert str(err.value) == "initial['p1'] = nan must be finite"
    with pytest.raises(ValueError) as err:
        sim.reset(initial={"p2": 0.0})
    assert str(err.value) == "initial['p2'] = 0.0 must be > 0 Pa (absolute)"
    half = 0.5 * default_params["stroke_m"]
    with pytest.raises(ValueError) as err:
        sim.reset(initial={"x": 0.05})
    assert str(err.value) == (
        f"initial['x'] = 0.05 is outside the stroke: must be in [{-half}, {half}] m"
    )


def test_batch_simulator_rejects_bad_currents(default_params):
    sim = BatchSimulator(parameter_array([default_params] * 3))
    with pytest.raises(ValueError) as err:
        sim.rollout(np.full((4, 3), np.nan))
    assert str(err.value) == "coil_current_a contains nan: coil currents must be finite (A)"
    with pytest.raises(ValueError) as err:
        sim.step(np.zeros((3, 1)))
    assert str(err.value) == (
        "coil_current_a has shape (3, 1), expected (3,) (steps x "
        "environments for rollout, environments for step)"
    )
    with pytest.raises(ValueError, match=r"^coil_current_a has shape \(2,\), expected \(3,\)"):
        sim.step(np.zeros(2))
    before = sim.state.copy()
    with pytest.raises(ValueError):
        sim.step(np.array([0.1, np.inf, 0.0]))
    assert np.array_equal(sim.state, before)  # nothing advanced on bad input


# --------------------------------------------------------------------------- vectorised batch path

EPS = np.finfo(float).eps


def test_vectorisable_elementary_functions_match_the_c_library():
    """physics/vecmath.py replaces exp, log and acos so loops over environments vectorise."""
    rng = np.random.default_rng(0)
    x = np.r_[rng.uniform(-700.0, 700.0, 4000), rng.uniform(-1.0, 1.0, 4000), 0.0, -708.0, 709.0]
    np.testing.assert_allclose([vecmath.exp_(v) for v in x], np.exp(x), rtol=4 * EPS, atol=0)
    assert vecmath.exp_(0.0) == 1.0
    y = np.r_[np.exp(rng.uniform(-700.0, 700.0, 4000)), rng.uniform(0.5, 2.0, 4000), 1.0]
    np.testing.assert_allclose([vecmath.log_(v) for v in y], np.log(y), rtol=4 * EPS, atol=4 * EPS)
    assert vecmath.log_(1.0) == 0.0
    z = np.r_[rng.uniform(-1.0, 1.0, 8000), np.linspace(-1.0, 1.0, 101)]
    np.testing.assert_allclose([vecmath.acos_(v) for v in z], np.arccos(z), rtol=0, atol=4 * EPS)
    assert vecmath.acos_(1.0) == 0.0 and vecmath.acos_(-1.0) == math.pi


def _eligible_sets():
    """Parameter sets the batch path advances with ``base_derivatives``: every rod mode."""
    return [
        load_parameters("numatics", tube_length_m=2.0),
        load_parameters("airpel", tube_length_m=0.5, piston_mode="free", load_mass_kg=0.1),
        load_parameters(
            "numatics",
            tube_length_m=1.0,
            piston_mode="spring",
            spring_stiffness_n_per_m=4000.0,
            exhaust_discharge_ratio=0.8,
            tube_volume_fraction=1.0,
        ),
    ]


def test_base_model_rhs_equals_the_general_rhs():
    """With the spool overlapped and no effect that needs it, the two-path right-hand side
    of the batch path is the general one, bit for bit, over random states."""
    rng = np.random.default_rng(3)
    for p in _eligible_sets():
        c = kernel.env_constants(parameter_array([p]), 0, 2e-4)
        assert kernel.base_model_only(c)
        half = 0.5 * p["stroke_m"]
        for _ in range(400):
            x_s, spool_delayed = rng.uniform(-1.5e-3, 1.5e-3, 2)
            p1, p2 = rng.uniform(2e4, 7e5, 2)
            x, v = rng.uniform(-half, half), rng.uniform(-0.5, 0.5)
            direction = float(rng.integers(-1, 2)) if p["piston_mode"] != "fixed" else 0.0
            coil, v_s = rng.uniform(-2.0, 2.0), rng.uniform(-0.2, 0.2)
            base = kernel.base_derivatives(
                c, coil, x_s, v_s, p1, p2, x, v, direction, spool_delayed
            )
            y = (x_s, v_s, p1, p2, x, v, 0.0, c.temperature, c.temperature)
            valve = (spool_delayed, p1, p2)
            general = kernel.derivatives(c, coil, y, direction, valve, (p1, p2), c.ambient_pa)
            assert base == general


def test_batch_path_reproduces_the_general_path_bit_for_bit():
    """BatchSimulator.step (vectorised lanes, general path for stiff substeps and piston
    events) against kernel.advance_env (the general path alone), env by env."""
    sets = _eligible_sets()
    currents = random_currents(np.random.default_rng(11), 300, len(sets))
    moved = assert_batch_matches_general_path(sets, currents)
    assert moved  # the free and spring rods really moved (events, stops, sticking)


def test_vectorised_delay_reads_equal_delayed_value_bit_for_bit():
    """The batch path's branch-free ring-buffer reads (``batch_path.delayed_spool_rows``)
    against ``kernel.delayed_value``, at every head slot (wrapping ends included) and for
    delays from exactly one substep (the read at head + 1 is the start's own value) to
    the longest the ring holds: lanes with delays of their own (gathers), and lanes that
    share one delay (contiguous rows), which ``lanes_share_delay`` tells apart."""
    rng = np.random.default_rng(5)
    n_slots, n = 9, kernel.CHUNK_ENVS
    history = rng.normal(size=(n_slots, L.N_HISTORY, n))
    mixed = np.concatenate(
        [[1.0, 2.0, 3.0, 1.5, float(n_slots - 2)], rng.uniform(1.0, n_slots - 2, n - 5)]
    )
    cases = [(mixed, False)] + [(np.full(n, d), True) for d in (1.0, 2.0, 1.5, 3.7, n_slots - 2.0)]
    for delays, same in cases:
        constants = np.zeros(kernel.N_CACHED_CONSTANTS * n)
        constants[kernel.C_DELAY_SUBSTEPS * n : (kernel.C_DELAY_SUBSTEPS + 1) * n] = delays
        assert batch_path.lanes_share_delay(constants, n) == same
        work = np.zeros(kernel.N_WORK * n)
        work[kernel.W_START * n : (kernel.W_START + 1) * n] = start = rng.normal(size=n)
        for head in range(n_slots):
            batch_path.delayed_spool_rows(constants, work, history, 0, n, head, same)
            for stage in range(3):
                row = kernel.W_SPOOL_DELAYED + stage
                want = [
                    kernel.delayed_value(
                        history, j, L.H_X_S, head, 0.5 * stage, delays[j], start[j], start[j]
                    )
                    for j in range(n)
                ]
                np.testing.assert_array_equal(work[row * n : (row + 1) * n], want)


def test_parameters_change_through_set_parameter_and_nowhere_else():
    """``BatchSimulator.params`` is read-only; ``set_parameter`` changes one parameter from
    the next step on: the kernel's cached constants are then those of the new column, and
    the run goes on as a batch built with the new value from the same state does."""
    base = load_parameters(tube_length_m=0.5)
    sim = BatchSimulator(parameter_array([base, base]), 1e-3, 5, parallel=False)
    with pytest.raises(ValueError, match="read-only"):
        sim.params[L.P_SUPPLY_PRESSURE_PA, 0] = 4e5
    currents = 0.6 * np.sin(np.arange(40) * 0.3)
    for k in range(20):
        sim.step(np.full(2, currents[k]))
    changed = BatchSimulator(
        parameter_array([base, load_parameters(tube_length_m=0.5, supply_pressure_pa=4e5)]),
        1e-3,
        5,
        parallel=False,
    )
    changed.state[:], changed.history[:], changed.head = sim.state, sim.history, sim.head
    sim.set_parameter("supply_pressure_pa", 1, 4e5)
    for k in range(20, 40):
        np.testing.assert_array_equal(
            sim.step(np.full(2, currents[k])), changed.step(np.full(2, currents[k]))
        )
    h = 1e-3 / 5
    cached = sim.constants[0].reshape(kernel.N_CACHED_CONSTANTS, kernel.CHUNK_ENVS)
    for env in range(2):
        fresh = np.zeros(kernel.N_CACHED_CONSTANTS * kernel.CHUNK_ENVS)
        kernel.store_constants(kernel.env_constants(sim.params, env, h), fresh, env)
        fresh = fresh.reshape(kernel.N_CACHED_CONSTANTS, kernel.CHUNK_ENVS)
        np.testing.assert_array_equal(
            cached[: kernel.N_CONSTANTS, env], fresh[: kernel.N_CONSTANTS, env]
        )
    # a parameter of the tube delay goes through set_params (the buffer grows)
    slots = sim.history.shape[0]
    sim.set_parameter("tube_length_m", [0], 3.0)
    assert sim.history.shape[0] > slots and sim.params[L.P_TUBE_LENGTH_M, 0] == 3.0
    with pytest.raises(ValueError) as err:
        sim.set_parameter("supply_pressure", 0, 4e5)
    assert str(err.value) == (
        "set_parameter: name = 'supply_pressure' is not a parameter; "
        "allowed: the names in pneumatic_env.physics.layout."
        "PARAMETER_NAMES"
    )
    with pytest.raises(ValueError) as err:
        sim.set_parameter("load_force_n", 0, np.inf)
    assert str(err.value) == "set_parameter: load_force_n = inf is not allowed: must be finite"


def test_a_longer_tube_grows_the_delay_buffer_without_disturbing_the_others():
    """``set_params`` with a tube longer than the ring buffer holds grows the buffer; the
    other environments go on bit for bit as if nothing had changed (their history is kept
    in order, newest sample at the head)."""
    short = load_parameters(tube_length_m=0.5)
    grown = BatchSimulator(parameter_array([short, short]), 1e-3, 5, parallel=False)
    alone = BatchSimulator(parameter_array([short, short]), 1e-3, 5, parallel=False)
    currents = 0.6 * np.sin(np.arange(60) * 0.3)
    for k in range(30):
        grown.step(np.full(2, currents[k]))
        alone.step(np.full(2, currents[k]))
    slots = grown.history.shape[0]
    grown.set_params([0], parameter_array([load_parameters(tube_length_m=3.0)]))
    grown.reset([0])
    assert grown.history.shape[0] > slots
    for k in range(30, 60):
        grown.step(np.full(2, currents[k]))
        alone.step(np.full(2, currents[k]))
        np.testing.assert_array_equal(grown.outputs[:, 1], alone.outputs[:, 1])


@pytest.mark.parametrize("current_a", [0.6, -0.6])
@pytest.mark.parametrize("cylinder", ["numatics", "airpel"])
def test_free_rod_pushed_onto_a_stop_rests_exactly_on_it(cylinder, current_a):
    """A free rod driven hard to an end stop rests on the stop itself (inelastic stop), not
    picometres short of it with its velocity zeroed; and it stays there while pushed.

    A rod left just short, at rest and pushed on, met the same stop event again at every
    later substep (issue 34: a free rod resting on a stop cost the general path five RK4
    steps per substep)."""
    p = load_parameters(cylinder, tube_length_m=0.5, piston_mode="free", load_mass_kg=0.5)
    half = 0.5 * p["stroke_m"]
    num = load_numerics()
    sim = BatchSimulator(parameter_array([p]), num["control_dt_s"], num["substeps"])
    pushed_for = 0
    for _ in range(1500):  # 0.3 s of a steady push
        sim.step(np.array([current_a]))
        x = float(sim.outputs[L.O_X, 0])
        if abs(x) > half - 1e-6:  # arrived
            assert x == math.copysign(half, current_a)
            assert float(sim.outputs[L.O_V, 0]) == 0.0
            pushed_for += 1
    assert pushed_for > 500  # it arrived early and stayed
