"""studies/learned_plots.py: learning curves read from the trainer's progress files."""

from __future__ import annotations

import numpy as np
import pytest

from pneumatic_env.studies.learned_plots import plot_curves, read_curve

HEADER = "update,wall_s,steps,steps_per_s,val_rms_pct,val_chatter_a\n"


def _run(tmp_path, name, rows):
    d = tmp_path / name
    d.mkdir()
    (d / "progress.csv").write_text(HEADER + "".join(rows), encoding="utf-8")
    return d


def test_only_validation_rows_make_the_curve(tmp_path):
    run = _run(
        tmp_path,
        "a",
        [
            "1,1.0,100,100,,\n",
            "2,2.0,200,100,5.5,0.01\n",
            "3,3.0,300,100,,\n",
            "4,4.0,400,100,4.5,0.01\n",
        ],
    )
    wall, steps, rms = read_curve(run)
    assert wall.tolist() == [2.0, 4.0] and steps.tolist() == [200, 400]
    assert rms.tolist() == [5.5, 4.5]


def test_missing_progress_and_empty_curves_are_named(tmp_path):
    with pytest.raises(FileNotFoundError, match="progress.csv"):
        read_curve(tmp_path)
    run = _run(tmp_path, "b", ["1,1.0,100,100,,\n"])
    with pytest.raises(ValueError, match="val_rms_pct"):
        read_curve(run)


def test_curves_of_several_runs_are_plotted(tmp_path):
    pytest.importorskip("matplotlib")
    runs = [
        _run(
            tmp_path,
            f"s{k}",
            [f"{i},{60.0 * i},{1e6 * i},1,{6 - i + 0.1 * k},0\n" for i in range(1, 5)],
        )
        for k in range(3)
    ]
    out = plot_curves(runs, tmp_path / "curves.png", baseline_pct=4.8)
    assert out.is_file() and out.stat().st_size > 1000
    assert np.isfinite(read_curve(runs[0])[2]).all()
