"""Effects beyond the paper's model (docs/effects.md): off at their neutral value, and each
does what its physics says."""

import math

import gymnasium as gym
import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

import pneumatic_env  # noqa: F401  (registers the environments)
from conftest import areas, run_batch
from pneumatic_env.params import ConfigError, load_parameters, parameter_array, parameter_info
from pneumatic_env.physics import effects as E
from pneumatic_env.physics import kernel
from pneumatic_env.physics import layout as L
from pneumatic_env.physics.flow import (
    flow_constants,
    orifice_mass_flow,
    reduced_flow,
    subsonic_reduced_flow,
)
from pneumatic_env.physics.valve import orifice_area, steady_spool_position
from pneumatic_env.simulator import BatchSimulator

NEUTRAL = L.EFFECT_NEUTRAL_VALUES
# one setting per effect that switches it on
ON = {
    "tube_volume_fraction": {"tube_volume_fraction": 1.0},
    "tube_air_model": {"tube_volume_fraction": 1.0, "tube_air_model": "isothermal"},
    "rod_seal_leak_area_m2": {"rod_seal_leak_area_m2": 2e-8},
    "valve_null_leak_area_m2": {"valve_null_leak_area_m2": 5e-8},
    "exhaust_discharge_ratio": {"exhaust_discharge_ratio": 0.6},
    "flow_law": {"flow_law": "iso6358", "iso_critical_ratio_b": 0.3},
    "supply_resistance_pa_s_per_kg": {"supply_resistance_pa_s_per_kg": 5e6},
    "coil_time_constant_s": {"coil_time_constant_s": 0.005},
    "coil_lag_shape": {"coil_time_constant_s": 0.005, "coil_lag_shape": 0.2},
    "wall_heat_transfer_w_per_k": {"wall_heat_transfer_w_per_k": 0.05},
    "stribeck_velocity_m_per_s": {"stribeck_velocity_m_per_s": 0.02},
    "spool_coulomb_friction_n": {"spool_coulomb_friction_n": 0.1},
    "tube_waves": {"tube_waves": "transmission_line"},
    "exhaust_vent_area_m2": {"exhaust_vent_area_m2": 2e-6},
    "exhaust_volume_m3": {"exhaust_vent_area_m2": 2e-6, "exhaust_volume_m3": 1e-5},
    "lugre_stiffness_n_per_m": {"lugre_stiffness_n_per_m": 1e5},
    "lugre_damping_n_s_per_m": {"lugre_stiffness_n_per_m": 1e5, "lugre_damping_n_s_per_m": 300.0},
    "leakage_conductance_kg_per_pa_s": {"leakage_conductance_kg_per_pa_s": 3e-11},
}
T_S = 293.15


def _constants(**overrides):
    """Kernel constants of one environment (substep of the default numerics)."""
    return kernel.env_constants(parameter_array(load_parameters(**overrides)), 0, 5e-5)


def _sim(param_sets, initial=None):
    sim = BatchSimulator(parameter_array(list(param_sets)), 1e-3, 20, parallel=False)
    sim.reset(initial=initial)
    return sim


# --------------------------------------------------------------------------- configs


def test_defaults_are_neutral_and_documented():
    values = load_parameters()
    for name, neutral in NEUTRAL.items():
        assert values[name] == neutral, name
        info = parameter_info(name)
        assert info["file"].endswith("effects.yaml")
        assert info["source"].startswith("assumed: ")
    assert parameter_info("flow_law")["names"] == {0: "paper", 1: "iso6358"}
    assert load_parameters(flow_law="iso6358")["flow_law"] == 1.0
    with pytest.raises(
        ConfigError,
        match=r"override 'coil_time_constant_s' = -0.001 is not "
        r"allowed: must be in \[0.0, 1.0\] s",
    ):
        load_parameters(coil_time_constant_s=-0.001)


def test_neutral_sub_models_return_the_paper_quantity_exactly():
    assert E.dead_volume_with_tube(1.0e-6, 0.0, 3.2e-3, 2.0) == 1.0e-6
    assert E.drooped_supply_pressure(6.5e5, 0.0108, 0.0) == 6.5e5
    assert E.lagged_coil_current(0.7, -0.3, E.coil_decay(0.0, 5e-5)) == 0.7
    assert E.spool_play_current(-0.3, 0.7, E.spool_play_band(0.0, 2.78)) == 0.7
    c1, c2, p_cr = flow_constants(1.4, 287.0)
    slope = subsonic_reduced_flow(0.995, 1.4, c2) / 0.005
    for r in (0.3, 0.6, 0.9, 0.998):
        assert reduced_flow(r, 1.4, c1, c2, p_cr, 0.995, slope, 0) == reduced_flow(
            r, 1.4, c1, c2, p_cr, 0.995, slope
        )


def test_effects_switch_per_environment():
    """A neutral column of a batch with every effect on elsewhere is the lone default run,
    bit for bit; every effect changes its own column."""
    base = dict(piston_mode="free", tube_length_m=2.0)
    sets = [load_parameters(**base)] + [load_parameters(**base, **on) for on in ON.values()]
    t = np.arange(150) * 1e-3
    currents = 0.9 * np.sin(2 * np.pi * 10 * t)
    initial = {"p2": 3e5}
    batch = run_batch(sets, currents, initial=initial)
    alone = run_batch(sets[:1], currents, initial=initial)
    np.testing.assert_array_equal(batch[:, :, :1], alone)
    for j, name in enumerate(ON, start=1):
        assert not np.array_equal(batch[:, :, j], alone[:, :, 0]), name


def test_effect_through_gym_make():
    env = gym.make("pneumatic_env/ForceTrack-Numatics-0.5m-v0", coil_time_constant_s=0.005)
    env.reset(seed=0)
    sim = env.unwrapped.core.sim
    assert sim.params[L.P_COIL_TIME_CONSTANT_S, 0] == 0.005
    for _ in range(3):
        obs, reward, terminated, truncated, info = env.step(np.ones(env.action_space.shape))
    assert np.all(np.isfinite(obs)) and np.isfinite(reward)
    i_max = sim.params[L.P_COIL_CURRENT_MAX_A, 0]
    # after 3 ms of a constant command the lagged current is 1 - exp(-3/5) = 45 % of it
    assert 0.0 < abs(sim.state[L.S_COIL, 0]) < 0.5 * i_max
    env.close()


# --------------------------------------------------------------------------- 1 tube volume


def test_tube_volume_adds_whole_tube_to_each_dead_volume():
    p = load_parameters(tube_length_m=2.0)
    tube = math.pi / 4 * p["tube_inner_diameter_m"] ** 2 * 2.0
    assert tube == pytest.approx(16.1e-6, rel=0.01)  # model-notes: a 2 m tube holds ~16 cm^3
    with_fraction = load_parameters(tube_length_m=2.0, tube_volume_fraction=1.0)
    bigger_dead = load_parameters(
        tube_length_m=2.0,
        dead_volume_cap_m3=p["dead_volume_cap_m3"] + tube,
        dead_volume_rod_m3=p["dead_volume_rod_m3"] + tube,
    )
    out = run_batch([p, with_fraction, bigger_dead], np.full(60, 0.6))
    np.testing.assert_allclose(out[:, :, 1], out[:, :, 2], rtol=1e-9, atol=1e-9)
    # the larger volume fills more slowly
    assert out[20, L.O_P1, 1] < out[20, L.O_P1, 0] - 1e4


def test_isothermal_tube_air_fills_like_alpha_out_and_empties_like_alpha_in_dead_volumes():
    """Eq. 14 with the tube's air isothermal at the chamber's pressure: while chamber 1 fills
    and chamber 2 empties (rod clamped, the valve held open) the run equals the paper's
    model with dead volumes V01 + alpha_out V_t and V02 + alpha_in V_t."""
    p = load_parameters(tube_length_m=2.0)
    tube = math.pi / 4 * p["tube_inner_diameter_m"] ** 2 * 2.0
    iso = load_parameters(tube_length_m=2.0, tube_volume_fraction=1.0, tube_air_model="isothermal")
    equivalent = load_parameters(
        tube_length_m=2.0,
        dead_volume_cap_m3=p["dead_volume_cap_m3"] + p["alpha_out"] * tube,
        dead_volume_rod_m3=p["dead_volume_rod_m3"] + p["alpha_in"] * tube,
    )
    polytropic = load_parameters(tube_length_m=2.0, tube_volume_fraction=1.0)
    out = run_batch(
        [iso, equivalent, polytropic], np.full(60, 0.6), initial={"p1": 1.2e5, "p2": 6.0e5}
    )
    p1, p2 = out[:, L.O_P1, 0], out[:, L.O_P2, 0]
    assert np.all(np.diff(p1) >= 0.0) and np.all(np.diff(p2) <= 0.0)  # fills, empties
    assert p1[-1] > p1[0] + 5e4 and p2[-1] < p2[0] - 5e4
    np.testing.assert_allclose(out[:, :, 0], out[:, :, 1], rtol=1e-9, atol=1e-9)
    # the polytropic dead volume (alpha_in = k > alpha_out) empties chamber 2 faster
    assert out[20, L.O_P2, 2] < p2[20] - 1e3
    with pytest.raises(
        ConfigError, match=r"'tube_air_model' = 1.0 is not allowed: must be dead_volume \(0\)"
    ):
        load_parameters(tube_air_model="isothermal", wall_heat_transfer_w_per_k=0.05)


# --------------------------------------------------------------------------- 2 rod-seal leak


def test_rod_seal_leak_empties_chamber_2_into_the_atmosphere():
    area = 1e-8
    p = load_parameters(rod_seal_leak_area_m2=area)
    sim = _sim([p], initial={"p1": 4e5, "p2": 5e5})
    out = sim.rollout(np.zeros((200, 1)))  # spool centred: the valve is shut (overlap)
    a1, a2, _ = areas(p)
    v2 = p["dead_volume_rod_m3"] + a2 * p["stroke_m"] / 2
    gas_rt = p["gas_constant_j_per_kg_k"] * p["temperature_k"]
    assert np.all(out[:, L.O_P1, 0] == 4e5)
    assert np.all(np.diff(out[:, L.O_P2, 0]) < 0)
    # every kilogram leaving chamber 2 (isothermal outflow, alpha_out = 1) is counted as exhaust
    np.testing.assert_allclose(
        out[:, L.O_EXHAUST, 0], (5e5 - out[:, L.O_P2, 0]) * v2 / gas_rt, rtol=1e-9
    )
    # first millisecond: choked flow of Eq. 39, C_f A P2 C1 / sqrt(T)
    c1 = math.sqrt(1.4 / 287.0 * (2 / 2.4) ** (2.4 / 0.4))
    choked = p["discharge_coefficient"] * area * 5e5 * c1 / math.sqrt(p["temperature_k"])
    assert out[0, L.O_EXHAUST, 0] == pytest.approx(choked * 1e-3, rel=1e-3)


def test_laminar_leak_flows_in_proportion_to_the_pressure_difference():
    """A laminar leak across the piston (G (P1 - P2)) with the valve shut: chamber 1 empties
    into chamber 2 without overshooting it, no air leaves the cylinder, and the first
    millisecond's flow doubles with the pressure difference (an orifice's, Eq. 39, grows
    about with its square root at these ratios)."""
    g = 3e-11
    p = load_parameters(leakage_conductance_kg_per_pa_s=g)
    starts = [(4e5, 3e5), (5e5, 3e5)]
    sims = [_sim([p], initial={"p1": p1, "p2": p2}) for p1, p2 in starts]
    outs = [sim.rollout(np.zeros((400, 1)))[:, :, 0] for sim in sims]
    a1, _, _ = areas(p)
    v1 = p["dead_volume_cap_m3"] + a1 * p["stroke_m"] / 2
    gas_rt = p["gas_constant_j_per_kg_k"] * p["temperature_k"]
    drops = []
    for (p1, p2), out in zip(starts, outs):
        assert np.all(np.diff(out[:, L.O_P1]) < 0) and np.all(np.diff(out[:, L.O_P2]) > 0)
        assert np.all(out[:, L.O_P1] > out[:, L.O_P2])  # they meet, never cross
        assert np.all(out[:, L.O_EXHAUST] == 0.0)
        # leaving chamber 1 at alpha_out = 1 (Eq. 14): dP1 = R T G (P1 - P2) dt / V1
        expected = gas_rt * g * (p1 - p2) * 1e-3 / v1
        assert p1 - out[0, L.O_P1] == pytest.approx(expected, rel=0.02)
        drops.append(p1 - out[0, L.O_P1])
    assert drops[1] / drops[0] == pytest.approx(2.0, rel=0.02)


# --------------------------------------------------------------------------- 3 null leak


def test_null_leak_holds_centred_chambers_at_the_leak_balance_pressure():
    leak = 1e-6
    p = load_parameters(valve_null_leak_area_m2=leak, tube_length_m=0.0)  # no attenuation
    out = run_batch([load_parameters(), p], np.zeros(500))
    assert np.all(out[:, L.O_P1, 0] == p["ambient_pressure_pa"])  # paper: sealed at null
    ps, pa = p["supply_pressure_pa"], p["ambient_pressure_pa"]
    c1, c2, p_cr = flow_constants(1.4, 287.0)
    r_lin = p["flow_linear_ratio"]
    slope = subsonic_reduced_flow(r_lin, 1.4, c2) / (1 - r_lin)

    def m_r(r):
        return reduced_flow(r, 1.4, c1, c2, p_cr, r_lin, slope)

    # equal areas on the supply and exhaust side; Eq. 14 is steady where
    # alpha_in mdot_in = alpha_out mdot_out
    a_in, a_out = p["alpha_in"], p["alpha_out"]
    p_eq = brentq(
        lambda q: a_in * ps * m_r(q / ps) - a_out * q * m_r(pa / q), pa * 1.001, ps * 0.999
    )
    assert out[-1, L.O_P1, 1] == pytest.approx(p_eq, rel=2e-3)
    assert out[-1, L.O_P2, 1] == pytest.approx(p_eq, rel=2e-3)


# --------------------------------------------------------------------------- 4 exhaust C_f


def test_exhaust_discharge_ratio_scales_the_choked_blow_down():
    sets = [
        load_parameters(tube_length_m=0.0),
        load_parameters(tube_length_m=0.0, exhaust_discharge_ratio=0.5),
    ]
    out = run_batch(sets, np.full(40, -1.5), initial={"p1": 5e5})
    p1 = out[:, L.O_P1, :]
    choked = np.all(p1 > 2.0e5, axis=1) & (p1[:, 0] < 5e5 - 1.0)
    assert choked.sum() > 5
    # choked exhaust: dP1/dt = -C_ex g(t) P1, so ln(P0/P1) is proportional to C_ex
    ratio = np.log(5e5 / p1[choked, 1]) / np.log(5e5 / p1[choked, 0])
    np.testing.assert_allclose(ratio, 0.5, rtol=1e-5)


# --------------------------------------------------------------------------- 5 ISO 6358


def test_iso_flow_law_follows_the_ellipse_between_b_and_the_linear_region():
    b = 0.3
    c = _constants(tube_length_m=0.0, flow_law="iso6358", iso_critical_ratio_b=b)
    c_paper = _constants(tube_length_m=0.0)
    p = load_parameters()
    ps = p["supply_pressure_pa"]
    x_s = 1.0e-3
    area = orifice_area(x_s, p["hole_radius_m"], p["spool_half_width_m"], p["holes_per_path"])
    c1 = math.sqrt(1.4 / 287.0 * (2 / 2.4) ** (2.4 / 0.4))
    full = p["discharge_coefficient"] * area * ps * c1 / math.sqrt(p["temperature_k"])
    for r in (0.2, 0.3, 0.45, 0.6, 0.9, 0.99):
        p1 = r * ps
        flow = kernel.valve_chamber_flows(
            c, x_s, p1, 1e5, p1, 1e5, c.inv_sqrt_t, c.inv_sqrt_t, c.ambient_pa
        )[0]
        expected = full * math.sqrt(1 - (max(r - b, 0.0) / (1 - b)) ** 2)
        assert flow == pytest.approx(expected, rel=1e-12), r
        paper = kernel.valve_chamber_flows(
            c_paper, x_s, p1, 1e5, p1, 1e5, c.inv_sqrt_t, c.inv_sqrt_t, c.ambient_pa
        )[0]
        if r > 0.528:  # the paper's law is subsonic there and differs
            assert abs(paper - flow) > 1e-3 * full
    # above flow_linear_ratio: the straight line to zero at r = 1, continuous at r_lin
    r_lin = p["flow_linear_ratio"]
    at_lin = full * math.sqrt(1 - ((r_lin - b) / (1 - b)) ** 2)
    r = 0.5 * (r_lin + 1)
    flow = kernel.valve_chamber_flows(
        c, x_s, r * ps, 1e5, r * ps, 1e5, c.inv_sqrt_t, c.inv_sqrt_t, c.ambient_pa
    )[0]
    assert flow == pytest.approx(at_lin * (1 - r) / (1 - r_lin), rel=1e-9)


# --------------------------------------------------------------------------- 6 supply droop


def test_supply_droop_lowers_the_supply_pressure_by_resistance_times_flow():
    resistance = 5e6
    c = _constants(tube_length_m=0.0, supply_resistance_pa_s_per_kg=resistance)
    ps = c.supply_pa
    x_s = 1.5e-3  # fully open to chamber 1; path b is shut

    def flow(consts, p1):
        return kernel.valve_chamber_flows(
            consts, x_s, p1, 1e5, p1, 1e5, consts.inv_sqrt_t, consts.inv_sqrt_t, consts.ambient_pa
        )[0]

    def ideal_flow(supply_pa, p1):  # no resistance, supply at supply_pa
        return flow(_constants(tube_length_m=0.0, supply_pressure_pa=supply_pa), p1)

    for p1 in (1.5e5, 4.5e5, 6.0e5, 6.45e5):  # choked, subsonic, near the linear region
        drooped = flow(c, p1)
        at_valve = brentq(lambda q, p1=p1: q - ps + resistance * ideal_flow(q, p1), p1 + 1e-6, ps)
        assert at_valve < ps
        assert drooped == pytest.approx(ideal_flow(at_valve, p1), rel=1e-8), p1
        assert drooped == pytest.approx((ps - at_valve) / resistance, rel=1e-6), p1
    assert ps - resistance * flow(c, 1.5e5) < ps - 2e4
    # no flow, no droop: the chamber still fills to the supply pressure, later
    out = run_batch(
        [load_parameters(), load_parameters(supply_resistance_pa_s_per_kg=resistance)],
        np.full(300, 1.0),
    )
    assert out[10, L.O_P1, 1] < out[10, L.O_P1, 0] - 5e3
    assert out[-1, L.O_P1, 1] == pytest.approx(ps, rel=1e-4)


# --------------------------------------------------------------------------- 6b exhaust vent


def test_exhaust_vent_passes_what_the_valve_exhausts():
    """The exhaust node behind a vent holds no air: at its pressure (an independent root of
    Eq. 39 flows, valve in and vent out) the valve's exhaust flow equals the vent's."""
    vent = 2e-6
    p = load_parameters(tube_length_m=0.0, exhaust_vent_area_m2=vent)
    c = _constants(tube_length_m=0.0, exhaust_vent_area_m2=vent)
    k, pa, inv_sqrt_t = p["heat_capacity_ratio"], p["ambient_pressure_pa"], c.inv_sqrt_t

    def eq39(area, discharge, p_from, p_to):
        return orifice_mass_flow(
            area,
            discharge,
            p_from,
            p_to,
            inv_sqrt_t,
            k,
            c.c1,
            c.c2,
            c.critical_ratio,
            c.linear_ratio,
            c.linear_slope,
        )

    for x_s in (-1.5e-3, -1.05e-3):  # chamber 1 exhausts through path b: fully, barely open
        area_b = orifice_area(
            -x_s, p["hole_radius_m"], p["spool_half_width_m"], p["holes_per_path"]
        )
        for p1 in (1.3e5, 2.5e5, 6.0e5):
            at_node = brentq(
                lambda q, area_b=area_b, p1=p1: (
                    eq39(area_b, c.discharge_ex, p1, q) - eq39(vent, 1.0, q, pa)
                ),
                pa,
                p1,
                xtol=1e-9,
            )
            flows = kernel.valve_chamber_flows(c, x_s, p1, 3e5, p1, 3e5, inv_sqrt_t, inv_sqrt_t, pa)
            exhausted = flows[1]
            assert exhausted == pytest.approx(eq39(vent, 1.0, at_node, pa), rel=1e-8), (x_s, p1)
            assert exhausted == pytest.approx(
                eq39(area_b, c.discharge_ex, p1, at_node), rel=1e-8
            ), (x_s, p1)
            assert pa < at_node < p1
            open_exhaust = _constants(tube_length_m=0.0)
            assert (
                exhausted
                < kernel.valve_chamber_flows(
                    open_exhaust, x_s, p1, 3e5, p1, 3e5, inv_sqrt_t, inv_sqrt_t, pa
                )[1]
            )
    # no flow, no back-pressure: a vented chamber still empties to the atmosphere, later
    out = run_batch(
        [load_parameters(), load_parameters(exhaust_vent_area_m2=vent)],
        np.full(400, -1.0),
        initial={"p1": 6e5},
    )
    assert out[5, L.O_P1, 1] > out[5, L.O_P1, 0] + 5e3
    assert out[-1, L.O_P1, 1] == pytest.approx(pa, rel=1e-3)
    with pytest.raises(
        ConfigError,
        match=r"^override 'exhaust_vent_area_m2' = 2e-06 is not "
        r"allowed: must be 0: the exhaust back-pressure is "
        r"not implemented with the transmission line "
        r"\(tube_waves = 1\)$",
    ):
        load_parameters(tube_waves=1, exhaust_vent_area_m2=vent)


@pytest.mark.parametrize("volume_m3, tolerance, lagging_step", [(1e-5, 0.005, 19), (1e-6, 0.03, 1)])
def test_muffler_node_follows_an_independent_solution(volume_m3, tolerance, lagging_step):
    """A muffler node (``exhaust_volume_m3``), the valve's inputs held: the kernel's
    backward-Euler steps against solve_ivp of dP_e/dt = (R T / V) (valve in - vent out),
    Eq. 39 flows; to the tolerance (of the rise to the steady pressure) over 20 ms. With
    no volume the first step lands on the quasi-static pressure."""
    vent, x_s, p1, p2, h = 1.5e-6, -1.5e-3, 4e5, 3e5, 5e-5  # chamber 1 exhausts (path b)
    p = load_parameters(tube_length_m=0.0, exhaust_vent_area_m2=vent, exhaust_volume_m3=volume_m3)
    c = _constants(tube_length_m=0.0, exhaust_vent_area_m2=vent, exhaust_volume_m3=volume_m3)
    k, pa, inv_sqrt_t = p["heat_capacity_ratio"], p["ambient_pressure_pa"], c.inv_sqrt_t
    area_b = orifice_area(-x_s, p["hole_radius_m"], p["spool_half_width_m"], p["holes_per_path"])
    storage = volume_m3 / (p["gas_constant_j_per_kg_k"] * p["temperature_k"])

    def rate(_, pe):
        valve = orifice_mass_flow(
            area_b,
            c.discharge_ex,
            p1,
            pe[0],
            inv_sqrt_t,
            k,
            c.c1,
            c.c2,
            c.critical_ratio,
            c.linear_ratio,
            c.linear_slope,
        )
        vented = orifice_mass_flow(
            vent,
            1.0,
            pe[0],
            pa,
            inv_sqrt_t,
            k,
            c.c1,
            c.c2,
            c.critical_ratio,
            c.linear_ratio,
            c.linear_slope,
        )
        return [(valve - vented) / storage]

    steps = 400
    times = h * np.arange(1, steps + 1)
    reference = solve_ivp(
        rate, (0.0, times[-1]), [pa], t_eval=times, method="LSODA", rtol=1e-10, atol=1e-6
    ).y[0]
    history = np.zeros((3, L.N_HISTORY, 1))
    y = (x_s, 0.0, p1, p2, 0.0, 0.0, 0.0, c.temperature, c.temperature)
    node, ours = pa, []
    for _ in range(steps):
        node = kernel.exhaust_node_after_substep(c, history, 0, 0, y, node, h)
        ours.append(node)
    rise = reference[-1] - pa
    assert rise > 2e5  # the steady back-pressure: close to p1, the valve no longer choked
    assert np.max(np.abs(np.array(ours) - reference)) < tolerance * rise
    assert reference[lagging_step] < pa + 0.5 * rise  # the volume makes it lag
    quasi_static = kernel.exhaust_pressure_at_valve(
        c, 0.0, area_b, p1, p2, inv_sqrt_t, inv_sqrt_t, 0.0, pa
    )
    assert quasi_static == pytest.approx(reference[-1], rel=1e-6)
    no_volume = _constants(tube_length_m=0.0, exhaust_vent_area_m2=vent, exhaust_volume_m3=1e-12)
    assert kernel.exhaust_node_after_substep(no_volume, history, 0, 0, y, pa, h) == pytest.approx(
        quasi_static, rel=1e-5
    )


def test_muffler_delays_the_back_pressure_and_lets_the_chamber_empty():
    """A charged chamber vented through a muffler: at first (the muffler still at ambient)
    it empties as with no vent, later slower than with a vent alone; in the end it reaches
    ambient, and so does the muffler; the node stays at ambient with the effect off."""
    vent = 1.5e-6
    sets = [
        load_parameters(),
        load_parameters(exhaust_vent_area_m2=vent),
        load_parameters(exhaust_vent_area_m2=vent, exhaust_volume_m3=1e-5),
    ]
    sim = _sim(sets, initial={"p1": 6e5})
    out = sim.rollout(np.full((400, 3), -1.0))
    open_vent, quasi_static, muffler = (out[:, L.O_P1, j] for j in range(3))
    assert abs(muffler[4] - open_vent[4]) < 0.2 * abs(quasi_static[4] - open_vent[4])
    assert muffler[60] > quasi_static[60] + 1e4
    assert muffler[-1] == pytest.approx(sets[0]["ambient_pressure_pa"], rel=1e-3)
    assert sim.state[L.S_EXHAUST_NODE, 2] == pytest.approx(sets[0]["ambient_pressure_pa"], rel=1e-3)
    np.testing.assert_array_equal(
        sim.state[L.S_EXHAUST_NODE, :2], [sets[0]["ambient_pressure_pa"]] * 2
    )


# --------------------------------------------------------------------------- 7 coil lag


def test_coil_lag_is_a_first_order_lag_of_the_current():
    tau = 0.004
    sim = _sim([load_parameters(), load_parameters(coil_time_constant_s=tau)])
    assert np.all(sim.state[L.S_COIL] == 0.0)
    sim.step(np.array([1.0, 1.0]))
    assert sim.state[L.S_COIL, 0] == 1.0
    assert sim.state[L.S_COIL, 1] == pytest.approx(1 - math.exp(-1e-3 / tau), rel=1e-12)
    lagged_spool = sim.outputs[L.O_X_S, 1]
    assert 0.0 < lagged_spool < 0.5 * sim.outputs[L.O_X_S, 0]
    i1 = sim.state[L.S_COIL, 1]
    for _ in range(3):
        sim.step(np.array([0.0, 0.0]))
    assert sim.state[L.S_COIL, 1] == pytest.approx(i1 * math.exp(-3e-3 / tau), rel=1e-12)
    sim.reset()
    assert np.all(sim.state[L.S_COIL] == 0.0)


@pytest.mark.parametrize(
    "coil_tau, force_tau", [(0.002, 0.001), (0.0015, 0.0015), (0.002, 0.0), (0.003, 1e-8)]
)
def test_coil_and_force_lags_match_an_independent_linear_simulation(coil_tau, force_tau):
    """The coil lag and the force lag behind it are two cascaded first-order lags of the held
    command: the kernel's exact solution equals SciPy's simulation of
    1 / ((tau_c s + 1)(tau_f s + 1)) with a zero-order-hold input (equal time constants
    included, where the closed form has its removable singularity, and a vanishing force
    lag). The parameters are the total T = tau_c + tau_f and shape tau_c tau_f / T^2."""
    from scipy.signal import lsim

    total = coil_tau + force_tau
    shape = coil_tau * force_tau / total**2
    assert E.coil_time_constants(total, shape) == pytest.approx(
        (coil_tau, force_tau), rel=1e-6, abs=1e-15
    )
    rng = np.random.default_rng(3)
    command = rng.uniform(-1.0, 1.0, 12)
    sim = _sim([load_parameters(coil_time_constant_s=total, coil_lag_shape=shape)])
    coil, force = [0.0], [0.0]
    for u in command:
        sim.step(np.array([u]))
        coil.append(sim.state[L.S_COIL, 0])
        force.append(sim.state[L.S_COIL_FORCE, 0])
    t = np.arange(command.size + 1) * 1e-3
    u = np.append(command, 0.0)
    # states (i, j): tau_c i' = u - i, tau_f j' = i - j (j = i without a force lag)
    rate_f = 1.0 / force_tau if force_tau > 0 else 0.0
    a = np.array([[-1.0 / coil_tau, 0.0], [rate_f, -rate_f]])
    b = np.array([[1.0 / coil_tau], [0.0]])
    c = np.array([[1.0, 0.0], [0.0, 1.0]]) if force_tau > 0 else np.array([[1.0, 0.0]] * 2)
    _, ref, _ = lsim((a, b, c, np.zeros((2, 1))), u, t, interp=False)
    np.testing.assert_allclose(coil, ref[:, 0], atol=1e-9)
    np.testing.assert_allclose(force, ref[:, 1], atol=1e-9)
    # the spool feels the force current: without a force lag it is the coil current
    if force_tau == 0.0:
        np.testing.assert_array_equal(force, coil)


def test_the_force_lag_drives_the_spool():
    """With a force lag the spool follows the force current (Eq. 38 with K_f j): it lags
    the spool of the coil lag alone, and settles at the same position (Eq. 46)."""
    sets = [
        load_parameters(coil_time_constant_s=0.002),
        load_parameters(coil_time_constant_s=0.004, coil_lag_shape=0.25),
    ]
    sim = _sim(sets)
    sim.step(np.full(2, 0.5))
    assert 0.0 < sim.outputs[L.O_X_S, 1] < 0.5 * sim.outputs[L.O_X_S, 0]
    for _ in range(60):
        sim.step(np.full(2, 0.5))
    assert sim.outputs[L.O_X_S, 1] == pytest.approx(sim.outputs[L.O_X_S, 0], rel=1e-6)


# --------------------------------------------------------------------------- 8 heat transfer


def test_closed_chamber_cools_to_the_wall_at_constant_mass():
    h_a = 0.05
    p = load_parameters(wall_heat_transfer_w_per_k=h_a)
    sim = _sim([p], initial={"p1": 4e5})
    assert sim.state[L.S_T1, 0] == sim.state[L.S_T2, 0] == T_S
    t0 = 350.0
    sim.state[L.S_T1, 0] = t0
    out = sim.rollout(np.zeros((300, 1)))  # valve shut: a closed rigid chamber
    t1 = sim.state[L.S_T1, 0]
    assert np.all(np.diff(out[:, L.O_P1, 0]) < 0)  # the cooling gas loses pressure ...
    assert out[-1, L.O_P1, 0] / t1 == pytest.approx(4e5 / t0, rel=1e-9)  # ... at constant m
    a1, _, _ = areas(p)
    v1 = p["dead_volume_cap_m3"] + a1 * p["stroke_m"] / 2
    mass = 4e5 * v1 / (287.0 * t0)
    tau = mass * 287.0 / 0.4 / h_a  # m c_v / hA
    assert t1 - T_S == pytest.approx((t0 - T_S) * math.exp(-0.3 / tau), rel=1e-6)


def test_adiabatic_filling_heats_the_gas_as_the_first_law_says():
    p = load_parameters(wall_heat_transfer_w_per_k=1e-9)  # > 0: energy model, ~adiabatic
    sim = _sim([p])
    out = sim.rollout(np.full((40, 1), 1.0))
    a1, _, _ = areas(p)
    v1 = p["dead_volume_cap_m3"] + a1 * p["stroke_m"] / 2
    p0, p1, t1 = p["ambient_pressure_pa"], out[-1, L.O_P1, 0], sim.state[L.S_T1, 0]
    assert p1 > 3e5
    # rigid tank filled at T_s: (P - P0) V / (k - 1) = (m - m0) c_p T_s
    mass = p0 * v1 / (287.0 * T_S) + (p1 - p0) * v1 / (1.4 * 287.0 * T_S)
    assert t1 == pytest.approx(p1 * v1 / (mass * 287.0), rel=1e-6)
    assert t1 > T_S + 60.0
    assert sim.state[L.S_T2, 0] == T_S  # chamber 2 untouched (at ambient, valve shut to it)


# --------------------------------------------------------------------------- 9 Stribeck


def test_stribeck_friction_falls_from_static_to_dynamic_with_speed():
    v_s = 0.02
    p = load_parameters(piston_mode="free", stribeck_velocity_m_per_s=v_s)
    c = _constants(piston_mode="free", stribeck_velocity_m_per_s=v_s)
    a1, a2, ar = areas(p)
    p1, p2 = 3e5, 1.5e5
    applied = p1 * a1 - p2 * a2 - p["ambient_pressure_pa"] * ar - p["load_force_n"]
    mass = p["piston_mass_kg"] + p["load_mass_kg"]
    f_sf, f_df = p["static_friction_n"], p["dynamic_friction_n"]
    for v in (1e-4, 0.01, 0.02, 0.2):
        y = (0.0, 0.0, p1, p2, 0.0, v, 0.0, T_S, T_S)
        accel = kernel.derivatives(c, 0.0, y, 1.0, (0.0, p1, p2), (p1, p2), c.ambient_pa)[5]
        friction = f_df + (f_sf - f_df) * math.exp(-((v / v_s) ** 2))
        expected = (applied - p["viscous_friction_n_s_per_m"] * v - friction) / mass
        assert accel == pytest.approx(expected, rel=1e-12), v
    assert E.stribeck_friction(0.0, f_df, f_sf, v_s) == f_sf
    assert E.stribeck_friction(1.0, f_df, f_sf, v_s) == pytest.approx(f_df, rel=1e-12)


# --------------------------------------------------------------------------- LuGre friction


@pytest.mark.parametrize("velocity", [0.0, 1e-7, 3e-3, 0.05, -0.2])
def test_lugre_bristle_step_is_the_exact_solution_at_a_held_velocity(velocity):
    """The bristle ODE dz/dt = v - sigma0 |v| z / g solved by SciPy at the same held v:
    the deflection at the step's end and the force sigma0 z + sigma1 dz/dt averaged over
    the step (the series branch at 1e-7 m/s, no relaxation at rest, the stiff one at 0.2)."""
    sigma0, sigma1, g, h, z0 = 1e5, 300.0, 2.0, 5e-5, 1.2e-5

    def rhs(_t, y):
        dz = velocity - sigma0 * abs(velocity) * y[0] / g
        return [dz, sigma0 * y[0] + sigma1 * dz]  # z and the integral of the force

    ref = solve_ivp(rhs, (0.0, h), [z0, 0.0], method="Radau", rtol=1e-12, atol=[1e-18, 1e-16])
    z_end, force = E.lugre_bristle_step(z0, velocity, h, sigma0, sigma1, g)
    assert z_end == pytest.approx(ref.y[0, -1], rel=1e-9, abs=1e-17)
    assert force == pytest.approx(ref.y[1, -1] / h, rel=1e-9)


def test_lugre_slides_on_the_friction_curve():
    """Sliding steadily the bristles sit at g sgn(v) / sigma0 and the force is g(v) sgn(v)."""
    g = E.stribeck_friction(-0.05, 0.5, 3.8, 0.01)
    z, force = E.lugre_bristle_step(0.0, -0.05, 1.0, 1e5, 300.0, g)
    assert z == pytest.approx(-g / 1e5, rel=1e-12)
    z, force = E.lugre_bristle_step(z, -0.05, 5e-5, 1e5, 300.0, g)
    assert force == pytest.approx(-g, rel=1e-9)


def _held_rod(net_force_n, **friction):
    """A free rod with the valve closed (sealed chambers) and pressures whose net force on
    the piston is ``net_force_n``, 50 ms from rest; returns the simulator and parameters."""
    p = load_parameters(piston_mode="free", **friction)
    a1, a2, ar = areas(p)
    p2 = 2.0e5
    p1 = (net_force_n + p2 * a2 + p["ambient_pressure_pa"] * ar + p["load_force_n"]) / a1
    sim = _sim([p], initial={"p1": p1, "p2": p2})
    for _ in range(50):
        sim.step(np.zeros(1))
    return sim, p


def test_lugre_pre_sliding_is_a_spring_and_breakaway_follows_the_friction_curve():
    """Below the friction Karnopp friction holds the rod exactly; LuGre lets it creep until
    its bristles carry the net force. Creeping one way, dz/dx = 1 - sigma0 z / g (g = F_df
    without Stribeck), so z = (g / sigma0) (1 - exp(-sigma0 x / g)), whatever the force
    did on the way; at rest sigma0 z is the net pneumatic force (the sealed air stiffens a
    little as the rod moves). Well above the static friction both slide."""
    sigma0 = 1e5
    mass = load_parameters()["piston_mass_kg"] + load_parameters()["load_mass_kg"]
    lugre = {
        "lugre_stiffness_n_per_m": sigma0,
        "lugre_damping_n_s_per_m": 2.0 * math.sqrt(sigma0 * mass),
    }  # critically damped
    sim, p = _held_rod(0.25)
    assert sim.state[L.S_X, 0] == 0.0
    sim, p = _held_rod(0.25, **lugre)
    x, z, g = sim.state[L.S_X, 0], sim.state[L.S_BRISTLE, 0], p["dynamic_friction_n"]
    assert sim.state[L.S_V, 0] == pytest.approx(0.0, abs=1e-9)
    a1, a2, ar = areas(p)
    net = (
        sim.state[L.S_P1, 0] * a1
        - sim.state[L.S_P2, 0] * a2
        - p["ambient_pressure_pa"] * ar
        - p["load_force_n"]
    )
    assert sigma0 * z == pytest.approx(net, rel=1e-6)
    # the bristles take each substep's starting velocity (operator splitting): 0.7 % here
    assert z == pytest.approx(g / sigma0 * -math.expm1(-sigma0 * x / g), rel=0.02)
    assert x == pytest.approx(-(g / sigma0) * math.log(1.0 - 0.25 / g), rel=0.1)  # 3.5 um
    for friction in ({}, lugre):
        sim, p = _held_rod(1.6 * p["static_friction_n"], **friction)
        assert sim.state[L.S_X, 0] > 1e-3


def test_stiff_lugre_bristles_split_the_substep_and_match_a_fine_one():
    """A stiff seal (sigma0 = 1e7 N/m: a pre-sliding mode of 2.3 kHz on the 50 g piston)
    at the default 200 us substep: ``refinement`` splits it (h sqrt(sigma0 / M) = 2.8), and
    the rod follows a run at 80 substeps per ms."""
    mass = load_parameters()["piston_mass_kg"]
    lugre = dict(
        piston_mode="free",
        tube_length_m=0.5,
        lugre_stiffness_n_per_m=1e7,
        lugre_damping_n_s_per_m=2.0 * math.sqrt(1e7 * mass),
        stribeck_velocity_m_per_s=0.01,
    )
    c = kernel.env_constants(parameter_array(load_parameters(**lugre)), 0, 2e-4)
    y = (0.0, 0.0, 3e5, 3e5, 0.0, 0.0, 0.0, T_S, T_S)
    assert kernel.refinement(c, y, 2e-4) >= 8
    t = np.arange(120) * 1e-3
    currents = np.where(t < 0.06, 0.4, -0.4)
    default = run_batch([load_parameters(**lugre)], currents)
    fine = run_batch([load_parameters(**lugre)], currents, substeps=80)
    assert np.all(np.isfinite(default))
    x = default[:, L.O_X, 0]
    assert np.ptp(x) > 5e-3  # it slid both ways
    assert np.abs(x - fine[:, L.O_X, 0]).max() < 0.01 * np.ptp(x)


# --------------------------------------------------------------------------- 10 spool friction


def test_spool_friction_is_a_play_of_half_width_friction_over_coil_force():
    """The settled spool sits at Eq. 46's position of the play's current: it does not move
    for a command change inside the band, and reaches a current from above and from
    below at two positions 2 F_cs / (2 k_s) apart (hysteresis)."""
    friction_n = 0.1
    p = load_parameters(spool_coulomb_friction_n=friction_n)
    k_fc, k_s = p["coil_force_n_per_a"], p["spool_spring_n_per_m"]
    band = friction_n / k_fc
    sim = _sim([load_parameters(), p])

    def settle(command_a, steps=60):  # the spool settles within a few ms (Eq. 38)
        for _ in range(steps):
            sim.step(np.array([command_a, command_a]))
        return sim.outputs[L.O_X_S].copy()

    assert sim.state[L.S_PLAY, 1] == 0.0
    up = settle(0.3)
    assert up[0] == pytest.approx(steady_spool_position(0.3, k_s, k_fc), rel=1e-6)
    assert up[1] == pytest.approx(steady_spool_position(0.3 - band, k_s, k_fc), rel=1e-6)
    assert sim.state[L.S_PLAY, 1] == pytest.approx(0.3 - band, rel=1e-12)
    inside = settle(0.3 - 1.5 * band)  # back by less than the band's width: no motion
    assert inside[1] == pytest.approx(up[1], rel=1e-9)
    assert inside[0] < up[0] - 0.5 * steady_spool_position(band, k_s, k_fc)
    down = settle(0.1)
    from_above = down[1]
    assert from_above == pytest.approx(steady_spool_position(0.1 + band, k_s, k_fc), rel=1e-6)
    settle(-0.2)
    from_below = settle(0.1)[1]
    assert from_above - from_below == pytest.approx(2 * friction_n / (2 * k_s), rel=1e-6)
    assert np.all(sim.state[L.S_COIL] == sim.state[L.S_PLAY])  # no coil lag: the same
    sim.reset()
    assert np.all(sim.state[L.S_PLAY] == 0.0)


# --------------------------------------------------------------------------- 11 tube waves


def test_segmented_line_reference_conserves_the_air():
    from pneumatic_env.studies.reference_solution import simulate_segmented_line

    ref = simulate_segmented_line(load_parameters(tube_length_m=2.0), 0.5, 0.03, n_segments=10)
    assert ref["line_mass_kg"] > 0.0 and ref["chamber_mass_kg"] > 0.0
    assert ref["line_mass_kg"] + ref["chamber_mass_kg"] == pytest.approx(
        ref["valve_mass_kg"], rel=1e-6
    )


@pytest.mark.parametrize(
    "tube_length_m, current_a, tolerance", [(0.5, 0.5, 0.01), (2.0, 0.5, 0.05), (2.0, -0.3, 0.05)]
)
def test_transmission_line_follows_an_independent_segmented_line(
    tube_length_m, current_a, tolerance
):
    """Chamber pressures of a current step through the transmission line against a
    30-segment finite-volume line (SciPy, ``reference_solution.simulate_segmented_line``),
    which conserves the air and so fills the chambers much faster than the paper's
    attenuated tube (Eq. 30 removes the flow it attenuates)."""
    from pneumatic_env.studies.tube_study import tube_model_errors

    errors = tube_model_errors(tube_length_m, current_a)
    assert errors["transmission line"] < tolerance
    assert errors["paper tube (Eqs. 30, 31)"] > 3.0 * errors["transmission line"]


def _chamber_end_flow(c, chamber_pa, drive_pa):
    """The line's flow into a chamber at ``chamber_pa`` with the wave W_in = P + drive."""
    from pneumatic_env.physics.tube import line_chamber_flow

    return line_chamber_flow(
        chamber_pa + drive_pa,
        chamber_pa,
        c.line_impedance,
        c.line_laminar_friction,
        c.line_turbulent_friction,
        c.line_transition_flow,
    )


def test_line_chamber_flow_solves_its_end_equation():
    """m (Z_c + R(m)/2) = W_in - P at the chamber end, laminar and turbulent (Eqs. 33, 35),
    with R from ``line_resistance`` (the flow is solved with the cached coefficients)."""
    from pneumatic_env.physics.tube import line_resistance, sound_speed

    c = _constants(tube_length_m=2.0, tube_waves=1)
    p = 5e5
    for drive in (-3e5, -2e4, -50.0, 50.0, 1e3, 2e4, 3e5):
        m = _chamber_end_flow(c, p, drive)
        resistance = line_resistance(
            m, p, c.line_friction, c.tube_diameter, c.viscosity, c.reynolds_turbulent
        )
        assert m * (c.line_impedance + 0.5 * resistance) == pytest.approx(drive, rel=1e-9)
    area = math.pi / 4 * load_parameters()["tube_inner_diameter_m"] ** 2
    assert c.line_impedance == pytest.approx(sound_speed(1.4, 287.0, T_S) / area, rel=1e-3)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_line_chamber_flow_meets_its_end_equation_to_the_solver_tolerance(seed):
    """Over random chamber pressures and drives W_in - P (10 Pa to 5 bar, both signs) on
    three tube diameters, the flow meets m (Z_c + R(m)/2) = W_in - P within 1e-11 of the
    drive (the solver's tolerance is 1e-12 on the flow), or sits at the transition flow
    where the jump of R at ``reynolds_turbulent`` leaves no root."""
    from pneumatic_env.physics.tube import line_resistance

    rng = np.random.default_rng(seed)
    for diameter in (2e-3, 4e-3, 6e-3):
        c = _constants(tube_length_m=2.0, tube_waves=1, tube_inner_diameter_m=diameter)
        for _ in range(300):
            p = rng.uniform(3e4, 8e5)
            drive = rng.choice([-1.0, 1.0]) * 10.0 ** rng.uniform(1.0, 5.7)
            m = _chamber_end_flow(c, p, drive)
            assert m * drive > 0.0
            if abs(m) == c.line_transition_flow:
                continue
            resistance = line_resistance(
                m, p, c.line_friction, c.tube_diameter, c.viscosity, c.reynolds_turbulent
            )
            balance = m * (c.line_impedance + 0.5 * resistance)
            assert balance == pytest.approx(drive, rel=1e-11)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_transmission_lines_at_a_stop_converge_with_the_substep(seed):
    """A free rod with transmission lines driven against its stops, a small dead volume
    behind the piston (the stiffness bound then counts the line's chamber end, not the
    valve's paths): the identification's 25 us substeps give the pressures of 8 x finer
    ones within the 1 kPa of a pressure sensor's noise (RMS over the run; a departure
    from a stop a substep apart moves a transient), the force within 0.2 N."""
    rng = np.random.default_rng(seed)
    currents = np.repeat(rng.uniform(-0.6, 0.6, 6), 500)  # steps held 0.5 s
    p = load_parameters(
        tube_length_m=2.0,
        tube_waves=1,
        piston_mode="free",
        load_mass_kg=0.5,
        dead_volume_cap_m3=1e-8,
        dead_volume_rod_m3=1e-8,
    )
    coarse = run_batch([p], currents, substeps=40)[:, :, 0]
    fine = run_batch([p], currents, substeps=320)[:, :, 0]
    at_stop = np.abs(fine[:, L.O_X]) >= p["stroke_m"] / 2 - 1e-9
    assert at_stop.mean() > 0.5  # the rod rests at a stop most of the time
    rms = np.sqrt(np.mean((coarse - fine) ** 2, axis=0))
    assert rms[L.O_P1] <= 1e3 and rms[L.O_P2] <= 1e3
    assert rms[L.O_F] <= 0.2


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_transmission_line_exhaust_mass_converges_with_the_substep(seed):
    """The lines' valve exhaust, solved at substep boundaries and integrated by the
    trapezoid rule, gives the exhaust mass of 80 substeps per period within 1e-4 at the
    env's 5."""
    rng = np.random.default_rng(seed)
    currents = np.repeat(rng.uniform(-1.0, 1.0, 8), 50)  # steps held 50 ms
    p = load_parameters(tube_length_m=2.0, tube_waves=1)
    coarse = run_batch([p], currents, substeps=5)[:, L.O_EXHAUST, 0]
    fine = run_batch([p], currents, substeps=80)[:, L.O_EXHAUST, 0]
    assert fine[-1] > 1e-4  # kg: the steps vent both chambers
    assert np.max(np.abs(coarse - fine)) <= 1e-4 * fine[-1]


def test_transmission_line_delays_by_the_tube_and_rings():
    """Nothing reaches the chamber before the wave, tau = L_t / c (Eq. 31); the filled
    chamber overshoots the supply pressure and settles on it (a reflected wave)."""
    p = load_parameters(tube_length_m=3.0, tube_waves=1)
    tau = 3.0 / math.sqrt(
        p["heat_capacity_ratio"] * p["gas_constant_j_per_kg_k"] * p["temperature_k"]
    )
    out = run_batch([p], np.full(300, 1.0))[:, :, 0]
    before = int(tau / 1e-3)  # whole control steps before the wave arrives
    assert before == 8
    assert np.all(out[:before, L.O_P1] == p["ambient_pressure_pa"])
    assert out[before + 2, L.O_P1] > p["ambient_pressure_pa"] + 1e3  # (the spool opens in ~2 ms)
    assert out[:, L.O_P1].max() > p["supply_pressure_pa"] + 5e3  # overshoot
    assert out[-1, L.O_P1] == pytest.approx(p["supply_pressure_pa"], rel=1e-2)
    assert out[-1, L.O_P2] == pytest.approx(p["ambient_pressure_pa"], rel=1e-3)


def test_transmission_line_refuses_what_it_cannot_do():
    with pytest.raises(
        ConfigError,
        match=r"^override 'tube_volume_fraction' = 0.5 is not "
        r"allowed: must be 0: the transmission line holds "
        r"the tube's air itself \(tube_waves = 1\)$",
    ):
        load_parameters(tube_waves=1, tube_volume_fraction=0.5)
    with pytest.raises(ConfigError, match=r"^override 'tube_coupling' = 1.0 is not allowed"):
        load_parameters(tube_waves=1, tube_coupling="literal")
    with pytest.raises(
        ValueError,
        match=r"^tube_waves = 1 \(transmission line\) of environment "
        r"1 needs a tube delay L_t/c of at least one substep "
        r"\(5e-05 s\); tube_length_m = 0.01 gives 2.91\d*e-05 s: "
        r"use a tube of at least 0.0172 m or more substeps, or "
        r"tube_waves = 0$",
    ):
        _sim([load_parameters(), load_parameters(tube_length_m=0.01, tube_waves=1)])
    sim = _sim([load_parameters(), load_parameters()])
    before = sim.params.copy()
    with pytest.raises(ValueError, match=r"^tube_waves = 1 \(transmission line\) of environment 1"):
        sim.set_params([1], parameter_array([load_parameters(tube_length_m=0.01, tube_waves=1)]))
    np.testing.assert_array_equal(sim.params, before)  # the refused change is not kept


@pytest.mark.parametrize("cylinder", ["numatics", "airpel"])
def test_every_effect_is_off_in_the_shipped_configs(cylinder):
    params = load_parameters(cylinder)
    for name, neutral in L.EFFECT_NEUTRAL_VALUES.items():
        assert params[name] == neutral, name
