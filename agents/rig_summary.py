"""The figures of controllers on a fitted rig (``agents.rig``) and ``train --rig``'s
``summary.md`` (``agents.rig_training``)."""

from __future__ import annotations

import numpy as np

from .bench import run_suite
from .bench_results import markdown_table
from .rig import FittedRig
from .rig_shipped import SHIPPED_SUFFIX
from .suite import Suite, load_suite

__all__ = ["suite_summary", "summary_markdown"]


def suite_summary(rig: FittedRig, controllers: list, suite: Suite | None = None) -> list[dict]:
    """Mean RMS error (%), chatter (A) and air (mg) over the suite's tasks on the fitted
    rig, per controller (a name, file or ``ControllerSpec``)."""
    suite = suite or load_suite()
    out = []
    for c in controllers:
        rows, _ = run_suite(c, [rig.variant], suite, env_options=rig.env_options)
        out.append(
            {
                "controller": rows[0]["controller"],
                **{k: float(np.mean([r[k] for r in rows])) for k in _FIGURES},
            }
        )
    return out


_FIGURES = ("rms_error_pct", "chatter_rms_a", "air_mg")


def summary_markdown(rig: FittedRig, figures: list[dict], base: dict, command: str) -> str:
    """``summary.md``: the figures of each controller on the fitted rig (the first the
    new controller, then the classical ones and the shipped learned ones, named
    ``<name> (shipped)``; "x best classical" against the best classical one) and the base
    it sits on (``choose_base``)."""
    best_classical = min(
        f["rms_error_pct"] for f in figures[1:] if not f["controller"].endswith(SHIPPED_SUFFIX)
    )
    rows = [
        [
            f["controller"],
            f"{f['rms_error_pct']:.2f}",
            f"{f['rms_error_pct'] / best_classical:.2f}",
            f"{f['chatter_rms_a']:.4f}",
            f"{f['air_mg']:.1f}",
        ]
        for f in figures
    ]
    header = ["controller", "mean RMS error (%)", "x best classical", "chatter (A)", "air (mg)"]
    return "\n".join(
        [
            f"# Controller for the rig of {rig.report_dir}",
            "",
            f"The fitted rig: {rig.cylinder}, tube {rig.params['tube_length_m']:g} m, "
            f"supply {rig.params.get('supply_pressure_pa', float('nan')):.0f} Pa "
            f"(env {rig.env_id} with the report's fitted_final.yaml). Benchmark suite "
            "means over its tasks (docs/benchmark.md).",
            "",
            markdown_table(header, rows),
            "",
            f"The residual's base: {base['controller']} ({base['reason']}).",
            ""
            if not base.get("residual_zeroed")
            else f"The residual was zeroed: {base['residual_zeroed']['reason']}.",
            "" if not base.get("shipped") else f"{base['shipped']['reason']}.",
            "",
            f"Command: `{command}`" if command else "",
            "",
        ]
    )
