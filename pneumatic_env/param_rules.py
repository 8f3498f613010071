"""Cross-field rules of a parameter set: relations between parameters that each file's
ranges cannot state (the valve's null, the cylinder's geometry, the numerics). A
violation blames the most specific field (an override before a cylinder file before a
base file) and names both values."""

from __future__ import annotations

from collections.abc import Callable

from pneumatic_env.config_files import ConfigError
from pneumatic_env.text_format import number_text, value_text


def _p_cr(k: float) -> float:
    return (2.0 / (k + 1.0)) ** (k / (k - 1.0))


# (a, b, holds(values), complaint about a, complaint about b): a violated rule is reported
# on whichever of a and b comes from the more specific source (a on a tie).
# (the lambdas bind their loop variables as defaults, hence Callable[..., ...])
_Rule = tuple[str, str, Callable[..., bool], Callable[..., str], Callable[..., str]]
_RULES: list[_Rule] = [
    (
        "supply_pressure_pa",
        "ambient_pressure_pa",
        lambda v: v["supply_pressure_pa"] > v["ambient_pressure_pa"],
        lambda v: f"greater than ambient_pressure_pa = {number_text(v['ambient_pressure_pa'])} Pa",
        lambda v: f"less than supply_pressure_pa = {number_text(v['supply_pressure_pa'])} Pa",
    ),
    (
        "rod_diameter_m",
        "bore_diameter_m",
        lambda v: v["rod_diameter_m"] < v["bore_diameter_m"],
        lambda v: f"less than bore_diameter_m = {number_text(v['bore_diameter_m'])} m",
        lambda v: f"greater than rod_diameter_m = {number_text(v['rod_diameter_m'])} m",
    ),
]
for _pos in ("fixed_position_m", "spring_rest_position_m"):
    _RULES.append(
        (
            _pos,
            "stroke_m",
            lambda v, p=_pos: abs(v[p]) <= v["stroke_m"] / 2.0,
            lambda v: f"within +-stroke_m/2 = {number_text(v['stroke_m'] / 2.0)} m",
            lambda v, p=_pos: f"at least 2 |{p}| = {number_text(2.0 * abs(v[p]))} m",
        )
    )
for _alpha in ("alpha_in", "alpha_out", "alpha_motion"):
    _RULES.append(
        (
            _alpha,
            "heat_capacity_ratio",
            lambda v, a=_alpha: v[a] <= v["heat_capacity_ratio"],
            lambda v: f"at most heat_capacity_ratio = {number_text(v['heat_capacity_ratio'])}",
            lambda v, a=_alpha: f"at least {a} = {number_text(v[a])}",
        )
    )
_RULES.append(
    (
        "flow_linear_ratio",
        "heat_capacity_ratio",
        lambda v: _p_cr(v["heat_capacity_ratio"]) < v["flow_linear_ratio"] < 1.0,
        lambda v: (
            f"in (P_cr, 1) = ({number_text(_p_cr(v['heat_capacity_ratio']))}, 1.0), P_cr the "
            f"critical pressure ratio for heat_capacity_ratio = "
            f"{number_text(v['heat_capacity_ratio'])}"
        ),
        lambda v: (
            f"such that the critical pressure ratio P_cr (here "
            f"{number_text(_p_cr(v['heat_capacity_ratio']))}) is below flow_linear_ratio = "
            f"{number_text(v['flow_linear_ratio'])}"
        ),
    )
)
# The transmission line replaces the paper's tube coupling and holds the tube's air itself;
# the supply droop's own root solve is not nested in the line's valve-end solve.
for _other, _off, _why in (
    ("tube_coupling", 0.0, "command (0): the transmission line couples valve and chamber"),
    ("tube_volume_fraction", 0.0, "0: the transmission line holds the tube's air itself"),
    (
        "supply_resistance_pa_s_per_kg",
        0.0,
        "0: the supply droop is not implemented with the transmission line",
    ),
    (
        "exhaust_vent_area_m2",
        0.0,
        "0: the exhaust back-pressure is not implemented with the transmission line",
    ),
):
    _RULES.append(
        (
            _other,
            "tube_waves",
            lambda v, o=_other, off=_off: v["tube_waves"] == 0.0 or v[o] == off,
            lambda v, why=_why: f"{why} (tube_waves = 1)",
            lambda v, o=_other: f"0 (off) while {o} = {value_text(v[o])}",
        )
    )
# The isothermal tube air is written for Eq. 14, not for the energy model's temperatures.
_RULES.append(
    (
        "tube_air_model",
        "wall_heat_transfer_w_per_k",
        lambda v: v["tube_air_model"] == 0.0 or v["wall_heat_transfer_w_per_k"] == 0.0,
        lambda v: (
            "dead_volume (0): the isothermal tube air is not implemented with the energy "
            "model (wall_heat_transfer_w_per_k > 0)"
        ),
        lambda v: f"0 (off) while tube_air_model = {value_text(v['tube_air_model'])}",
    )
)
del _pos, _alpha, _other, _off, _why


def _check_relations(values: dict, origin: dict, level: dict) -> None:
    for a, b, holds, about_a, about_b in _RULES:
        if holds(values):
            continue
        name, why = (a, about_a) if level[a] >= level[b] else (b, about_b)
        shown = value_text(values[name])
        rule = why(values)
        raise ConfigError(f"{origin[name]} {name!r} = {shown} is not allowed: must be {rule}")
