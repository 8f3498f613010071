"""Tests of the benchmark: suite loading, runner, metrics, bandwidth estimate, output, CLI."""

from __future__ import annotations

import csv
import math

import gymnasium as gym
import numpy as np
import pytest
import yaml
from scipy import signal

from conftest import PID_TEST_GAINS
from pneumatic_env.agents.base import ControllerContext
from pneumatic_env.agents.bench import (
    CSV_COLUMNS,
    bandwidth,
    closed_loop,
    error_bandwidth,
    frequency_response,
    leaderboard,
    load_suite,
    make_env,
    parse_variant,
    read_results,
    run_suite,
    write_results,
)
from pneumatic_env.agents.pid import PIDController
from pneumatic_env.cli import main as cli_main
from pneumatic_env.params import ConfigError
from pneumatic_env.references import make_reference

DT = 1e-3


def _chirp(duration=4.0, f0=0.5, f1=30.0):
    n = int(duration / DT)
    return make_reference(
        {"kind": "chirp", "amplitude": 1.0, "f0_hz": f0, "f1_hz": f1, "duration_s": duration}
    ).generate(n, DT)


# --------------------------------------------------------------------------- bandwidth


@pytest.mark.parametrize("fc", [3.0, 8.0, 15.0])
def test_bandwidth_of_a_first_order_low_pass(fc):
    """The chirp estimate finds the -3 dB corner of 1 / (s / wc + 1) within 10 %."""
    r = _chirp()
    b, a = signal.bilinear([1.0], [1.0 / (2 * np.pi * fc), 1.0], fs=1 / DT)
    y = signal.lfilter(b, a, r)
    f, H = frequency_response(r, y, DT, 0.5, 30.0, 6)
    bw, lower = bandwidth(f, H)
    assert not lower
    assert bw == pytest.approx(fc, rel=0.10)
    # for 1 / (s / wc + 1) the error |1 - H| = (w / wc) / sqrt(1 + (w / wc)^2) also crosses
    # -3 dB at wc
    ebw, lower = error_bandwidth(f, H)
    assert not lower and ebw == pytest.approx(fc, rel=0.10)


def test_bandwidth_ignores_a_pure_delay_and_flags_a_lower_bound():
    r = _chirp()
    y = np.concatenate([np.zeros(5), r[:-5]])  # 5 ms delay: |H| = 1, phase only
    f, H = frequency_response(r, y, DT, 0.5, 30.0, 6)
    bw, lower = bandwidth(f, H)
    assert lower and bw == pytest.approx(f[-1])
    assert np.all(np.abs(np.abs(H) - 1) < 0.1)
    # but the error does grow: |1 - exp(-j w D)| = 2 sin(pi f D) = 0.7071 at f = 23.0 Hz
    ebw, lower = error_bandwidth(f, H)
    f_expected = math.asin(0.5 / math.sqrt(2)) / (math.pi * 0.005)
    assert not lower and ebw == pytest.approx(f_expected, rel=0.08)


# --------------------------------------------------------------------------- suite


def test_shipped_suite_is_valid():
    suite = load_suite()
    assert suite.version == "v1"
    assert set(suite.variants) == {"Numatics-0.5m", "Numatics-2m", "Airpel-0.5m", "Airpel-2m"}
    names = [t.name for t in suite.tasks]
    for needed in (
        "step_up",
        "step_down",
        "sine_1hz",
        "sine_5hz",
        "sine_10hz",
        "sine_20hz",
        "chirp",
        "multisine",
        "random_step",
    ):
        assert needed in names
    assert max(t.duration_s for t in suite.tasks) <= 2.0


def _write_suite(tmp_path, **over):
    data = {
        "version": "test",
        "task": "ForceTrack",
        "variants": ["Numatics-0.5m"],
        "env": {"preview_steps": 20},
        "metrics": {
            "bandwidth_task": "chirp",
            "bandwidth_bins_per_octave": 3,
            "bandwidth_level": 0.7071,
        },
        "plots": {"sine_task": "sine", "chirp_task": "chirp"},
        "tasks": [
            {
                "name": "step",
                "seed": 1,
                "duration_s": 0.3,
                "reference": {"kind": "step", "amplitude": 0.4, "step_time_s": 0.05},
            },
            {
                "name": "sine",
                "seed": 2,
                "duration_s": 0.2,
                "reference": {"kind": "sine", "amplitude": 0.3, "frequency_hz": 10.0},
            },
            {
                "name": "chirp",
                "seed": 3,
                "duration_s": 0.4,
                "reference": {
                    "kind": "chirp",
                    "amplitude": 0.3,
                    "f0_hz": 2.0,
                    "f1_hz": 30.0,
                    "duration_s": 0.4,
                },
            },
            {
                "name": "rs",
                "seed": 4,
                "duration_s": 0.3,
                "reference": {
                    "kind": "random_step",
                    "amplitude": 0.5,
                    "hold_min_s": 0.05,
                    "hold_max_s": 0.1,
                },
            },
        ],
    }
    data.update(over)
    path = tmp_path / "suite.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_suite_errors_name_the_field(tmp_path):
    with pytest.raises(ConfigError, match=r"metrics.bandwidth_task = 'nope' is not a task"):
        load_suite(
            _write_suite(
                tmp_path,
                metrics={
                    "bandwidth_task": "nope",
                    "bandwidth_bins_per_octave": 3,
                    "bandwidth_level": 0.7,
                },
            )
        )
    with pytest.raises(ValueError, match=r"variant = 'Numatics-7m' is not allowed"):
        load_suite(_write_suite(tmp_path, variants=["Numatics-7m"]))
    with pytest.raises(ConfigError, match=r"tasks\[0\].reference: .*amplitude"):
        load_suite(
            _write_suite(
                tmp_path,
                tasks=[{"name": "x", "seed": 1, "duration_s": 1.0, "reference": {"kind": "step"}}],
            )
        )


def test_parse_variant():
    assert parse_variant("Airpel-2m") == "pneumatic_env/ForceTrack-Airpel-2m-v0"
    assert parse_variant("Numatics-0.5m", "PositionTrack") == (
        "pneumatic_env/PositionTrack-Numatics-0.5m-v0"
    )
    with pytest.raises(ValueError, match="use one of"):
        parse_variant("airpel-2m")


def test_default_preview_is_the_suite_s_not_the_env_s():
    """Two facts: the benchmark's preview (configs/benchmark.yaml) and the env's default."""
    from pneumatic_env.agents.bench import resolve_controller
    from pneumatic_env.ids import ENV_PREVIEW_STEPS

    suite = load_suite()
    zero = resolve_controller("zero", "Numatics-2m")
    assert zero.env_options["preview_steps"] == suite.preview_steps == 20
    env = gym.make(parse_variant("Numatics-2m"))
    assert env.unwrapped.preview_steps == ENV_PREVIEW_STEPS == 10
    assert (
        resolve_controller("zero", "Numatics-2m", preview_steps=3).env_options["preview_steps"] == 3
    )


# --------------------------------------------------------------------------- runner


def test_vector_runner_reproduces_the_single_env():
    """Env i of the bench's vector env = the single env with that reference and seed."""
    refs = [
        {"kind": "multisine", "amplitude": 0.4, "frequencies_hz": [2.0, 7.0]},
        {"kind": "random_step", "amplitude": 0.5, "hold_min_s": 0.05, "hold_max_s": 0.1},
    ]
    seeds, n = [17, 18], 150
    gains = dict(PID_TEST_GAINS)
    venv = make_env("Airpel-0.5m", 2, n, preview_steps=20)
    tr = closed_loop(venv, PIDController(ControllerContext.from_env(venv), **gains), refs, seeds, n)
    scale = venv.unwrapped.reference_scale
    for i in range(2):
        si = dict(refs[i], amplitude=refs[i]["amplitude"] * scale)
        env = gym.make(
            "pneumatic_env/ForceTrack-Airpel-0.5m-v0",
            max_episode_steps=n,
            preview_steps=20,
            reference=si,
        )
        ctrl = PIDController(ControllerContext.from_env(env), **gains)
        obs, _ = env.reset(seed=seeds[i])
        force = []
        for _ in range(n):
            obs, _, _, _, info = env.step(ctrl.act(obs))
            force.append(info["reference"] + info["tracking_error"])
        np.testing.assert_allclose(tr["force_n"][:, i], force, rtol=0, atol=1e-9)


@pytest.fixture(scope="module")
def zero_and_pid_results(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("bench")
    suite = load_suite(_write_suite(tmp))
    out = {}
    for name in ("zero", "pid"):
        rows, traces = run_suite(name, suite=suite)
        write_results(tmp / name, rows, traces, suite, command=f"test {name}")
        out[name] = (rows, traces)
    return tmp, suite, out


def test_zero_controller_metrics_are_those_of_the_reference(zero_and_pid_results):
    """With the valve closed the force stays 0: RMS error = RMS of the reference, no air."""
    tmp, suite, out = zero_and_pid_results
    rows, traces = out["zero"]
    scale = traces["Numatics-0.5m"]["scale_n"]
    n_ref = make_env("Numatics-0.5m", 1, 10, preview_steps=20).unwrapped.references.shape[1]
    for task, row in zip(suite.tasks, rows):
        n = int(round(task.duration_s / DT))
        spec = dict(task.reference)
        spec["amplitude"] *= scale
        rng = gym.utils.seeding.np_random(task.seed)[0]
        # sample k of the episode is compared after k steps: samples 1..n
        ref = make_reference(spec).generate(n_ref, DT, rng)[1 : n + 1]
        assert row["rms_error_n"] == pytest.approx(np.sqrt(np.mean(ref**2)), rel=1e-9), task.name
        assert row["peak_error_pct"] == pytest.approx(100 * np.max(np.abs(ref)) / scale)
        assert row["air_mg"] == 0.0 and row["effort_rms_a"] == 0.0
    chirp = [r for r in rows if r["task"] == "chirp"][0]
    assert chirp["bandwidth_hz"] == pytest.approx(2.0 * 2 ** (1 / 6), rel=0.05)  # first band


def test_results_files(zero_and_pid_results):
    tmp, suite, out = zero_and_pid_results
    d = tmp / "pid"
    with open(d / "results.csv", newline="") as fh:
        reader = csv.DictReader(fh)
        assert tuple(reader.fieldnames) == CSV_COLUMNS
        rows = list(reader)
    assert [r["task"] for r in rows] == [t.name for t in suite.tasks]
    for r in rows:
        for col in (
            "rms_error_n",
            "rms_error_pct",
            "peak_error_n",
            "effort_rms_a",
            "chatter_rms_a",
            "air_mg",
        ):
            assert math.isfinite(float(r[col]))
        assert (r["bandwidth_hz"] != "") == (r["task"] == "chirp")
        assert (r["error_bandwidth_hz"] != "") == (r["task"] == "chirp")
    pid_rows = read_results(d)
    assert all(r["air_mg"] > 0 for r in pid_rows)  # a working valve lets air out
    md = (d / "results.md").read_text()
    lines = [ln for ln in md.splitlines() if ln.startswith("|")]
    assert lines[0].startswith("| task | RMS err (N)") and set(lines[1]) <= set("|-")
    assert len(lines) == 2 + len(suite.tasks)
    assert "Command: `test pid`" in md
    for png in ("tracking_sine.png", "tracking_chirp.png", "frequency_response.png"):
        assert (d / png).stat().st_size > 1000


def test_leaderboard_merges_and_sorts(zero_and_pid_results, tmp_path):
    tmp, _, out = zero_and_pid_results
    text = leaderboard([tmp / "zero", tmp / "pid" / "results.csv"])
    rows = [ln for ln in text.splitlines() if ln.startswith("| Numatics")]
    assert len(rows) == 2
    assert rows[0].split("|")[2].strip() == "pid"  # smaller mean RMS error first
    mean_pid = np.mean([r["rms_error_pct"] for r in out["pid"][0]])
    assert f"{mean_pid:.2f}" in rows[0]
    other = tmp_path / "other.csv"
    other.write_text((tmp / "pid" / "results.csv").read_text().replace("\ntest,", "\nv9,"))
    with pytest.raises(ValueError, match="different suite versions"):
        leaderboard([tmp / "zero", other])


def test_cli_bench_and_leaderboard(tmp_path, capsys):
    suite = _write_suite(
        tmp_path,
        tasks=[
            {
                "name": "sine",
                "seed": 2,
                "duration_s": 0.1,
                "reference": {"kind": "sine", "amplitude": 0.3, "frequency_hz": 10.0},
            },
            {
                "name": "chirp",
                "seed": 3,
                "duration_s": 0.1,
                "reference": {
                    "kind": "chirp",
                    "amplitude": 0.3,
                    "f0_hz": 10.0,
                    "f1_hz": 30.0,
                    "duration_s": 0.1,
                },
            },
        ],
    )
    out = tmp_path / "res"
    assert (
        cli_main(
            [
                "bench",
                "--controller",
                "sliding_mode",
                "--suite",
                str(suite),
                "--variants",
                "Numatics-0.5m",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    assert (out / "results.csv").is_file() and (out / "results.md").is_file()
    assert cli_main(["bench", "--leaderboard", str(out)]) == 0
    assert "| Numatics-0.5m | sliding_mode |" in capsys.readouterr().out
    with pytest.raises(ValueError, match="controller = 'nope' is not allowed"):
        cli_main(
            ["bench", "--controller", "nope", "--suite", str(suite), "--out", str(tmp_path / "x")]
        )
