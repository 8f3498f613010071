"""Measurement recording format: reader, writer, plausibility warnings, rig mapping."""

import hashlib
import json
import re
import warnings

import numpy as np
import pytest

from conftest import NO_VALUE, assert_error_names
from pneumatic_env.recording import (
    Recording,
    RecordingError,
    RecordingWarning,
    read_recording,
    rig_to_parameter_overrides,
    write_recording,
)

RIG = {
    "cylinder": "numatics-0750D02-03A",
    "tube_length_m": 0.5,
    "supply_pressure_pa": 650000.0,
    "ambient_pressure_pa": 101325.0,
    "temperature_k": 293.15,
    "piston": {"mode": "fixed", "position_m": 0.0},
    "notes": "free text",
}


def _signals(n=200, dt=1e-3):
    t = np.arange(n) * dt
    rng = np.random.default_rng(0)
    return t, {
        "i_c": 0.1 * np.sin(2 * np.pi * 5 * t) + 0.01 * rng.standard_normal(n),
        "p1": 3e5 + 1e5 * np.sin(2 * np.pi * 3 * t) + 100 * rng.standard_normal(n),
        "p2": 2.5e5 + 5e4 * np.cos(2 * np.pi * 3 * t) + 100 * rng.standard_normal(n),
        "f": 10 * np.sin(2 * np.pi * 3 * t) + 0.1 * rng.standard_normal(n),
    }


def _write_raw(tmp_path, csv_text, rig=None, name="run1"):
    rig = dict({"format": "pneumatic-measurement", "version": 1}, **(RIG if rig is None else rig))
    (tmp_path / f"{name}.csv").write_text(csv_text)
    (tmp_path / f"{name}.json").write_text(json.dumps(rig, indent=2))
    return tmp_path / f"{name}.csv"


def _write_json(tmp_path, rig_text, name="run1"):
    t, ch = _signals(20)
    write_recording(tmp_path / name, t, ch, RIG)
    text = rig_text if isinstance(rig_text, str) else json.dumps(rig_text)
    (tmp_path / f"{name}.json").write_text(text)
    return tmp_path / f"{name}.csv"


def _good_csv(n=20):
    rows = ["t,i_c,p1"]
    for k in range(n):
        rows.append(f"{k * 0.001!r},{0.01 * (k % 7)!r},{300000.0 + 1000.0 * (k % 5)!r}")
    return rows


def _read_quiet(path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RecordingWarning)
        return read_recording(path)


# --------------------------------------------------------------------------- round trip


def test_round_trip_is_exact(tmp_path):
    t, ch = _signals()
    ch["x"] = 0.01 * np.sin(np.arange(len(t)) * 0.1)
    ch["v"] = np.gradient(ch["x"], t)
    ch["x_s"] = 1e-4 * np.tanh(ch["i_c"])
    ch["p_s"] = 650000.0 + 50 * np.sin(np.arange(len(t)))
    rig = dict(RIG, initial={"p1": 101325.0, "x": 0.0})
    path = write_recording(tmp_path / "run1", t, ch, rig)
    assert path == tmp_path / "run1.csv"
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rec = read_recording(path)
    assert isinstance(rec, Recording)
    np.testing.assert_array_equal(rec.t, t)
    assert list(rec.channels) == ["i_c", "p1", "p2", "x", "f", "v", "x_s", "p_s"]
    for name, y in ch.items():
        assert rec.channels[name].tobytes() == np.asarray(y, dtype=float).tobytes(), name
    assert rec.rig == dict({"format": "pneumatic-measurement", "version": 1}, **rig)
    assert rec.path == path
    assert rec.warnings == []
    header = path.read_text().splitlines()[0]
    assert header == "t,i_c,p1,p2,x,f,v,x_s,p_s"
    sidecar = json.loads((tmp_path / "run1.json").read_text())
    assert list(sidecar)[:2] == ["format", "version"]


def test_properties(tmp_path):
    t, ch = _signals(101, dt=2e-3)
    del ch["p2"]
    ch["x"] = 0.01 * np.sin(t * 7)
    write_recording(tmp_path / "r", t, ch, RIG)
    rec = _read_quiet(tmp_path / "r")
    assert rec.dt == pytest.approx(2e-3, rel=1e-12)
    assert rec.duration == pytest.approx(0.2, rel=1e-12)
    assert rec.i_c is rec.channels["i_c"]
    assert rec.has("p1") and rec.has("x") and rec.has("t") and not rec.has("p2")
    assert rec.measured_outputs == ("p1", "x", "f")


def test_rig_is_kept_as_the_file_says(tmp_path):
    rig = {
        "cylinder": "Airpel",
        "tube_length_m": 2,
        "piston": {"mode": "free", "load_mass_kg": 1, "load_force_n": 0},
    }
    t, ch = _signals(20)
    write_recording(tmp_path / "r", t, ch, rig)
    rec = _read_quiet(tmp_path / "r.json")
    assert rec.rig == {"format": "pneumatic-measurement", "version": 1, **rig}
    assert "supply_pressure_pa" not in rec.rig


@pytest.mark.parametrize("suffix", ["", ".csv", ".json", ".CSV"])
def test_stem_csv_and_json_paths(tmp_path, suffix):
    t, ch = _signals(30)
    write_recording(tmp_path / "run.v2", t, ch, RIG)
    assert (tmp_path / "run.v2.csv").exists() and (tmp_path / "run.v2.json").exists()
    rec = _read_quiet(str(tmp_path / "run.v2") + suffix)
    np.testing.assert_array_equal(rec.t, t)


def test_write_accepts_csv_and_json_paths(tmp_path):
    t, ch = _signals(10)
    assert write_recording(tmp_path / "a.csv", t, ch, RIG) == tmp_path / "a.csv"
    assert write_recording(tmp_path / "b.json", t, ch, RIG) == tmp_path / "b.csv"
    assert (tmp_path / "b.json").exists()


def test_reading_does_not_modify_files(tmp_path):
    t, ch = _signals(50)
    ch["p1"][:] = ch["p1"] - 101325.0 - 2.5e5  # gauge pressure: a warning, still read
    with pytest.warns(RecordingWarning, match="unknown key 'extra_key'"):
        write_recording(tmp_path / "r", t, ch, dict(RIG, extra_key=1))
    files = sorted(tmp_path.iterdir())
    before = {p: (hashlib.sha256(p.read_bytes()).hexdigest(), p.stat().st_mtime_ns) for p in files}
    with pytest.warns(RecordingWarning):
        read_recording(tmp_path / "r")
    assert sorted(tmp_path.iterdir()) == files
    after = {p: (hashlib.sha256(p.read_bytes()).hexdigest(), p.stat().st_mtime_ns) for p in files}
    assert before == after


def test_reader_accepts_crlf_bom_and_final_newline(tmp_path):
    text = "\ufeff" + "\r\n".join(_good_csv()) + "\r\n"
    path = _write_raw(tmp_path, text)
    rec = _read_quiet(path)
    assert len(rec.t) == 20 and rec.measured_outputs == ("p1",)


# --------------------------------------------------------------------------- CSV errors


def _err(tmp_path, csv_text):
    """The RecordingError that reading ``csv_text`` (as run1.csv) raises."""
    path = _write_raw(tmp_path, csv_text)
    with pytest.raises(RecordingError) as info:
        _read_quiet(path)
    return info.value


def _at(error, line=None, column=None, file="run1.csv", attributes=True):
    """Assert the error's location: named in the message and (``attributes``) held in the
    error's ``file``, ``line`` and ``column``."""
    if attributes:  # the checks of the time column name it in the message only
        assert (error.file, error.line, error.column) == (file, line, column)
    where = [file] + ([f"line {line}"] if line else []) + ([f"'{column}'"] if column else [])
    assert_error_names(error, where)
    return error


def test_error_not_a_number(tmp_path):
    rows = _good_csv()
    rows[16] = "0.015,0.0,abc"
    e = _at(_err(tmp_path, "\n".join(rows) + "\n"), 17, "p1")
    assert_error_names(e, "'p1'", "abc", "not a number")


def test_error_decimal_comma_in_semicolon_file(tmp_path):
    e = _at(_err(tmp_path, "t;i_c;p1\n0;0;1\n"), 1)
    assert_error_names(e, "header", "t;i_c;p1", ("single column", "separator", "','"))


def test_error_empty_cell(tmp_path):
    rows = _good_csv()
    rows[5] = "0.004,,300000.0"
    assert_error_names(_at(_err(tmp_path, "\n".join(rows)), 6, "i_c"), "'i_c'", rule="empty cell")


@pytest.mark.parametrize("word", ["nan", "NaN", "inf", "-inf", "Infinity"])
def test_error_nan_inf(tmp_path, word):
    rows = _good_csv()
    rows[3] = f"0.002,0.0,{word}"
    e = _at(_err(tmp_path, "\n".join(rows)), 4, "p1")
    assert_error_names(e, "'p1'", word, "NaN and inf are not allowed")


def test_error_overflow(tmp_path):
    rows = _good_csv()
    rows[3] = "0.002,0.0,1e999"
    e = _at(_err(tmp_path, "\n".join(rows)), 4, "p1")
    assert_error_names(e, "'p1'", "1e999", "finite number")


def test_error_underscore_and_decimal_comma_are_not_numbers(tmp_path):
    rows = _good_csv()
    rows[3] = "0.002,0.0,300_000"
    e = _at(_err(tmp_path, "\n".join(rows)), 4, "p1")
    assert_error_names(e, "'p1'", "300_000", "not a number")


@pytest.mark.parametrize("row,n", [("0.002,0.0", 2), ("0.002,0.0,1,2", 4)])
def test_error_wrong_number_of_cells(tmp_path, row, n):
    rows = _good_csv()
    rows[3] = row
    e = _at(_err(tmp_path, "\n".join(rows)), 4)
    assert_error_names(e, "line 4", rule=(f"{n} cells", "3 columns"))


def test_error_blank_line_inside(tmp_path):
    rows = _good_csv()
    rows[3] = ""
    e = _at(_err(tmp_path, "\n".join(rows)), 4)
    assert_error_names(e, "line 4", rule=("empty line", "one sample"))


@pytest.mark.parametrize("header,missing", [("i_c,p1", "t"), ("t,p1", "i_c")])
def test_error_missing_required_column(tmp_path, header, missing):
    e = _at(_err(tmp_path, header + "\n0,1\n1,2\n"), 1, missing)
    assert_error_names(e, f"'{missing}'", rule="missing required column")


def test_error_headerless_file_hints(tmp_path):
    e = _at(_err(tmp_path, "0,0.5,1e5\n1,0,2\n"), 1)
    assert_error_names(e, "first line", "0,0.5,1e5", ("header", "column names"))


def test_error_no_output_column(tmp_path):
    e = _at(_err(tmp_path, "t,i_c,v\n0,0,0\n1,0,0\n"), 1)
    assert_error_names(e, "columns", rule=("'p1'", "'p2'", "'x'", "'f'"))


def test_error_duplicate_column(tmp_path):
    e = _at(_err(tmp_path, "t,i_c,p1,p1\n0,0,1,1\n1,0,2,2\n"), 1, "p1")
    assert_error_names(e, "'p1'", rule="duplicate")


def test_error_empty_column_name(tmp_path):
    e = _at(_err(tmp_path, "t,i_c,,p1\n0,0,1,1\n1,0,2,2\n"), 1)
    assert_error_names(e, "column 3", rule="empty column name")


def test_error_t_not_increasing(tmp_path):
    rows = _good_csv()
    rows[10] = "0.008,0.0,300000.0"  # sample 9 is t=0.008 too
    e = _at(_err(tmp_path, "\n".join(rows)), 11, "t", attributes=False)
    assert_error_names(e, "'t'", 0.008, "strictly increasing")


def test_error_t_decreasing(tmp_path):
    rows = _good_csv()
    rows[10] = "0.005,0.0,300000.0"
    e = _at(_err(tmp_path, "\n".join(rows)), 11, "t", attributes=False)
    assert_error_names(e, "'t'", 0.005, ("0.008", "strictly increasing"))


def test_error_gap_in_time(tmp_path):
    rows = _good_csv()
    rows = rows[:8] + [
        r.replace(r.split(",")[0], repr(float(r.split(",")[0]) + 0.01)) for r in rows[8:]
    ]
    e = _at(_err(tmp_path, "\n".join(rows)), 9, "t", attributes=False)
    assert_error_names(e, "'t'", rule=("gap in time", "0.011 s", "t=0.006", "t=0.017", "0.001 s"))


@pytest.mark.parametrize("jitter,ok", [(5e-7, True), (-9e-7, True), (2e-6, False), (-5e-6, False)])
def test_jitter_threshold(tmp_path, jitter, ok):
    dt = 1e-3
    t = np.arange(30) * dt
    t[12] += jitter * dt
    rows = ["t,i_c,p1"] + [f"{float(v)!r},0.0,{300000.0 + 10 * k!r}" for k, v in enumerate(t)]
    path = _write_raw(tmp_path, "\n".join(rows))
    if ok:
        rec = _read_quiet(path)
        np.testing.assert_array_equal(rec.t, t)
    else:
        # the first bad step is the one into sample 12, on line 14; a guard of the wording:
        # the whole sentence
        with pytest.raises(
            RecordingError,
            match=r"^run1\.csv line 14, column 't': non-uniform "
            r"sampling: step [0-9.e-]+ s found .*, 0\.001 s expected \(relative "
            r"deviation [0-9.e-]+, allowed 1e-06\)$",
        ):
            _read_quiet(path)


def test_error_too_few_rows(tmp_path):
    assert_error_names(
        _at(_err(tmp_path, "t,i_c,p1\n0,0,300000\n")), "run1.csv", rule=("1 data row", "at least 2")
    )
    assert_error_names(
        _at(_err(tmp_path, "t,i_c,p1\n")), "run1.csv", rule=("0 data rows", "at least 2")
    )


def test_error_blank_first_line(tmp_path):
    e = _at(_err(tmp_path, "\n" + "\n".join(_good_csv())), 1)
    assert_error_names(e, "first line", rule=("empty line", "header"))


def test_quoted_cells_take_the_careful_path_and_read_the_same(tmp_path):
    plain = _read_quiet(_write_raw(tmp_path, "\n".join(_good_csv()), name="plain"))
    rows = _good_csv()
    rows[0] = '"t","i_c","p1"'
    rows[4] = ",".join(f'"{c}"' for c in rows[4].split(","))
    quoted = _read_quiet(_write_raw(tmp_path, "\n".join(rows), name="quoted"))
    np.testing.assert_array_equal(plain.t, quoted.t)
    for k in plain.channels:
        np.testing.assert_array_equal(plain.channels[k], quoted.channels[k])


def test_error_empty_file(tmp_path):
    assert_error_names(_at(_err(tmp_path, "")), "run1.csv", rule="empty file")


def test_error_missing_files(tmp_path):
    with pytest.raises(RecordingError) as info:
        read_recording(tmp_path / "nothere")
    assert_error_names(info, "nothere.csv", rule="not found")
    (tmp_path / "run1.csv").write_text("\n".join(_good_csv()))
    with pytest.raises(RecordingError) as info:
        read_recording(tmp_path / "run1.csv")
    assert_error_names(info, "run1.json", rule=("sidecar", "not found"))


# --------------------------------------------------------------------------- sidecar errors


def _rig(**changes):
    rig = dict({"format": "pneumatic-measurement", "version": 1}, **RIG)
    for k, v in changes.items():
        if v is None:
            rig.pop(k, None)
        else:
            rig[k] = v
    return rig


PISTON_MODES = ('"fixed"', '"free"', '"spring"')


@pytest.mark.parametrize(
    "changes,key,value,rule",
    [
        (dict(format=None), "format", NO_VALUE, ("missing", '"pneumatic-measurement"')),
        (dict(format="pneumatic"), "format", "pneumatic", '"pneumatic-measurement"'),
        (dict(version=2), "version", 2, "must be 1"),
        (dict(version="1"), "version", "1", "must be 1"),
        (dict(version=True), "version", True, "must be 1"),
        (dict(cylinder=None), "cylinder", NO_VALUE, ("missing", '"numatics-0750D02-03A"')),
        (
            dict(cylinder="festo-DSNU"),
            "cylinder",
            "festo-DSNU",
            ('"numatics-0750D02-03A"', '"airpel-E16D3.0N"', '"numatics"', '"airpel"'),
        ),
        (dict(tube_length_m=None), "tube_length_m", NO_VALUE, ("missing", "positive number", "m")),
        (dict(tube_length_m=-0.5), "tube_length_m", -0.5, "positive number"),
        (dict(tube_length_m=0), "tube_length_m", 0, "positive number"),
        (dict(tube_length_m="0.5"), "tube_length_m", "0.5", "positive number"),
        (dict(supply_pressure_pa=-1.0), "supply_pressure_pa", -1.0, "positive number"),
        (dict(temperature_k=0), "temperature_k", 0, "positive number"),
        (dict(tube_inner_diameter_m="4mm"), "tube_inner_diameter_m", "4mm", "positive number"),
        (dict(piston=None), "piston", NO_VALUE, "missing"),
        (dict(piston="fixed"), "piston", NO_VALUE, "object"),
        (dict(piston={"position_m": 0.0}), "piston.mode", NO_VALUE, ("missing", *PISTON_MODES)),
        (dict(piston={"mode": "clamped"}), "piston.mode", "clamped", PISTON_MODES),
        (
            dict(piston={"mode": "fixed"}),
            "piston.position_m",
            NO_VALUE,
            ("missing", "'fixed'", "position_m"),
        ),
        (
            dict(piston={"mode": "free", "load_mass_kg": 1.0}),
            "piston.load_force_n",
            NO_VALUE,
            ("missing", "'free'", "load_mass_kg, load_force_n"),
        ),
        (
            dict(piston={"mode": "spring", "stiffness_n_per_m": 1e3, "load_mass_kg": 1.0}),
            "piston.rest_position_m",
            NO_VALUE,
            ("missing", "'spring'", "stiffness_n_per_m, rest_position_m, load_mass_kg"),
        ),
        (
            dict(piston={"mode": "free", "load_mass_kg": "heavy", "load_force_n": 0}),
            "piston.load_mass_kg",
            "heavy",
            "finite number",
        ),
        (
            dict(piston={"mode": "free", "load_mass_kg": -1, "load_force_n": 0}),
            "piston.load_mass_kg",
            -1,
            "non-negative number",
        ),
        (dict(initial={"p3": 1e5}), "initial.p3", NO_VALUE, "p1, p2, x, v, x_s"),
        (dict(initial={"p1": "ambient"}), "initial.p1", "ambient", "finite number"),
        (dict(initial=[1, 2]), "initial", NO_VALUE, "object"),
        (dict(notes=3), "notes", 3, "string"),
    ],
)
def test_sidecar_errors(tmp_path, changes, key, value, rule):
    path = _write_json(tmp_path, _rig(**changes))
    with pytest.raises(RecordingError) as info:
        _read_quiet(path)
    assert info.value.file == "run1.json"
    assert_error_names(info, ("run1.json", f"'{key}'"), value, rule)


def test_sidecar_error_wording(tmp_path):
    """A guard of the wording: the whole sentence of one sidecar error."""
    with pytest.raises(
        RecordingError,
        match=r"^run1\.json: key 'cylinder' is 'festo-DSNU', "
        r"allowed: \"numatics-0750D02-03A\", \"airpel-E16D3\.0N\" \(or the "
        r"aliases \"numatics\", \"airpel\"\)$",
    ):
        _read_quiet(_write_json(tmp_path, _rig(cylinder="festo-DSNU")))


@pytest.mark.parametrize(
    "text,where,rule",
    [
        (
            json.dumps(_rig(), indent=2).replace('"tube_length_m": 0.5', '"tube_length_m": NaN'),
            "run1.json",
            ("NaN", "finite"),
        ),
        (
            json.dumps(_rig(), indent=2).replace('"tube_length_m": 0.5,', '"tube_length_m": 0.5'),
            ("run1.json", "line 6", "column 3"),
            ("invalid JSON", "',' delimiter"),
        ),
        (
            '{"format": "pneumatic-measurement", "format": "x"}',
            ("run1.json", "'format'"),
            "duplicate key",
        ),
        ("[]", "run1.json", ("JSON object", "list")),
    ],
)
def test_sidecar_nan_and_bad_json(tmp_path, text, where, rule):
    with pytest.raises(RecordingError) as info:
        _read_quiet(_write_json(tmp_path, text))
    assert_error_names(info, where, rule=rule)


@pytest.mark.parametrize(
    "name", ["numatics", "NUMATICS", "Airpel", "airpel-e16d3.0n", "numatics-0750D02-03A"]
)
def test_cylinder_aliases(tmp_path, name):
    rec = _read_quiet(_write_json(tmp_path, _rig(cylinder=name)))
    assert rec.rig["cylinder"] == name  # kept as the file says


def test_unknown_top_level_and_piston_keys_warn(tmp_path):
    rig = _rig(
        operator="bob",
        piston={"mode": "fixed", "position_m": 0.0, "load_mass_kg": 2.0, "colour": "red"},
    )
    with pytest.warns(RecordingWarning) as record:
        rec = read_recording(_write_json(tmp_path, rig))
    messages = [str(w.message) for w in record]
    assert any(re.match(r"^run1\.json: unknown key 'operator' ignored", m) for m in messages)
    assert "run1.json: key 'piston.load_mass_kg' is not used in mode 'fixed'; ignored" in messages
    assert any(m.startswith("run1.json: unknown key 'piston.colour' ignored") for m in messages)
    assert rec.warnings == messages


# --------------------------------------------------------------------------- warnings


def _warn_messages(tmp_path, t, ch, rig=RIG):
    write_recording(tmp_path / "w", t, ch, rig)
    with pytest.warns(RecordingWarning) as record:
        rec = read_recording(tmp_path / "w")
    messages = [str(w.message) for w in record]
    assert all(w.category is RecordingWarning for w in record)
    assert rec.warnings == messages
    return messages


def test_warning_unknown_column(tmp_path):
    rows = _good_csv()
    rows = [r + (",temp" if k == 0 else ",21.5") for k, r in enumerate(rows)]
    rows = [r + (",P2" if k == 0 else ",oops") for k, r in enumerate(rows)]  # ignored: never parsed
    path = _write_raw(tmp_path, "\n".join(rows))
    with pytest.warns(
        RecordingWarning,
        match=r"^run1\.csv: unknown column 'temp' ignored; "
        r"known columns: t, i_c, p1, p2, x, f, v, x_s, p_s$",
    ):
        with pytest.warns(
            RecordingWarning, match=r"unknown column 'P2' ignored \(did you mean 'p2'\?\)"
        ):
            rec = read_recording(path)
    assert set(rec.channels) == {"i_c", "p1"}


def test_warning_gauge_pressure(tmp_path):
    t, ch = _signals()
    ch["p1"] = ch["p1"] - 2.5e5  # about 50 kPa +- 100 kPa: negative values
    messages = _warn_messages(tmp_path, t, ch)
    assert len(messages) == 1
    assert re.match(
        r"^w\.csv: p1 looks like gauge pressure: values below ambient "
        r"\(min -[0-9.e+]+ Pa\); the format wants absolute Pa$",
        messages[0],
    )


def test_warning_gauge_pressure_respects_rig_ambient(tmp_path):
    t, ch = _signals()
    ch["p2"] = 4.5e4 + 1e3 * np.sin(t * 50)  # fine at an ambient of 70 kPa, gauge-like at 101 kPa
    low_ambient = dict(RIG, ambient_pressure_pa=7e4)
    assert not [m for m in _read_and_collect(tmp_path, t, ch, low_ambient) if "p2" in m]
    assert any("p2 looks like gauge pressure" in m for m in _read_and_collect(tmp_path, t, ch, RIG))


def _read_and_collect(tmp_path, t, ch, rig):
    write_recording(tmp_path / "g", t, ch, rig, overwrite=True)
    with warnings.catch_warnings(record=True):
        warnings.simplefilter("always")
        return read_recording(tmp_path / "g").warnings


def test_warning_bar(tmp_path):
    t, ch = _signals()
    ch["p1"] = ch["p1"] / 1e5
    ch["p_s"] = np.full_like(t, 6.5) + 0.01 * np.sin(t * 30)
    messages = _warn_messages(tmp_path, t, ch)
    assert any(
        re.match(
            r"^w\.csv: p1 looks like bar \(max [0-9.]+\); the format wants "
            r"absolute Pa$",
            m,
        )
        for m in messages
    )
    assert any(m.startswith("w.csv: p_s looks like bar") for m in messages)
    assert not any("gauge" in m for m in messages)


def test_warning_millimetres(tmp_path):
    t, ch = _signals()
    ch["x"] = 25.0 * np.sin(2 * np.pi * 2 * t)
    messages = _warn_messages(tmp_path, t, ch)
    assert any(
        re.match(
            r"^w\.csv: x looks like millimetres \(max \|x\| [0-9.]+\); the format "
            r"wants metres$",
            m,
        )
        for m in messages
    )


def test_warning_clipped(tmp_path):
    t, ch = _signals(400)
    ch["f"] = np.minimum(ch["f"], 8.0)  # about a quarter of the samples flat at 8 N
    messages = _warn_messages(tmp_path, t, ch)
    assert any(
        re.match(
            r"^w\.csv: f looks clipped: it sits at its maximum 8\.0 for [0-9.]+% of "
            r"the samples \(longest run [0-9]+ samples\)",
            m,
        )
        for m in messages
    )


def test_clipping_needs_runs_and_ignores_leading_rest(tmp_path):
    t, ch = _signals(400)
    f = ch["f"].copy()
    f[::50] = f.max() + 1.0  # isolated maxima: no runs of 5
    ch["f"] = f
    p1 = ch["p1"].copy()
    p1[:100] = p1.min() - 1e3  # the recording starts at rest: not clipping
    ch["p1"] = p1
    write_recording(tmp_path / "c", t, ch, RIG)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert read_recording(tmp_path / "c").warnings == []


def test_warning_constant_channel(tmp_path):
    t, ch = _signals()
    ch["p2"] = np.full_like(t, 101325.0)
    messages = _warn_messages(tmp_path, t, ch)
    assert messages == ["w.csv: p2 is constant (101325.0) over the whole recording"]


def test_constant_x_is_normal_with_a_fixed_piston(tmp_path):
    t, ch = _signals()
    ch["x"] = np.zeros_like(t)
    write_recording(tmp_path / "c", t, ch, RIG)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        read_recording(tmp_path / "c")


# --------------------------------------------------------------------------- writer


def test_writer_refuses_to_overwrite(tmp_path):
    t, ch = _signals(10)
    write_recording(tmp_path / "r", t, ch, RIG)
    before = (tmp_path / "r.csv").read_bytes()
    ch2 = {k: v + 1.0 for k, v in ch.items()}
    with pytest.raises(FileExistsError) as info:
        write_recording(tmp_path / "r", t, ch2, RIG)
    assert_error_names(info, "r.csv", rule=("exists", "overwrite=True"))
    assert (tmp_path / "r.csv").read_bytes() == before
    (tmp_path / "r.csv").unlink()  # the sidecar alone also blocks
    with pytest.raises(FileExistsError) as info:
        write_recording(tmp_path / "r", t, ch2, RIG)
    assert_error_names(info, "r.json", rule="exists")
    write_recording(tmp_path / "r", t, ch2, RIG, overwrite=True)
    np.testing.assert_array_equal(_read_quiet(tmp_path / "r").channels["p1"], ch2["p1"])


@pytest.mark.parametrize(
    "mutate,field,rule",
    [
        (lambda t, ch: ch["p1"].__setitem__(3, np.nan), ("'p1'", "sample 3", "nan"), "not allowed"),
        (lambda t, ch: ch.pop("i_c"), "'i_c'", "missing required channel"),
        (lambda t, ch: [ch.pop(k) for k in ("p1", "p2", "f")], "channels", "at least one"),
        (lambda t, ch: ch.__setitem__("temp", ch["p1"]), "'temp'", "unknown channel"),
        (lambda t, ch: ch.__setitem__("p2", ch["p2"][:-1]), "'p2'", ("(9,)", "(10,)")),
        (lambda t, ch: t.__setitem__(5, t[5] + 1e-7), ("'t'", "sample 5"), "non-uniform sampling"),
        (lambda t, ch: t.__setitem__(5, t[4]), ("'t'", "sample 5"), "is not after"),
    ],
)
def test_writer_validates(tmp_path, mutate, field, rule):
    t, ch = _signals(10)
    mutate(t, ch)
    with pytest.raises(RecordingError) as info:
        write_recording(tmp_path / "w", t, ch, RIG)
    assert_error_names(info, ("w.csv", *([field] if isinstance(field, str) else field)), rule=rule)
    assert list(tmp_path.iterdir()) == []


def test_writer_validates_rig(tmp_path):
    t, ch = _signals(10)
    with pytest.raises(RecordingError) as info:
        write_recording(tmp_path / "w", t, ch, dict(RIG, piston={"mode": "loose"}))
    assert_error_names(info, ("w.json", "'piston.mode'"), "loose", PISTON_MODES)
    with pytest.raises(RecordingError) as info:
        write_recording(tmp_path / "w", t, ch, dict(RIG, version=2))
    assert_error_names(info, ("w.json", "'version'"), 2, "must be 1")
    with pytest.raises(RecordingError) as info:
        write_recording(tmp_path / "w", t[:1], {k: v[:1] for k, v in ch.items()}, RIG)
    assert_error_names(info, "w.csv", rule=("1 samples", "at least 2"))
    assert list(tmp_path.iterdir()) == []


def test_writer_accepts_numpy_scalars_in_rig(tmp_path):
    t, ch = _signals(10)
    rig = dict(
        RIG, tube_length_m=np.float64(1.5), piston={"mode": "fixed", "position_m": np.float32(0.0)}
    )
    write_recording(tmp_path / "w", t, ch, rig)
    assert _read_quiet(tmp_path / "w").rig["tube_length_m"] == 1.5


# --------------------------------------------------------------------------- physics mapping


def test_rig_to_parameter_overrides_fixed():
    assert rig_to_parameter_overrides(RIG) == {
        "cylinder": "numatics-0750D02-03A",
        "tube_length_m": 0.5,
        "supply_pressure_pa": 650000.0,
        "ambient_pressure_pa": 101325.0,
        "temperature_k": 293.15,
        "piston_mode": 0,
        "fixed_position_m": 0.0,
    }


def test_rig_to_parameter_overrides_free():
    rig = {
        "format": "pneumatic-measurement",
        "version": 1,
        "cylinder": "airpel",
        "tube_length_m": 2.0,
        "tube_inner_diameter_m": 0.004,
        "piston": {"mode": "free", "load_mass_kg": 1.5, "load_force_n": 5.0},
    }
    assert rig_to_parameter_overrides(rig) == {
        "cylinder": "airpel-E16D3.0N",
        "tube_length_m": 2.0,
        "tube_inner_diameter_m": 0.004,
        "piston_mode": 1,
        "load_mass_kg": 1.5,
        "load_force_n": 5.0,
    }


def test_rig_to_parameter_overrides_spring():
    rig = {
        "format": "pneumatic-measurement",
        "version": 1,
        "cylinder": "Numatics",
        "tube_length_m": 1,
        "piston": {
            "mode": "spring",
            "stiffness_n_per_m": 2000,
            "rest_position_m": -0.01,
            "load_mass_kg": 0.2,
        },
        "initial": {"p1": 2e5},
    }
    assert rig_to_parameter_overrides(rig) == {
        "cylinder": "numatics-0750D02-03A",
        "tube_length_m": 1.0,
        "piston_mode": 2,
        "spring_stiffness_n_per_m": 2000.0,
        "spring_rest_position_m": -0.01,
        "load_mass_kg": 0.2,
    }


def test_rig_to_parameter_overrides_rejects_invalid_rig():
    with pytest.raises(RecordingError) as info:
        rig_to_parameter_overrides(
            dict(RIG, format="pneumatic-measurement", version=1, cylinder="festo")
        )
    assert_error_names(info, ("rig", "'cylinder'"), "festo", '"numatics-0750D02-03A"')
