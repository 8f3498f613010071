"""The derived physical quantities (pneumatic_env/physics/derived.py): each against the
paper's formula written out here, and the kernel's constants against them bit for bit
(the kernel and the Python callers share one computation)."""

from __future__ import annotations

import math

import pytest

from pneumatic_env.params import load_parameters, parameter_array
from pneumatic_env.physics import derived, kernel
from pneumatic_env.physics.flow import FLOW_LAW_ISO, flow_constants, reduced_flow
from pneumatic_env.simulator import BatchSimulator

CYLINDERS = ("numatics", "airpel")


@pytest.mark.parametrize("cylinder", CYLINDERS)
def test_piston_areas_are_eq_1s(cylinder):
    p = load_parameters(cylinder)
    cap, rod_side, rod = derived.piston_areas_m2(p["bore_diameter_m"], p["rod_diameter_m"])
    assert cap == pytest.approx(math.pi / 4 * p["bore_diameter_m"] ** 2, rel=1e-15)
    assert rod == pytest.approx(math.pi / 4 * p["rod_diameter_m"] ** 2, rel=1e-15)
    assert rod_side == cap - rod
    assert derived.circle_area_m2(p["bore_diameter_m"]) == cap


def test_numatics_areas_in_square_millimetres():
    """The Numatics cylinder: 19.05 mm bore, 6.35 mm rod (3/4 and 1/4 inch)."""
    cap, rod_side, rod = derived.piston_areas_m2(19.05e-3, 6.35e-3)
    assert (cap * 1e6, rod_side * 1e6, rod * 1e6) == pytest.approx(
        (285.02, 253.35, 31.669), abs=0.01
    )


@pytest.mark.parametrize("cylinder", CYLINDERS)
def test_force_scale_is_the_weaker_direction(cylinder):
    p = load_parameters(cylinder)
    span = p["supply_pressure_pa"] - p["ambient_pressure_pa"]
    cap, rod_side, _ = derived.piston_areas_m2(p["bore_diameter_m"], p["rod_diameter_m"])
    scale = derived.force_scale_n(
        p["supply_pressure_pa"], p["ambient_pressure_pa"], p["bore_diameter_m"], p["rod_diameter_m"]
    )
    assert scale == span * rod_side < span * cap  # the rod side pulls less than the cap pushes
    # a rod thicker than the bore / sqrt(2) would make the push the weaker direction
    assert derived.force_scale_n(5e5, 1e5, 0.02, 0.0) == pytest.approx(4e5 * math.pi * 1e-4)


def test_valve_currents_of_the_default_valve():
    """Dead band (p_w - R_h) 2 k_s / K_fc and full opening (p_w + R_h) 2 k_s / K_fc (Eqs. 43,
    44, 46): the default 0.1 mm overlap is a dead band of about 0.07 A (configs/valve.yaml)."""
    p = load_parameters()
    pw, rh = p["spool_half_width_m"], p["hole_radius_m"]
    per_metre = 2.0 * p["spool_spring_n_per_m"] / p["coil_force_n_per_a"]
    dead_band, full = derived.valve_currents_a(
        pw, rh, p["spool_spring_n_per_m"], p["coil_force_n_per_a"]
    )
    assert dead_band == pytest.approx((pw - rh) * per_metre, rel=1e-14)
    assert full == pytest.approx((pw + rh) * per_metre, rel=1e-14)
    assert 0.065 < dead_band < 0.075 and full > dead_band
    # no overlap, no dead band
    assert (
        derived.valve_currents_a(rh, rh, p["spool_spring_n_per_m"], p["coil_force_n_per_a"])[0]
        == 0.0
    )
    assert (
        derived.valve_currents_a(0.5 * rh, rh, p["spool_spring_n_per_m"], p["coil_force_n_per_a"])[
            0
        ]
        == 0.0
    )


def test_orifice_gas_constants_of_air():
    """1/sqrt(T), k, C1, C2, P_cr (Eq. 40: 0.040418, 0.156174, 0.528 for air) and the slope
    of the linearised Eq. 52, which meets the subsonic branch at the linear ratio."""
    gas = derived.orifice_gas_constants(1.4, 287.0, 293.15, 0.995)
    assert isinstance(gas, derived.OrificeGas)
    k, c1, c2, p_cr, r_lin, slope = gas[1:]  # the fields in orifice_mass_flow's order
    assert (gas.k, gas.c1, gas.c2, gas.critical_ratio) == (k, c1, c2, p_cr)
    assert (gas.linear_ratio, gas.linear_slope) == (r_lin, slope)
    assert gas.inv_sqrt_t == 1.0 / math.sqrt(293.15) and k == 1.4 and r_lin == 0.995
    assert (c1, c2, p_cr) == flow_constants(1.4, 287.0)
    assert (c1, c2, p_cr) == pytest.approx((0.040418, 0.156174, 0.528), abs=5e-4)
    subsonic = c2 * r_lin ** (1 / k) * math.sqrt(1 - r_lin ** ((k - 1) / k))
    assert slope == pytest.approx(subsonic / (1 - r_lin), rel=1e-12)
    assert reduced_flow(r_lin, k, c1, c2, p_cr, r_lin, slope) == pytest.approx(
        slope * (1 - r_lin), rel=1e-12
    )


def test_iso_linear_slope_meets_the_ellipse():
    c1, c2, _ = flow_constants(1.4, 287.0)
    b, r_lin = 0.4, 0.99
    slope = derived.linear_flow_slope(r_lin, 1.4, c1, c2, b, FLOW_LAW_ISO)
    ellipse = c1 * math.sqrt(1 - ((r_lin - b) / (1 - b)) ** 2)
    assert slope == pytest.approx(ellipse / (1 - r_lin), rel=1e-12)


def test_tube_delay_of_a_2_m_tube():
    """tau = L_t / sqrt(k R T) (Eq. 31): 2 m of tube at 20 C is 5.8 ms."""
    tau = derived.tube_delay_s(2.0, 1.4, 287.0, 293.15)
    assert tau == 2.0 / math.sqrt(1.4 * 287.0 * 293.15)
    assert tau == pytest.approx(5.83e-3, abs=1e-5)


@pytest.mark.parametrize(
    "overrides",
    [
        {"cylinder": "numatics", "tube_length_m": 2.0},
        {
            "cylinder": "airpel",
            "tube_length_m": 0.5,
            "flow_law": "iso6358",
            "iso_critical_ratio_b": 0.45,
        },
    ],
)
def test_kernel_constants_are_the_derived_quantities(overrides):
    """The kernel takes its areas, delay and gas constants from derived.py, bit for bit; so
    does BatchSimulator's delay (the ring buffer's length)."""
    p = load_parameters(**overrides)
    params = parameter_array([p])
    c = kernel.env_constants(params, 0, 5e-5)
    assert (c.area_cap, c.area_rod, c.rod_area) == derived.piston_areas_m2(
        p["bore_diameter_m"], p["rod_diameter_m"]
    )
    delay = derived.tube_delay_s(
        p["tube_length_m"],
        p["heat_capacity_ratio"],
        p["gas_constant_j_per_kg_k"],
        p["temperature_k"],
    )
    assert c.delay_s == delay
    assert BatchSimulator(params, 1e-3, 20).delays_s()[0] == delay
    assert (c.c1, c.c2) == flow_constants(p["heat_capacity_ratio"], p["gas_constant_j_per_kg_k"])[
        :2
    ]
    iso = p["flow_law"] == FLOW_LAW_ISO
    assert c.critical_ratio == (
        p["iso_critical_ratio_b"]
        if iso
        else flow_constants(p["heat_capacity_ratio"], p["gas_constant_j_per_kg_k"])[2]
    )
    assert c.linear_slope == derived.linear_flow_slope(
        p["flow_linear_ratio"],
        p["heat_capacity_ratio"],
        c.c1,
        c.c2,
        c.critical_ratio,
        int(p["flow_law"]),
    )
    if not iso:
        assert (
            c.inv_sqrt_t,
            c.k,
            c.c1,
            c.c2,
            c.critical_ratio,
            c.linear_ratio,
            c.linear_slope,
        ) == derived.orifice_gas_constants(
            p["heat_capacity_ratio"],
            p["gas_constant_j_per_kg_k"],
            p["temperature_k"],
            p["flow_linear_ratio"],
        )


def test_python_callers_share_the_derived_quantities():
    """The env's force scale and the controllers' valve currents are derived.py's."""
    from pneumatic_env.agents.base import valve_currents
    from pneumatic_env.envs.tasks import force_scale

    p = load_parameters("airpel")
    assert force_scale(p) == derived.force_scale_n(
        p["supply_pressure_pa"], p["ambient_pressure_pa"], p["bore_diameter_m"], p["rod_diameter_m"]
    )
    assert valve_currents(p) == derived.valve_currents_a(
        p["spool_half_width_m"],
        p["hole_radius_m"],
        p["spool_spring_n_per_m"],
        p["coil_force_n_per_a"],
    )
