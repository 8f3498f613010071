"""Parameter configs (configs/*.yaml) and their loader (pneumatic_env.params)."""

import math
import shutil

import numpy as np
import pytest
import yaml

from conftest import assert_error_names
from pneumatic_env import params as P
from pneumatic_env.config_files import read_yaml
from pneumatic_env.params import (
    CYLINDER_PARAMETERS,
    CYLINDERS,
    ConfigError,
    config_dir,
    load_numerics,
    load_parameters,
    parameter_array,
    parameter_info,
    save_parameters,
)
from pneumatic_env.physics.layout import DISCRETE_PARAMETERS, N_PARAMS, PARAMETER_NAMES

NUMATICS = "numatics-0750D02-03A"
AIRPEL = "airpel-E16D3.0N"


def _raw(path):
    return read_yaml(path)


def _copy_configs(tmp_path, monkeypatch):
    monkeypatch.delenv(P.CONFIG_DIR_ENV, raising=False)
    dst = tmp_path / "configs"
    shutil.copytree(config_dir(), dst)
    monkeypatch.setenv(P.CONFIG_DIR_ENV, str(dst))
    return dst


# --------------------------------------------------------------------------- the configs


def test_every_parameter_defined_once_with_value_unit_source():
    cfg = config_dir()
    seen = {}
    for fname in P.BASE_FILES:
        for name in _raw(cfg / fname):
            assert name not in seen, f"{name} in {fname} and {seen[name]}"
            seen[name] = fname
    for name in PARAMETER_NAMES:
        if name in CYLINDER_PARAMETERS:
            assert name not in seen
        else:
            assert name in seen, name
    for canonical in CYLINDERS:
        entries = _raw(cfg / "cylinders" / f"{canonical}.yaml")
        assert set(CYLINDER_PARAMETERS) <= set(entries)
    for canonical in CYLINDERS:
        for name in PARAMETER_NAMES:
            info = parameter_info(name, cylinder=canonical)
            assert info["unit"] and info["source"]
            assert info["source"].startswith(
                ("paper ", "assumed: ", "assumed, chosen by measurement: ")
            ), (name, info["source"])
            if name in DISCRETE_PARAMETERS:
                assert set(info["allowed"]) == set(DISCRETE_PARAMETERS[name])
            else:
                assert info["min"] <= info["max"]


def test_numerics_not_in_parameter_rows():
    numerics_yaml = yaml.safe_load((config_dir() / "numerics.yaml").read_text())
    assert load_numerics() == {
        "control_dt_s": float(numerics_yaml["control_dt_s"]["value"]),
        "substeps": int(numerics_yaml["substeps"]["value"]),
    }
    assert isinstance(load_numerics()["substeps"], int)
    assert load_numerics(substeps=40)["substeps"] == 40
    with pytest.raises(ConfigError) as exc:
        load_numerics(substeps=2.5)
    assert_error_names(exc, "substeps", 2.5, ("whole number", "[1.0, 100000.0]"))
    assert "control_dt_s" not in load_parameters()
    assert parameter_info("control_dt_s")["unit"] == "s"


@pytest.mark.parametrize("cylinder", [NUMATICS, AIRPEL])
def test_both_cylinders_load_complete_and_ordered(cylinder):
    values = load_parameters(cylinder)
    assert list(values) == list(PARAMETER_NAMES)
    assert all(isinstance(v, float) and math.isfinite(v) for v in values.values())


def test_reference_values_from_model_notes():
    n = load_parameters("numatics")
    assert n["static_friction_n"] == 3.8
    assert n["dynamic_friction_n"] == 0.486
    assert n["viscous_friction_n_s_per_m"] == 4.47
    assert n["bore_diameter_m"] == 19.05e-3
    assert n["stroke_m"] == 76.2e-3
    assert n["discharge_coefficient"] == 0.25
    assert n["spool_damping_n_s_per_m"] == 7.5
    assert n["coil_force_n_per_a"] == 2.78
    assert n["spool_spring_n_per_m"] == 1000.0
    assert n["holes_per_path"] == 14.0
    assert n["supply_pressure_pa"] == 6.5e5
    assert n["tube_length_m"] == 0.5
    assert n["tube_coupling"] == 0.0 and n["piston_mode"] == 0.0
    assert n["flow_linear_ratio"] == 0.995
    a = load_parameters("airpel")
    assert a["dynamic_friction_n"] == 0.8
    assert a["static_friction_n"] == 0.0
    assert a["bore_diameter_m"] == 15.93e-3
    assert parameter_info("static_friction_n")["source"] == "paper Sec. 3: identified F_sf = 3.8 N"
    assert parameter_info("supply_pressure_pa")["source"].startswith("assumed: ")
    assert parameter_info("coil_current_max_a", AIRPEL)["source"].startswith("assumed: ")


# --------------------------------------------------------------------------- selection


def test_cylinder_aliases_case_insensitive():
    ref = load_parameters(AIRPEL)
    assert load_parameters("airpel") == ref
    assert load_parameters("AIRPEL") == ref
    assert load_parameters("Airpel-e16d3.0n") == ref
    assert load_parameters("Numatics") == load_parameters()
    assert P.resolve_cylinder("NUMATICS") == NUMATICS


def test_unknown_cylinder_lists_known():
    with pytest.raises(ConfigError) as exc:
        load_parameters("festo")
    # a guard of the wording: the whole sentence
    assert str(exc.value) == (
        "unknown cylinder 'festo'; known cylinders: 'numatics-0750D02-03A' (alias "
        "'numatics'), 'airpel-E16D3.0N' (alias 'airpel')"
    )


def test_overrides_params_and_discrete_names(tmp_path):
    v = load_parameters(
        tube_length_m=2.0,
        tube_coupling="literal",
        piston_mode="Spring",
        spring_stiffness_n_per_m=500,
    )
    assert v["tube_length_m"] == 2.0
    assert v["tube_coupling"] == 1.0 and v["piston_mode"] == 2.0
    assert v["spring_stiffness_n_per_m"] == 500.0
    v = load_parameters(
        params={"supply_pressure_pa": 5e5, "load_mass_kg": {"value": 0.2, "unit": "kg"}},
        supply_pressure_pa=4e5,
    )
    assert v["supply_pressure_pa"] == 4e5 and v["load_mass_kg"] == 0.2
    with pytest.raises(ConfigError) as exc:
        load_parameters(params={"load_mass_kg": {"value": 200, "unit": "g"}})
    assert_error_names(exc, ("params", "load_mass_kg"), "g", "'kg'")


# --------------------------------------------------------------------------- error messages


def _error(**kw):
    with pytest.raises(ConfigError) as exc:
        load_parameters(**kw)
    assert isinstance(exc.value, ValueError)
    return str(exc.value)


def test_unknown_field_suggests_close_match():
    # a guard of the wording: the whole sentence
    assert _error(suply_pressure_pa=5e5) == (
        "override 'suply_pressure_pa' is not a known parameter; did you mean 'supply_pressure_pa'?"
    )
    assert_error_names(
        _error(alpha=1.2), ("override", "'alpha'"), rule=("'alpha_in'", "'alpha_out'")
    )
    assert_error_names(
        _error(params={"bore_diam": 0.02}), ("params", "'bore_diam'"), rule="'bore_diameter_m'"
    )
    assert_error_names(_error(bore=0.02), "'bore'", rule="'bore_diameter_m'")
    assert_error_names(_error(zzz=1), "'zzz'", rule="pneumatic_env.physics.layout.PARAMETER_NAMES")


def test_out_of_range():
    # a guard of the wording: the whole sentence
    assert _error(supply_pressure_pa=-3.0) == (
        "override 'supply_pressure_pa' = -3.0 is not allowed: must be in [100000.0, 2000000.0] Pa"
    )
    assert_error_names(_error(discharge_coefficient=0), "discharge_coefficient", 0, "(0.0, 1.0]")


def test_nan_and_non_numeric():
    assert_error_names(
        _error(temperature_k=float("nan")),
        "temperature_k",
        float("nan"),
        ("finite number", "(0.0, inf] K"),
    )
    assert_error_names(
        _error(load_mass_kg="heavy"), "load_mass_kg", "heavy", ("number", "[0.0, inf] kg")
    )
    assert_error_names(_error(load_mass_kg="0.5"), "load_mass_kg", "0.5", "[0.0, inf] kg")
    assert_error_names(_error(load_mass_kg=True), "load_mass_kg", True, "[0.0, inf] kg")


def test_cross_field_rules():
    assert_error_names(
        _error(supply_pressure_pa=1.005e5),
        "supply_pressure_pa",
        100500.0,
        ("greater than", "ambient_pressure_pa = 101325.0 Pa"),
    )
    assert_error_names(
        _error(ambient_pressure_pa=1.5e5, params={"supply_pressure_pa": 1.2e5}),
        "ambient_pressure_pa",
        150000.0,
        ("less than", "supply_pressure_pa = 120000.0 Pa"),
    )
    assert_error_names(
        _error(rod_diameter_m=19.05e-3),
        "rod_diameter_m",
        0.01905,
        ("less than", "bore_diameter_m = 0.01905 m"),
    )
    assert_error_names(
        _error(cylinder="airpel", bore_diameter_m=4e-3),
        "bore_diameter_m",
        0.004,
        ("greater than", "rod_diameter_m = 0.00476 m"),
    )
    assert_error_names(
        _error(fixed_position_m=-0.04), "fixed_position_m", -0.04, "+-stroke_m/2 = 0.0381 m"
    )
    assert_error_names(
        _error(spring_rest_position_m=0.05),
        "spring_rest_position_m",
        0.05,
        "+-stroke_m/2 = 0.0381 m",
    )
    assert_error_names(
        _error(alpha_in=1.5), "alpha_in", 1.5, ("at most", "heat_capacity_ratio = 1.4")
    )
    assert_error_names(
        _error(flow_linear_ratio=0.5), "flow_linear_ratio", 0.5, ("(P_cr, 1)", "(0.528")
    )
    assert load_parameters(fixed_position_m=0.0381)["fixed_position_m"] == 0.0381


def test_bad_discrete_value():
    for value in ("delayed", 0.5, 2):
        assert_error_names(
            _error(tube_coupling=value), "tube_coupling", value, ("0 ('command')", "1 ('literal')")
        )
    assert_error_names(
        _error(piston_mode="clamped"),
        "piston_mode",
        "clamped",
        ("0 ('fixed')", "1 ('free')", "2 ('spring')"),
    )


def test_malformed_config_files(tmp_path, monkeypatch):
    cfg = _copy_configs(tmp_path, monkeypatch)
    load_parameters()  # the copy is valid
    air = cfg / "air.yaml"
    text = air.read_text()
    air.write_text(text.replace("  unit: Pa s\n", ""))
    with pytest.raises(ConfigError) as exc:
        load_parameters()
    assert_error_names(exc, (str(air), "air_viscosity_pa_s"), rule="'unit'")
    air.write_text(text.replace("value: 6.5e+5", "value: 5.0e+4"))
    with pytest.raises(ConfigError) as exc:
        load_parameters()
    assert_error_names(exc, (str(air), "supply_pressure_pa"), 50000.0, "[100000.0, 2000000.0] Pa")
    air.write_text(text + "\nbroken: [\n")
    with pytest.raises(ConfigError) as exc:
        load_parameters()
    assert_error_names(exc, str(air), rule="YAML")
    air.write_text(text.replace("alpha_motion:", "alpha_motoin:"))
    with pytest.raises(ConfigError) as exc:
        load_parameters()
    assert_error_names(exc, (str(air), "'alpha_motoin'"), rule="'alpha_motion'")
    air.write_text(text)
    cyl = cfg / "cylinders" / f"{NUMATICS}.yaml"
    cyl.write_text(cyl.read_text().replace("value: 6.35e-3", "value: 25.0e-3"))
    with pytest.raises(ConfigError) as exc:
        load_parameters()
    assert_error_names(exc, (str(cyl), "rod_diameter_m"), 0.025, "bore_diameter_m")


def test_cylinder_file_overrides_and_custom_cylinder(tmp_path, monkeypatch):
    cfg = _copy_configs(tmp_path, monkeypatch)
    src = (cfg / "cylinders" / f"{AIRPEL}.yaml").read_text()
    extra = (
        "\nsupply_pressure_pa:\n  value: 4.0e+5\n  unit: Pa\n"
        '  source: "assumed: test"\n  min: 1.0e+5\n  max: 1.0e+6\n'
    )
    (cfg / "cylinders" / "my-cyl.yaml").write_text(src + extra)
    assert load_parameters("MY-CYL")["supply_pressure_pa"] == 4e5
    assert load_parameters(cfg / "cylinders" / "my-cyl.yaml")["supply_pressure_pa"] == 4e5
    assert_error_names(_error(cylinder="nope"), "'nope'", rule="'my-cyl'")


# --------------------------------------------------------------------------- save / array


def test_save_load_round_trip(tmp_path):
    values = load_parameters("airpel", tube_length_m=2.0, tube_coupling="literal")
    values["dynamic_friction_n"] = 0.8123456789012345
    values["dead_volume_cap_m3"] = 1.2345678901234567e-7
    path = tmp_path / "fit.yaml"
    save_parameters(
        path, values, notes="step response 2026-01-01", uncertainties={"dynamic_friction_n": 0.01}
    )
    assert load_parameters(params=path) == values
    assert load_parameters(AIRPEL, params=str(path)) == values
    doc = _raw(path)
    assert list(doc) == list(PARAMETER_NAMES)
    assert doc["dynamic_friction_n"]["source"] == "fitted: step response 2026-01-01"
    assert doc["dynamic_friction_n"]["uncertainty"] == 0.01
    assert doc["dynamic_friction_n"]["unit"] == "N"
    assert (
        doc["static_friction_n"]["source"] == parameter_info("static_friction_n", AIRPEL)["source"]
    )
    assert doc["tube_coupling"]["value"] == 1
    # a partial set is filled from the configs
    save_parameters(path, {"supply_pressure_pa": 5.5e5})
    assert load_parameters(params=path) == load_parameters(supply_pressure_pa=5.5e5)
    assert _raw(path)["supply_pressure_pa"]["source"] == "fitted"
    with pytest.raises(ConfigError) as exc:
        save_parameters(path, {"supply_pressure_pa": -1.0})
    assert_error_names(exc, "supply_pressure_pa", -1.0, "[100000.0, 2000000.0] Pa")


def test_params_file_edits_are_seen(tmp_path):
    path = tmp_path / "p.yaml"
    path.write_text("load_mass_kg: 0.1\n")
    assert load_parameters(params=path)["load_mass_kg"] == 0.1
    path.write_text("load_mass_kg: 0.25\nload_force_n: 1e1\n")
    v = load_parameters(params=path)
    assert v["load_mass_kg"] == 0.25 and v["load_force_n"] == 10.0
    path.write_text("load_mas_kg: 0.25\n")
    with pytest.raises(ConfigError) as exc:
        load_parameters(params=path)
    assert_error_names(exc, (str(path), "'load_mas_kg'"), rule="'load_mass_kg'")


def test_parameter_array():
    a = load_parameters("numatics")
    b = load_parameters("airpel", tube_length_m=2.0)
    arr = parameter_array([a, b])
    assert arr.shape == (N_PARAMS, 2)
    assert arr.dtype == np.float64 and arr.flags.c_contiguous
    for i, name in enumerate(PARAMETER_NAMES):
        assert arr[i, 0] == a[name] and arr[i, 1] == b[name]
    one = parameter_array(a)
    assert one.shape == (N_PARAMS, 1)
    assert np.array_equal(one[:, 0], arr[:, 0])
    incomplete = dict(a)
    del incomplete["stroke_m"]
    with pytest.raises(ConfigError) as exc:
        parameter_array([a, incomplete])
    assert_error_names(exc, ("parameter set 1", "stroke_m"), rule="missing")


def test_config_dir_env_override(tmp_path, monkeypatch):
    default = config_dir()
    assert (default / "air.yaml").is_file()
    monkeypatch.setenv(P.CONFIG_DIR_ENV, str(tmp_path / "missing"))
    with pytest.raises(ConfigError) as exc:
        config_dir()
    assert_error_names(exc, P.CONFIG_DIR_ENV, str(tmp_path / "missing"), "not a directory")
    cfg = _copy_configs(tmp_path, monkeypatch)
    assert config_dir() == cfg.resolve()
