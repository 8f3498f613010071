"""`pneumatic-env speed --quick` runs end to end (no timing assertions)."""

from __future__ import annotations

import platform

import pytest

from conftest import assert_error_names
from pneumatic_env import cli


def test_quick_speed_run_prints_every_table(tmp_path, capsys):
    out = tmp_path / "speed.md"
    assert cli.main(["speed", "--quick", "--max-n", "2", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    for header in (
        "| ratio | value | target | met |",
        "| env | steps/s (median) |",
        "| N | threads | what | env-steps/s | between autoresets | autoreset (ms) | "
        "env-substeps/s | wall ns per RHS |",
        "| N | Sync env-steps/s |",
        "| operation | ns each | per substep and env | ns per substep |",
    ):
        assert header in printed, header
    for row in (
        "| single env / Pendulum |",
        "| vector env / SyncVectorEnv, N=2, 1 thread |",
        "| kernel measured / ceiling, N=2, 1 thread |",
    ):
        assert row in printed, row
    assert "pneumatic-env speed --quick --max-n 2" in printed
    # the env's jitted task kernel runs the same physics as BatchSimulator, bit for bit
    assert "The env's step reproduced `BatchSimulator.step` bit for bit at every N" in printed
    assert out.read_text(encoding="utf-8") == printed.rstrip("\n") + "\n"


@pytest.mark.parametrize(
    "flag, value", [("--max-n", "0"), ("--repeats", "-1"), ("--max-n", "many")]
)
def test_bad_counts_are_rejected_with_the_option_name(flag, value, capsys):
    with pytest.raises(SystemExit):
        cli.main(["speed", flag, value])
    assert_error_names(capsys.readouterr().err, flag, value, "integer >= 1")


@pytest.mark.skipif(
    platform.machine().lower() not in ("x86_64", "amd64"),
    reason="reads x86-64 assembly (SIMD registers %xmm/%ymm/%zmm, AT&T syntax); "
    f"this machine is {platform.machine()}",
)
def test_batch_loop_compiles_to_simd_code():
    """The ceiling counts the instructions of the compiled vectorised loops: every one must
    be vectorised, the RK4 loop with the divisions and square roots of the flow, tube and
    orifice sub-models."""
    from pneumatic_env.studies.speed.ceiling import vector_loop_instructions

    found = vector_loop_instructions()
    assert found["vectorised"] and found["lanes"] >= 2  # every loop of VECTOR_LOOPS
    rk4 = found["loops"]["base_substeps_vectorised"]
    assert rk4["vdiv"] > 0 and rk4["vsqrt"] > 0
    # only the loop body counts, per vector of lanes: the delayed spool read's body loads
    # two vectors and the start's, subtracts, multiplies and adds, selects and stores one;
    # the whole function (prologue, remainder loop, wrapper) counts several times that
    interpolate = found["loops"]["interpolate_row"]
    assert 5 <= interpolate["vother"] <= 20 and interpolate["vdiv"] == interpolate["vsqrt"] == 0
