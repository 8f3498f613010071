"""The effects the batch path advances (``constants.batch_lane_kind``) against the general
path (``general_path.advance_env``), bit for bit: states and outputs after every control
period, random piecewise-constant currents, free and spring rods that meet the stops and
reverse (piston events, redone substeps), in chunks that mix them with base-model lanes
and general-path lanes."""

from __future__ import annotations

import numpy as np
import pytest

from pneumatic_env.params import load_parameters, parameter_array
from pneumatic_env.physics import constants as K
from pneumatic_env.physics import kernel
from rollout_inputs import assert_batch_matches_general_path, random_currents

# each effect the batch path takes (alone and together), a strong and a weak setting
BATCH_EFFECTS = {
    "leakage": ({"leakage_area_m2": 2e-7}, {"leakage_area_m2": 1e-9}),
    "rod_seal_leak": ({"rod_seal_leak_area_m2": 2e-7}, {"rod_seal_leak_area_m2": 1e-9}),
    "laminar_leak": (
        {"leakage_conductance_kg_per_pa_s": 1e-9, "wall_heat_transfer_w_per_k": 0.5},
        {"leakage_conductance_kg_per_pa_s": 3e-11},
    ),
    "both_leaks": (
        {"leakage_area_m2": 5e-8, "rod_seal_leak_area_m2": 1e-7},
        {"leakage_area_m2": 1e-9, "rod_seal_leak_area_m2": 3e-9},
    ),
    "coil_lag": (
        {"coil_time_constant_s": 5e-3, "coil_lag_shape": 0.0},
        {"coil_time_constant_s": 1e-3, "coil_lag_shape": 0.1},
    ),
    "heat_transfer": ({"wall_heat_transfer_w_per_k": 2.0}, {"wall_heat_transfer_w_per_k": 0.05}),
    "heat_transfer_and_leaks": (
        {"wall_heat_transfer_w_per_k": 0.5, "leakage_area_m2": 5e-8},
        {"wall_heat_transfer_w_per_k": 0.05, "rod_seal_leak_area_m2": 1e-7},
    ),
    "tube_air": (
        {"tube_air_model": 1.0, "tube_volume_fraction": 1.0},
        {"tube_air_model": 1.0, "tube_volume_fraction": 0.3},
    ),
    "iso_flow_law": (
        {"flow_law": 1.0, "iso_critical_ratio_b": 0.3},
        {"flow_law": 1.0, "iso_critical_ratio_b": 0.45, "leakage_area_m2": 5e-8},
    ),
    "coil_lags_and_leaks": (
        {"coil_time_constant_s": 2e-3, "coil_lag_shape": 0.25, "leakage_area_m2": 5e-8},
        {"coil_time_constant_s": 3e-4, "coil_lag_shape": 0.2, "rod_seal_leak_area_m2": 5e-8},
    ),
    "valve_null_leak": (
        {"valve_null_leak_area_m2": 2e-7},
        {"valve_null_leak_area_m2": 2e-8},
    ),
    "null_leak_leak_and_coil_lag": (
        {
            "valve_null_leak_area_m2": 5e-8,
            "leakage_area_m2": 5e-8,
            "coil_time_constant_s": 2e-3,
            "coil_lag_shape": 0.25,
        },
        {
            "valve_null_leak_area_m2": 1e-9,
            "rod_seal_leak_area_m2": 5e-8,
            "coil_time_constant_s": 3e-4,
            "wall_heat_transfer_w_per_k": 0.5,
        },
    ),
    "exhaust_backpressure": (
        {"exhaust_vent_area_m2": 5e-6, "exhaust_volume_m3": 0.0},
        {"exhaust_vent_area_m2": 1e-4, "exhaust_volume_m3": 0.0},
    ),
    "exhaust_backpressure_and_effects": (
        {"exhaust_vent_area_m2": 3e-6, "valve_null_leak_area_m2": 5e-8, "leakage_area_m2": 5e-8},
        {
            "exhaust_vent_area_m2": 2e-5,
            "coil_time_constant_s": 2e-3,
            "wall_heat_transfer_w_per_k": 0.5,
            "rod_seal_leak_area_m2": 5e-8,
        },
    ),
    "supply_droop": (
        {"supply_resistance_pa_s_per_kg": 1e6},
        {"supply_resistance_pa_s_per_kg": 3e7},
    ),
    "supply_droop_and_nodes": (
        {
            "supply_resistance_pa_s_per_kg": 5e6,
            "exhaust_vent_area_m2": 3e-6,
            "valve_null_leak_area_m2": 5e-8,
        },
        {
            "supply_resistance_pa_s_per_kg": 2e6,
            "coil_time_constant_s": 2e-3,
            "wall_heat_transfer_w_per_k": 0.5,
            "leakage_area_m2": 5e-8,
            "flow_law": 1.0,
        },
    ),
    "tube_waves": (
        {"tube_waves": 1.0},
        {"tube_waves": 1.0, "tube_inner_diameter_m": 0.004},
    ),
    "tube_waves_and_effects": (
        {
            "tube_waves": 1.0,
            "wall_heat_transfer_w_per_k": 0.5,
            "leakage_area_m2": 5e-8,
            "spool_coulomb_friction_n": 0.05,
        },
        {
            "tube_waves": 1.0,
            "coil_time_constant_s": 2e-3,
            "valve_null_leak_area_m2": 2e-8,
            "rod_seal_leak_area_m2": 5e-8,
            "flow_law": 1.0,
        },
    ),
    "all_batch_effects": (
        {
            "wall_heat_transfer_w_per_k": 0.5,
            "flow_law": 1.0,
            "coil_time_constant_s": 2e-3,
            "leakage_area_m2": 5e-8,
            "rod_seal_leak_area_m2": 5e-8,
            "spool_coulomb_friction_n": 0.05,
            "valve_null_leak_area_m2": 2e-8,
        },
        {
            "tube_air_model": 1.0,
            "tube_volume_fraction": 0.5,
            "flow_law": 1.0,
            "coil_time_constant_s": 1e-3,
            "leakage_area_m2": 1e-9,
        },
    ),
}
ROD_SETUPS = (
    {"tube_length_m": 2.0},
    {"tube_length_m": 0.5, "piston_mode": "free", "load_mass_kg": 0.1},
    {
        "tube_length_m": 1.0,
        "piston_mode": "spring",
        "spring_stiffness_n_per_m": 4000.0,
        "exhaust_discharge_ratio": 0.8,
    },
)


def _sets(effect):
    """Every rod setup with the effect's strong and weak setting, then a base-model lane and
    a general-path lane (an exhaust muffler) in the same chunk."""
    sets = [
        load_parameters("numatics", **rod, **setting)
        for setting in BATCH_EFFECTS[effect]
        for rod in ROD_SETUPS
    ]
    sets.append(load_parameters("airpel", **ROD_SETUPS[1]))
    muffler = {"exhaust_vent_area_m2": 5e-6, "exhaust_volume_m3": 1e-5}
    sets.append(load_parameters("numatics", **muffler, **ROD_SETUPS[1]))
    return sets


@pytest.mark.parametrize("effect", sorted(BATCH_EFFECTS))
def test_the_batch_path_takes_the_effect_lanes(effect):
    params = parameter_array(_sets(effect))
    kinds = [
        K.batch_lane_kind(kernel.env_constants(params, env, 2e-4)) for env in range(params.shape[1])
    ]
    want = [
        K.BATCH_LEAKS
        if {"leakage_area_m2", "rod_seal_leak_area_m2", "leakage_conductance_kg_per_pa_s"}
        & set(setting)
        else K.BATCH_BASE
        for setting in BATCH_EFFECTS[effect]
        for _ in ROD_SETUPS
    ]
    assert kinds == want + [K.BATCH_BASE, K.BATCH_GENERAL]


@pytest.mark.parametrize("seed", [1, 2, 3])
@pytest.mark.parametrize("effect", sorted(BATCH_EFFECTS))
def test_batch_effects_reproduce_the_general_path_bit_for_bit(effect, seed):
    sets = _sets(effect)
    currents = random_currents(np.random.default_rng(seed), 300, len(sets))
    moved = assert_batch_matches_general_path(sets, currents)
    assert moved  # the free and spring rods really moved (events, stops, sticking)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_chunk_of_transmission_lines_alone_reproduces_the_general_path(seed):
    """Every lane of the chunk with the tubes as transmission lines (the batch path then
    skips the valve's vectorised loop, ``constants.chunk_effects``), bit for bit."""
    sets = [
        load_parameters("numatics", **rod, **setting)
        for effect in ("tube_waves", "tube_waves_and_effects")
        for setting in BATCH_EFFECTS[effect]
        for rod in ROD_SETUPS
    ]
    currents = random_currents(np.random.default_rng(seed), 300, len(sets))
    assert assert_batch_matches_general_path(sets, currents)


# friction laws that act only on a moving rod: clamped, the batch path takes them
FRICTION_LAWS = (
    {"stribeck_velocity_m_per_s": 0.02, "static_friction_n": 8.0},
    {"lugre_stiffness_n_per_m": 1e5, "lugre_damping_n_s_per_m": 300.0},
    {"stribeck_velocity_m_per_s": 0.01, "lugre_stiffness_n_per_m": 2e4},
)


def _friction_sets():
    """Each friction law on a clamped rod (two tubes, one with a leak) and on a free rod,
    then a base-model lane."""
    sets = []
    for law in FRICTION_LAWS:
        sets.append(load_parameters("numatics", **ROD_SETUPS[0], **law))
        sets.append(load_parameters("airpel", tube_length_m=0.5, leakage_area_m2=5e-8, **law))
        sets.append(load_parameters("numatics", **ROD_SETUPS[1], **law))
    sets.append(load_parameters("airpel", **ROD_SETUPS[1]))
    return sets


def test_the_batch_path_takes_clamped_friction_laws():
    params = parameter_array(_friction_sets())
    kinds = [
        K.batch_lane_kind(kernel.env_constants(params, env, 2e-4)) for env in range(params.shape[1])
    ]
    assert kinds == [K.BATCH_BASE, K.BATCH_LEAKS, K.BATCH_GENERAL] * len(FRICTION_LAWS) + [
        K.BATCH_BASE
    ]


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_clamped_friction_laws_reproduce_the_general_path_bit_for_bit(seed):
    sets = _friction_sets()
    currents = random_currents(np.random.default_rng(seed), 300, len(sets))
    assert assert_batch_matches_general_path(sets, currents)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_the_valve_ends_solved_in_lockstep_equal_the_solve_lane_by_lane(seed):
    """``batch_lines``' valve-end solve over a chunk (random spool positions, closed ones
    among them, and waves from below the atmosphere to above the supply, so the lanes stop
    after different numbers of Illinois steps) gives each lane ``nodes._line_valve_end``'s
    pressure, flow and exhaust, bit for bit."""
    from pneumatic_env.physics import batch_lines as BL
    from pneumatic_env.physics.nodes import _line_valve_end
    from pneumatic_env.simulator import BatchSimulator

    rng = np.random.default_rng(seed)
    n = K.CHUNK_ENVS
    sets = [
        load_parameters(
            "numatics",
            tube_waves=1.0,
            discharge_coefficient=0.15 + 0.2 * rng.random(),
            supply_pressure_pa=4e5 + 4e5 * rng.random(),
            valve_null_leak_area_m2=float(rng.choice([0.0, 2e-8])),
        )
        for _ in range(n)
    ]
    sim = BatchSimulator(parameter_array(sets), 1e-3, 20)
    constants = sim.constants[0]
    K.refresh_constants(sim.params, 0, n, 5e-5, sim.constants_key, constants)
    rows = np.zeros(BL.N_ROWS * n)
    # spool positions from closed (inside the overlap) to fully open either way; waves from
    # below the atmosphere to above the supply
    spool = rng.choice([0.0, 1.0], n) * rng.uniform(-1.2e-3, 1.2e-3, n)
    waves = rng.uniform(0.3e5, 9e5, (2, n))
    expected = []
    for j in range(n):
        c = K.load_constants(constants, j)
        area_a, area_b = BL.line_valve_areas(c, spool[j])
        for end, (block, areas) in enumerate(
            ((BL.R_END, (area_a, area_b)), (BL.R_END + BL.N_END, (area_b, area_a)))
        ):
            rows[(block + BL.E_SUPPLY) * n + j] = areas[0]
            rows[(block + BL.E_EXHAUST) * n + j] = areas[1]
            rows[(BL.R_WAVES + end) * n + j] = waves[end, j]
        expected.append(
            (
                _line_valve_end(c, area_a, area_b, waves[0, j]),
                _line_valve_end(c, area_b, area_a, waves[1, j]),
            )
        )
    BL._solve(constants, rows, n, BL.R_END, BL.R_WAVES)
    BL._solve(constants, rows, n, BL.R_END + BL.N_END, BL.R_WAVES + 1)
    for j in range(n):
        for end, block in enumerate((BL.R_END, BL.R_END + BL.N_END)):
            got = BL._end(rows, block, j)
            assert got == expected[j][end], (j, end, got, expected[j][end])
    closed = sum(e[0] == (waves[0, j], 0.0, 0.0) for j, e in enumerate(expected))
    assert 0 < closed < n  # both closed and open valves were solved
