"""`pneumatic-env speed --quick` runs end to end (no timing assertions)."""
from __future__ import annotations

import pytest

from pneumatic_env import cli


def test_quick_speed_run_prints_every_table(tmp_path, capsys):
    out = tmp_path / "speed.md"
    assert cli.main(["speed", "--quick", "--max-n", "2", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    for header in ("| ratio | value | target | met |",
                   "| env | steps/s (median) |",
                   "| N | threads | what | env-steps/s | env-substeps/s | wall ns per RHS |",
                   "| N | Sync env-steps/s |",
                   "| operation | ns each | per substep | ns per substep |"):
        assert header in printed, header
    for row in ("| single env / Pendulum |", "| vector env / SyncVectorEnv, N=2, 1 thread |",
                "| kernel measured / ceiling, N=2, 1 thread |"):
        assert row in printed, row
    assert "pneumatic-env speed --quick --max-n 2" in printed
    assert out.read_text(encoding="utf-8") == printed.rstrip("\n") + "\n"


@pytest.mark.parametrize("flag, value", [("--max-n", "0"), ("--repeats", "-1"),
                                          ("--max-n", "many")])
def test_bad_counts_are_rejected_with_the_option_name(flag, value, capsys):
    with pytest.raises(SystemExit):
        cli.main(["speed", flag, value])
    err = capsys.readouterr().err
    assert f"{flag} = '{value}' is not allowed: must be an integer >= 1" in err
