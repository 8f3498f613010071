"""``pneumatic-env paper --out DIR``: the experiments of :mod:`pneumatic_env.studies.paper`,
their figures (:mod:`pneumatic_env.studies.paper_figures`, the ``plots`` extra) and
``table.md`` / ``table.json`` with the quantities the paper states facts about."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from pneumatic_env.params import DEFAULT_CYLINDER, load_parameters
from pneumatic_env.text_format import jsonable

from .paper import (
    FINAL_FRACTION,
    OSCILLATION_WINDOW_S,
    RISE_FRACTION,
    SINE_AMPLITUDE_A,
    SINE_DURATION_S,
    SINE_FREQUENCY_HZ,
    STEP_CURRENT_A,
    STEP_DURATION_S,
    TUBE_DURATION_S,
    TUBE_FLOW_AMPLITUDE_KG_S,
    TUBE_MEAN_PRESSURE_PA,
    clamped_step_runs,
    free_sine_runs,
    step_metrics,
    tube_response,
    valve_numbers,
)
from .paper_figures import write_figures

__all__ = ["reproduce", "add_arguments", "run"]


# --------------------------------------------------------------------------- table


def _table_rows(table: dict) -> list[tuple[str, str, str, str]]:
    """(quantity, value, unit, paper / expected) rows of table.md."""
    v, s, t = table["valve"], table["step"], table["tube"]
    cmd, lit = s["command"], s["literal"]
    rows = [
        (
            "steady spool displacement at 0.5 A (Eq. 46)",
            f"{1e3 * v['spool_displacement_at_step_m']:.4f}",
            "mm",
            "K_fc 0.5 / (2 k_s)",
        ),
        (
            "simulated spool position at the end of the 0.5 A step",
            f"{1e3 * cmd['spool_position_at_end_m']:.4f}",
            "mm",
            "same",
        ),
        ("current that opens the valve fully", f"{v['full_open_current_a']:.3f}", "A", ""),
        (
            "full-open area per path (Eq. 44)",
            f"{1e6 * v['full_open_area_m2']:.3f}",
            "mm^2",
            "pi n_h R_h^2",
        ),
        (
            "choked flow, fully open, supply -> ambient (Eq. 39)",
            f"{1e3 * v['choked_flow_full_open_kg_s']:.3f}",
            "g/s",
            "",
        ),
    ]
    for name, m in (("command", cmd), ("literal", lit)):
        rise = m["first_rise_s"]
        final = m["time_to_final_force_s"]
        rows += [
            (
                f"[{name}] first p1 rise, 0.5 m / 2 m tube",
                f"{1e3 * rise['0.5']:.2f} / {1e3 * rise['2.0']:.2f}",
                "ms",
                "",
            ),
            (
                f"[{name}] extra delay of the 2 m tube",
                f"{1e3 * m['extra_delay_s']:.2f}",
                "ms",
                f"1.5 m / c = {1e3 * m['expected_extra_delay_s']:.2f} ms (paper: about 5 ms)",
            ),
            (
                f"[{name}] time to {100 * FINAL_FRACTION:g}% of the final force, 0.5 m / 2 m",
                f"{1e3 * final['0.5']:.1f} / {1e3 * final['2.0']:.1f}",
                "ms",
                "",
            ),
            (
                f"[{name}] ratio 2 m / 0.5 m of that time",
                f"{m['final_force_time_ratio']:.2f}",
                "-",
                "more than 2",
            ),
            (
                f"[{name}] p1 half peak-to-peak over the last {1e3 * OSCILLATION_WINDOW_S:g} ms, "
                "0.5 m / 2 m",
                f"{1e-3 * m['p1_oscillation_amplitude_pa']['0.5']:.2f} / "
                f"{1e-3 * m['p1_oscillation_amplitude_pa']['2.0']:.2f}",
                "kPa",
                "0 (command); oscillation near supply (literal)",
            ),
        ]
    rows += [
        ("tube 3 m: delay L / c", f"{1e3 * t['delay_s']:.2f}", "ms", ""),
        (
            f"tube 3 m: phi at {1e3 * TUBE_FLOW_AMPLITUDE_KG_S:g} g/s (turbulent) / laminar, "
            f"P = {1e-5 * t['mean_pressure_pa']:g} bar",
            f"{t['phi_at_peak_flow']:.3f} / {t['phi_laminar']:.3f}",
            "-",
            "",
        ),
        (
            "tube 3 m: outlet / inlet amplitude, Eq. 31 / Eqs. 19-20",
            f"{t['amplitude_ratio_eq31']:.3f} / {t['amplitude_ratio_wave']:.3f}",
            "-",
            "attenuated",
        ),
    ]
    return rows


def reproduce(out_dir: str | Path, quick: bool = False, figures: bool = True) -> dict:
    """Run (a)-(d), write the PNGs and ``table.md`` / ``table.json`` to ``out_dir``.

    ``quick`` shortens the runs (0.15 s step, 0.3 s sine, 0.06 s tube) for tests.
    Returns the table (also in ``table.json``) with the list of files written.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    params = load_parameters(DEFAULT_CYLINDER)
    step_runs = clamped_step_runs(0.15 if quick else STEP_DURATION_S)
    sine_runs = free_sine_runs(0.3 if quick else SINE_DURATION_S)
    tube = tube_response(params, duration_s=0.06 if quick else TUBE_DURATION_S)
    table = {
        "valve": valve_numbers(params),
        "step": step_metrics(step_runs),
        "tube": {k: v for k, v in tube.items() if not isinstance(v, np.ndarray)},
        "sine": {
            c: {"x_min_m": float(r["x"].min()), "x_max_m": float(r["x"].max())}
            for c, r in sine_runs.items()
        },
        "settings": {
            "step_current_a": STEP_CURRENT_A,
            "sine_amplitude_a": SINE_AMPLITUDE_A,
            "sine_frequency_hz": SINE_FREQUENCY_HZ,
            "rise_fraction": RISE_FRACTION,
            "final_fraction": FINAL_FRACTION,
            "tube_mean_pressure_pa": TUBE_MEAN_PRESSURE_PA,
            "quick": quick,
        },
    }
    files = []
    if figures:
        files += write_figures(params, step_runs, sine_runs, tube, out)
    (out / "table.json").write_text(json.dumps(jsonable(table), indent=2) + "\n")
    lines = ["| quantity | value | unit | paper / expected |", "|---|---|---|---|"]
    lines += [f"| {a} | {b} | {c} | {d} |" for a, b, c, d in _table_rows(table)]
    (out / "table.md").write_text("\n".join(lines) + "\n")
    files += [out / "table.json", out / "table.md"]
    table["files"] = [str(f) for f in files]
    return table


# --------------------------------------------------------------------------- CLI


def add_arguments(p) -> None:
    p.add_argument(
        "--out",
        metavar="DIR",
        required=True,
        help="directory for the PNG figures and table.md / table.json",
    )
    p.add_argument(
        "--quick",
        action="store_true",
        help="shorter runs (for tests); the table's numbers stay meaningful",
    )


def run(args) -> int:
    table = reproduce(args.out, quick=args.quick)
    cmd = table["step"]["command"]
    print(
        f"wrote {len(table['files'])} files to {args.out}: extra delay 2 m vs 0.5 m "
        f"{1e3 * cmd['extra_delay_s']:.2f} ms (1.5/c = {1e3 * cmd['expected_extra_delay_s']:.2f}"
        f" ms), time-to-final-force ratio {cmd['final_force_time_ratio']:.2f}"
    )
    return 0
