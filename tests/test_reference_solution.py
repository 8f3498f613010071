"""Tests of the high-accuracy reference solution (studies/reference_solution/).

The parameter set is built here from the reference table (Numatics cylinder) so the tests
do not depend on the config loader.
"""

import math

import numpy as np
import pytest

from pneumatic_env.studies.reference_solution import (
    NEUTRAL_EFFECTS,
    ModelConstants,
    chamber_volumes,
    flow_constants,
    orifice_area,
    orifice_mass_flow,
    pneumatic_force,
    reduced_flow,
    simulate_reference,
)

SOUND_SPEED = math.sqrt(1.4 * 287.0 * 293.15)  # 343.2 m/s


def numatics(**overrides) -> dict:
    p = dict(
        gas_constant_j_per_kg_k=287.0,
        heat_capacity_ratio=1.4,
        temperature_k=293.15,
        ambient_pressure_pa=101325.0,
        supply_pressure_pa=6.5e5,
        air_viscosity_pa_s=1.81e-5,
        alpha_in=1.4,
        alpha_out=1.0,
        alpha_motion=1.2,
        spool_mass_kg=0.010,
        spool_damping_n_s_per_m=7.5,
        spool_spring_n_per_m=1000.0,
        coil_force_n_per_a=2.78,
        coil_current_max_a=2.0,
        discharge_coefficient=0.25,
        hole_radius_m=0.8e-3,
        spool_half_width_m=0.9e-3,
        holes_per_path=14.0,
        tube_length_m=0.5,
        tube_inner_diameter_m=3.2e-3,
        reynolds_turbulent=2300.0,
        tube_coupling=0.0,
        bore_diameter_m=19.05e-3,
        rod_diameter_m=6.35e-3,
        stroke_m=76.2e-3,
        dead_volume_cap_m3=1.0e-6,
        dead_volume_rod_m3=1.0e-6,
        piston_mass_kg=0.05,
        static_friction_n=3.8,
        dynamic_friction_n=0.486,
        viscous_friction_n_s_per_m=4.47,
        leakage_area_m2=0.0,
        piston_mode=0.0,
        fixed_position_m=0.0,
        load_mass_kg=0.0,
        load_force_n=0.0,
        spring_stiffness_n_per_m=0.0,
        spring_rest_position_m=0.0,
        flow_linear_ratio=0.995,
    )
    p.update(overrides)
    return p


def rel_err(a, b):
    return float(np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-300))


def test_parameter_names_match_layout():
    from pneumatic_env.physics.layout import PARAMETER_NAMES

    # the paper's parameters are layout names; the rest of the layout are the effects
    # beyond the paper (docs/effects.md), which the reference accepts only when neutral
    assert set(numatics()) <= set(PARAMETER_NAMES)
    assert set(NEUTRAL_EFFECTS) <= set(PARAMETER_NAMES)
    extra = set(PARAMETER_NAMES) - set(numatics()) - set(NEUTRAL_EFFECTS)
    assert extra <= {"iso_critical_ratio_b"}  # used only with flow_law = 1


def test_effects_beyond_the_paper_must_be_neutral():
    p = numatics(**NEUTRAL_EFFECTS)
    p["iso_critical_ratio_b"] = 0.3
    r = simulate_reference(p, np.full(5, 0.5), 1e-3)
    ref = simulate_reference(numatics(), np.full(5, 0.5), 1e-3)
    np.testing.assert_array_equal(r["p1"], ref["p1"])
    with pytest.raises(NotImplementedError):
        simulate_reference(numatics(coil_time_constant_s=0.005), np.zeros(3), 1e-3)


def test_sub_models():
    m = ModelConstants.from_params(numatics())
    c1, c2, p_cr = flow_constants(1.4, 287.0)
    assert c1 == pytest.approx(0.040418, abs=2e-6)
    assert c2 == pytest.approx(0.156174, abs=2e-6)
    assert p_cr == pytest.approx(0.5283, abs=1e-4)
    # reduced flow: continuous at P_cr and at the linearisation ratio, zero at r = 1
    assert reduced_flow(m, p_cr * (1 + 1e-12)) == pytest.approx(c1, rel=1e-9)
    r = m.r_lin
    assert reduced_flow(m, r + 1e-12) == pytest.approx(reduced_flow(m, r - 1e-12), rel=1e-6)
    assert reduced_flow(m, 1.0) == 0.0
    # areas: dead band, full opening, A_ex(x) = A_in(-x)
    assert orifice_area(m, 0.0) == 0.0
    assert orifice_area(m, 0.099e-3) == 0.0
    assert orifice_area(m, -0.5e-3) == 0.0
    assert orifice_area(m, 0.101e-3) > 0.0
    full = math.pi * 14 * (0.8e-3) ** 2
    assert orifice_area(m, 5e-3) == pytest.approx(full)
    assert orifice_area(m, 0.1e-3 + 0.8e-3) == pytest.approx(full / 2)  # half a hole
    # flow is antisymmetric and about 10.8 g/s choked at full opening
    assert orifice_mass_flow(m, full, 6.5e5, 1e5) == pytest.approx(10.8e-3, rel=0.02)
    assert orifice_mass_flow(m, full, 1e5, 6.5e5) == -orifice_mass_flow(m, full, 6.5e5, 1e5)


def test_closed_chambers_follow_polytropic_law():
    """Valve closed (i_c = 0, inside the dead band): no flow, so each chamber keeps
    P V^alpha constant (alpha = alpha_motion) while a spring pushes the piston, which
    slides, oscillates and finally sticks."""
    p = numatics(piston_mode=2.0, spring_stiffness_n_per_m=500.0, spring_rest_position_m=-0.02)
    r = simulate_reference(p, np.zeros(80), 1e-3)
    m = ModelConstants.from_params(p)
    assert r["x"].min() < -5e-3  # the piston really moved
    v1, v2 = chamber_volumes(m, r["x"])
    for pres, vol in ((r["p1"], v1), (r["p2"], v2)):
        inv = pres * vol**1.2
        assert np.ptp(inv) / inv[0] < 1e-8
    np.testing.assert_array_equal(r["x_s"], 0.0)
    # stuck at the end: static friction holds the residual force, and f is the spring force
    assert np.all(r["v"][-10:] == 0.0)
    assert np.ptp(r["x"][-10:]) == 0.0
    x_end = r["x"][-1]
    residual = pneumatic_force(m, r["p1"][-1], r["p2"][-1]) - 500.0 * (x_end + 0.02)
    assert abs(residual) <= 3.8
    assert r["f"][-1] == pytest.approx(500.0 * (x_end + 0.02))


def test_fixed_rod_step_reaches_supply_force():
    p = numatics(tube_length_m=0.5)
    r = simulate_reference(p, np.full(100, 0.5), 1e-3)
    m = ModelConstants.from_params(p)
    assert r["p1"][-1] == pytest.approx(6.5e5, rel=2e-3)
    assert r["p2"][-1] == pytest.approx(101325.0, rel=2e-3)
    f_final = 6.5e5 * m.a1 - 101325.0 * m.a2 - 101325.0 * m.a_r
    assert r["f"][-1] == pytest.approx(f_final, rel=0.01)
    np.testing.assert_array_equal(r["x"], 0.0)
    # the spool settles at K_fc i / (2 k_s) (Eq. 46)
    assert r["x_s"][-1] == pytest.approx(2.78 * 0.5 / 2000.0, rel=1e-6)


@pytest.mark.parametrize("tube_length", [0.5, 2.0])
def test_converged_fixed_rod(tube_length):
    p = numatics(tube_length_m=tube_length)
    a = simulate_reference(p, np.full(60, 0.5), 1e-3, rtol=1e-8)
    b = simulate_reference(p, np.full(60, 0.5), 1e-3, rtol=1e-10)
    for key in ("p1", "p2", "f"):
        assert rel_err(a[key], b[key]) < 1e-6, key


def test_converged_free_piston_stick_slip_and_end_stop():
    t = np.arange(250) * 1e-3
    current = 0.4 * np.sin(2 * np.pi * 5 * t)
    p = numatics(piston_mode=1.0)
    a = simulate_reference(p, current, 1e-3, rtol=1e-8)
    b = simulate_reference(p, current, 1e-3, rtol=1e-10)
    for key in ("p1", "p2", "x", "v", "f"):
        assert rel_err(a[key], b[key]) < 1e-6, key
    half = 0.5 * 76.2e-3
    assert np.all(np.abs(b["x"]) <= half)
    at_stop = b["x"] == half
    assert at_stop.sum() > 5  # rests at the end stop ...
    assert np.all(b["v"][at_stop] == 0.0)
    assert b["x"][-1] < half  # ... and leaves it again


def test_converged_literal_coupling():
    p = numatics(tube_length_m=2.0, tube_coupling=1.0)
    a = simulate_reference(p, np.full(60, 0.5), 1e-3, rtol=1e-8)
    b = simulate_reference(p, np.full(60, 0.5), 1e-3, rtol=1e-10)
    for key in ("p1", "f"):
        assert rel_err(a[key], b[key]) < 1e-6, key


def test_long_tube_adds_acoustic_delay():
    def first_rise(tube_length):
        dt = 1e-4
        r = simulate_reference(numatics(tube_length_m=tube_length), np.full(120, 0.5), dt)
        thr = 101325.0 + 1000.0
        k = int(np.argmax(r["p1"] > thr))
        assert k > 0
        p0, p1 = r["p1"][k - 1], r["p1"][k]
        return r["t"][k - 1] + (thr - p0) / (p1 - p0) * dt

    extra = first_rise(2.0) - first_rise(0.5)
    assert extra == pytest.approx((2.0 - 0.5) / SOUND_SPEED, abs=0.3e-3)


def test_initial_state_and_validation():
    p = numatics(piston_mode=1.0, load_force_n=5.0)
    r = simulate_reference(p, np.zeros(5), 1e-3, initial={"p1": 3e5, "p2": 2e5, "x": 0.01})
    assert r["p1"][0] == 3e5 and r["x"][0] == 0.01 and r["v"][0] == 0.0
    assert r["t"].shape == (6,)
    with pytest.raises(KeyError):
        simulate_reference(p, np.zeros(5), 1e-3, initial={"pressure": 1e5})
    with pytest.raises(ValueError):
        simulate_reference(numatics(), np.zeros(5), 1e-3, initial={"x": 0.01})
