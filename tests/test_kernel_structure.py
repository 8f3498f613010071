"""The kernel's named structures: the written-out row constants of physics/layout.py match
their tables, and the kernel's ``Constants`` carry each field from its named source
through ``env_constants`` and the batch path's cache (``store_constants`` /
``load_constants``)."""

from __future__ import annotations

import numpy as np
import pytest

from pneumatic_env.params import load_parameters, parameter_array
from pneumatic_env.physics import kernel
from pneumatic_env.physics import layout as L


@pytest.mark.parametrize("prefix, names", [("P_", L.PARAMETER_NAMES), ("S_", L.STATE_NAMES)])
def test_row_constants_are_the_rows_of_their_names(prefix, names):
    for row, name in enumerate(names):
        assert getattr(L, prefix + name.upper()) == row, name
    assert (L.N_PARAMS, L.N_STATE) == (len(L.PARAMETER_NAMES), len(L.STATE_NAMES))
    assert all(L.PARAMETER_INDEX[name] == row for row, name in enumerate(L.PARAMETER_NAMES))


def test_the_layout_check_catches_a_wrong_row():
    """``layout._check_rows`` (run at import) refuses two swapped rows and a missing one."""
    namespace = dict(vars(L))
    L._check_rows(namespace)
    swapped = dict(
        namespace, P_BORE_DIAMETER_M=L.P_ROD_DIAMETER_M, P_ROD_DIAMETER_M=L.P_BORE_DIAMETER_M
    )
    with pytest.raises(AssertionError, match="P_BORE_DIAMETER_M"):
        L._check_rows(swapped)
    missing = {k: v for k, v in namespace.items() if k != "S_T2_K"}
    with pytest.raises(AssertionError, match="S_T2_K"):
        L._check_rows(missing)


def test_constants_round_trip_through_the_chunk_cache():
    """Every field comes back from the cache in its own place: distinct values per field."""
    fields = kernel.Constants._fields
    original = kernel.Constants(*(1.5 + i for i in range(len(fields))))
    for lane in (0, 5, kernel.CHUNK_ENVS - 1):
        cache = np.zeros(kernel.N_CACHED_CONSTANTS * kernel.CHUNK_ENVS)
        kernel.store_constants(original, cache, lane)
        assert tuple(kernel.load_constants(cache, lane)) == tuple(original)
        rows = cache.reshape(kernel.N_CACHED_CONSTANTS, kernel.CHUNK_ENVS)[:, lane]
        assert rows[kernel.C_DELAY_SUBSTEPS] == original.delay_substeps
        assert rows[kernel.C_SPOOL_PLAY_BAND] == original.spool_play_band


# Constants fields that copy one parameter row as it is
COPIED = {
    "k": "heat_capacity_ratio",
    "gas": "gas_constant_j_per_kg_k",
    "temperature": "temperature_k",
    "linear_ratio": "flow_linear_ratio",
    "supply_pa": "supply_pressure_pa",
    "ambient_pa": "ambient_pressure_pa",
    "viscosity": "air_viscosity_pa_s",
    "alpha_in": "alpha_in",
    "alpha_out": "alpha_out",
    "alpha_motion": "alpha_motion",
    "spool_damping": "spool_damping_n_s_per_m",
    "spool_spring": "spool_spring_n_per_m",
    "coil_force": "coil_force_n_per_a",
    "discharge": "discharge_coefficient",
    "hole_radius": "hole_radius_m",
    "half_width": "spool_half_width_m",
    "holes": "holes_per_path",
    "tube_diameter": "tube_inner_diameter_m",
    "reynolds_turbulent": "reynolds_turbulent",
    "dynamic_friction": "dynamic_friction_n",
    "static_friction": "static_friction_n",
    "viscous": "viscous_friction_n_s_per_m",
    "leak_area": "leakage_area_m2",
    "load_force": "load_force_n",
    "spring_k": "spring_stiffness_n_per_m",
    "spring_rest": "spring_rest_position_m",
    "null_leak": "valve_null_leak_area_m2",
    "seal_leak": "rod_seal_leak_area_m2",
    "leak_conductance": "leakage_conductance_kg_per_pa_s",
    "supply_resistance": "supply_resistance_pa_s_per_kg",
    "exhaust_vent": "exhaust_vent_area_m2",
    "heat_conductance": "wall_heat_transfer_w_per_k",
    "stribeck_v": "stribeck_velocity_m_per_s",
    "lugre_stiffness": "lugre_stiffness_n_per_m",
    "lugre_damping": "lugre_damping_n_s_per_m",
}


def test_env_constants_take_each_field_from_its_named_parameter():
    """With every copied parameter at its own value, each field holds its parameter's (a
    swap of two fields in ``env_constants`` would show), and the derived fields follow."""
    p = load_parameters("numatics", tube_length_m=1.0, piston_mode="spring")
    for i, name in enumerate(COPIED.values()):
        p[name] = p[name] * (1.0 + 0.01 * (i + 1)) + 1e-9 * (i + 1)  # all distinct
    params = parameter_array([p])
    c = kernel.env_constants(params, 0, 5e-5)
    values = {field: getattr(c, field) for field in COPIED}
    assert len(set(values.values())) == len(COPIED)
    for field, name in COPIED.items():
        assert values[field] == params[L.PARAMETER_INDEX[name], 0], (field, name)
    assert c.gas_rt == c.gas * c.temperature
    assert c.inv_spool_mass == 1.0 / p["spool_mass_kg"]
    assert c.inv_moving_mass == 1.0 / (p["piston_mass_kg"] + p["load_mass_kg"])
    assert c.half_stroke == 0.5 * p["stroke_m"]
    assert c.discharge_ex == c.discharge * p["exhaust_discharge_ratio"]
    assert c.delay_substeps == c.delay_s / 5e-5
    assert c.mode == 2.0 and c.inv_k == 1.0 / c.k and c.inv_hole_radius == 1.0 / c.hole_radius
