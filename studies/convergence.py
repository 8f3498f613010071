"""Convergence of the fixed-step kernel: the table that decides the default substeps.

``python -m pneumatic_env.studies.convergence`` runs the paper's scenarios (b) (rod clamped,
0.5 A step, 0.5 m and 2 m tubes, both tube couplings) and (c) (free rod, 5 Hz sine, both
cylinders) from :mod:`pneumatic_env.studies.paper` at 5, 10, 20, 40, 80 (and 320) RK4 substeps
per control period and prints, as Markdown:

1. the largest error of ``p1``, ``p2`` (% of supply - ambient), ``f`` (% of the
   scenario's force range) and ``x`` (% of half the stroke) over the control-period
   samples, against the SciPy reference solution (:mod:`pneumatic_env.studies.reference_solution`,
   an independent adaptive integrator with event location) where it runs, else against
   the kernel at 1280 substeps;
2. the effect of the flow linearisation (``flow_linear_ratio`` 0.999 and 0.9995 against
   the default) at 320 substeps;
3. chatter (sign changes of dp/dt on consecutive substeps near supply or ambient
   pressure) and NaN for every ratio and substep count;
4. the smallest substep count that keeps every error below 0.1 % of full scale.

Each run is made with the control period split into single-substep periods
(``control_dt_s / n``, the current repeated ``n`` times): the arithmetic is the same as
``n`` substeps per period, and dp/dt is visible at every substep.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from pneumatic_env.params import load_numerics
from pneumatic_env.replay import simulate_currents
from pneumatic_env.text_format import number_text

from .paper import (
    COUPLINGS,
    CYLINDERS,
    STEP_TUBES_M,
    Scenario,
    clamped_step_scenario,
    free_sine_scenario,
)

__all__ = ["SUBSTEPS", "scenarios", "fine_run", "errors", "chatter", "study", "markdown", "main"]

SUBSTEPS = (5, 10, 20, 40, 80)
FINE_SUBSTEPS = 320  # shown in the table; also where the flow linearisation is compared
EXTRA_SUBSTEPS = (640,)  # error table only (default flow_linear_ratio)
KERNEL_REFERENCE_SUBSTEPS = 1280  # reference when the SciPy reference is unavailable
LINEAR_RATIOS = (0.995, 0.999, 0.9995)
TOLERANCE_PERCENT = 0.1
CHANNELS = ("p1", "p2", "f", "x")
# Chatter is looked for where a chamber is within this fraction of (supply - ambient) of
# supply or ambient pressure (the flow function's ratio -> 1), counting sign changes of
# dp/dt where |dp/dt| exceeds CHATTER_MIN_RATE_FRACTION_PER_S of that range per second
# (far above round-off, far below any real transient).
NEAR_FRACTION = 0.02
CHATTER_MIN_RATE_FRACTION_PER_S = 1e-3
STEP_DURATION_S = 0.2
QUICK_STEP_DURATION_S = 0.1
QUICK_SINE_DURATION_S = 0.4


def scenarios(quick: bool = False) -> list[Scenario]:
    """(b) for both tubes and couplings, (c) for both cylinders, at the default control period."""
    dt = float(load_numerics()["control_dt_s"])
    step_s = QUICK_STEP_DURATION_S if quick else STEP_DURATION_S
    out = [clamped_step_scenario(L, c, step_s, dt) for c in COUPLINGS for L in STEP_TUBES_M]
    sine = {"duration_s": QUICK_SINE_DURATION_S} if quick else {}
    out += [free_sine_scenario(cyl, control_dt_s=dt, **sine) for cyl in CYLINDERS]
    return out


def fine_run(scenario: Scenario, substeps: int, **overrides) -> tuple[dict, dict]:
    """Run with ``substeps`` per control period, sampled at every substep; (run, params)."""
    params = scenario.parameters(**overrides)
    run = simulate_currents(
        params,
        np.repeat(scenario.coil_current_a, substeps),
        scenario.control_dt_s / substeps,
        substeps=1,
    )
    return run, params


def _scales(params: dict, reference: dict) -> dict:
    f_range = float(np.ptp(reference["f"]))
    return {
        "p1": params["supply_pressure_pa"] - params["ambient_pressure_pa"],
        "p2": params["supply_pressure_pa"] - params["ambient_pressure_pa"],
        "f": f_range if f_range > 0 else 1.0,
        "x": 0.5 * params["stroke_m"],
    }


def errors(run: dict, stride: int, reference: dict, scales: dict) -> dict:
    """Largest |run - reference| over the control-period samples, % of each channel's scale."""
    return {
        k: 100.0 * float(np.abs(run[k][::stride] - reference[k]).max()) / scales[k]
        for k in CHANNELS
    }


def chatter(run: dict, params: dict, substep_s: float) -> dict:
    """Sign changes of dp/dt between consecutive substeps near supply or ambient pressure.

    ``flips``: sign changes (a physical oscillation near supply has some too);
    ``alternating``: flips followed by another on the very next substep (a period-2
    oscillation, the signature of a step too long for the flow's slope: chatter);
    ``nan``: whether any output is not finite.
    """
    supply, ambient = params["supply_pressure_pa"], params["ambient_pressure_pa"]
    span = supply - ambient
    flips = alternating = 0
    for key in ("p1", "p2"):
        y = run[key]
        d = np.diff(y)
        sign = np.sign(d) * (np.abs(d) > CHATTER_MIN_RATE_FRACTION_PER_S * span * substep_s)
        near = (np.abs(y[1:] - supply) < NEAR_FRACTION * span) | (
            np.abs(y[1:] - ambient) < NEAR_FRACTION * span
        )
        flip = (sign[1:] * sign[:-1] < 0) & near[1:]
        flips += int(flip.sum())
        alternating += int((flip[1:] & flip[:-1]).sum())
    nan = not all(np.all(np.isfinite(run[k])) for k in CHANNELS)
    return {"flips": flips, "alternating": alternating, "nan": nan}


def _scipy_reference(scenario: Scenario, params: dict):
    """(reference dict, None) from the SciPy reference solution, or (None, reason)."""
    try:
        from .reference_solution import simulate_reference
    except ImportError as exc:
        return None, f"not available ({exc})"
    try:
        ref = simulate_reference(params, scenario.coil_current_a, scenario.control_dt_s)
    except Exception as exc:  # a failing reference is reported, the study goes on
        return None, f"failed: {type(exc).__name__}: {exc}"
    return {k: np.asarray(ref[k]) for k in CHANNELS}, None


def study(quick: bool = False, use_scipy: bool = True) -> dict:
    """Run everything; returns the numbers that :func:`markdown` prints."""
    results = []
    for s in scenarios(quick):
        params = s.parameters()
        reference, why = _scipy_reference(s, params) if use_scipy else (None, "not used")
        ref_name = "SciPy reference_solution"
        if reference is None:
            run, _ = fine_run(s, KERNEL_REFERENCE_SUBSTEPS)
            reference = {k: run[k][::KERNEL_REFERENCE_SUBSTEPS] for k in CHANNELS}
            ref_name = f"kernel at {KERNEL_REFERENCE_SUBSTEPS} substeps (SciPy reference {why})"
        scales = _scales(params, reference)
        row = {
            "name": s.name,
            "reference": ref_name,
            "scales": scales,
            "errors": {},
            "chatter": {},
            "linearisation": {},
        }
        for n in (*SUBSTEPS, FINE_SUBSTEPS):
            runs = {}
            for ratio in LINEAR_RATIOS:
                runs[ratio], p = fine_run(s, n, flow_linear_ratio=ratio)
                row["chatter"][(n, ratio)] = chatter(runs[ratio], p, s.control_dt_s / n)
            default = runs[LINEAR_RATIOS[0]]
            row["errors"][n] = errors(default, n, reference, scales)
            if n == FINE_SUBSTEPS:
                base = {k: default[k][::n] for k in CHANNELS}
                for ratio in LINEAR_RATIOS[1:]:
                    row["linearisation"][ratio] = errors(runs[ratio], n, base, scales)
        for n in EXTRA_SUBSTEPS:
            run, _ = fine_run(s, n)
            row["errors"][n] = errors(run, n, reference, scales)
        results.append(row)
    return {"rows": results, "quick": quick}


def _worst(err: dict) -> float:
    return max(err.values())


def smallest_substeps(rows: list, tolerance: float = TOLERANCE_PERCENT) -> int | None:
    """Smallest tested substep count whose errors stay below ``tolerance`` % in ``rows``."""
    for n in SUBSTEPS + (FINE_SUBSTEPS,) + EXTRA_SUBSTEPS:
        if all(_worst(r["errors"][n]) < tolerance for r in rows):
            return n
    return None


def _fmt(x: float) -> str:
    return "0" if x == 0 else (number_text(x, 4, fixed=True) if x >= 1e-4 else "<0.0001")


def markdown(result: dict) -> str:
    rows = result["rows"]
    numerics = load_numerics()
    dt_ms = 1e3 * float(numerics["control_dt_s"])
    out = [
        f"Control period {dt_ms:g} ms; substeps per period as listed. Errors are the "
        "largest over the control-period samples, in % of full scale: p1, p2 of "
        "(supply - ambient), f of the scenario's force range, x of half the stroke.",
        "",
    ]
    out += [
        "## Errors against the reference",
        "",
        "| scenario | substeps | substep [us] | p1 % | p2 % | f % | x % | max % |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        for n in SUBSTEPS + (FINE_SUBSTEPS,) + EXTRA_SUBSTEPS:
            e = r["errors"][n]
            out.append(
                f"| {r['name']} | {n} | {1e3 * dt_ms / n:g} | "
                + " | ".join(_fmt(e[k]) for k in CHANNELS)
                + f" | {_fmt(_worst(e))} |"
            )
    out += ["", "Reference of each scenario:", ""]
    out += [f"- {r['name']}: {r['reference']}" for r in rows]
    out += [""]

    out += [
        f"## Flow linearisation (at {FINE_SUBSTEPS} substeps)",
        "",
        "Largest difference from the default `flow_linear_ratio` "
        f"{LINEAR_RATIOS[0]} (% of full scale).",
        "",
        "| scenario | flow_linear_ratio | p1 % | p2 % | f % | x % |",
        "|---|---|---|---|---|---|",
    ]
    for r in rows:
        for ratio, e in r["linearisation"].items():
            out.append(
                f"| {r['name']} | {ratio} | " + " | ".join(_fmt(e[k]) for k in CHANNELS) + " |"
            )

    out += [
        "",
        "## Chatter and NaN",
        "",
        "Sign changes of dp/dt between consecutive substeps while a chamber is within "
        f"{100 * NEAR_FRACTION:g}% of (supply - ambient) of supply or ambient; in brackets "
        "those on consecutive substeps (period-2 oscillation). `NaN` marks a non-finite "
        "output.",
        "",
        "| scenario | flow_linear_ratio | "
        + " | ".join(f"{n} substeps" for n in SUBSTEPS + (FINE_SUBSTEPS,))
        + " |",
        "|---|---|" + "---|" * (len(SUBSTEPS) + 1),
    ]
    for r in rows:
        for ratio in LINEAR_RATIOS:
            cells = []
            for n in SUBSTEPS + (FINE_SUBSTEPS,):
                c = r["chatter"][(n, ratio)]
                cells.append(("NaN " if c["nan"] else "") + f"{c['flips']} ({c['alternating']})")
            out.append(f"| {r['name']} | {ratio} | " + " | ".join(cells) + " |")

    clamped = [r for r in rows if r["name"].startswith("(b)")]
    free = [r for r in rows if r["name"].startswith("(c)")]

    def calm(ratio):
        return [
            n
            for n in SUBSTEPS + (FINE_SUBSTEPS,)
            if all(
                r["chatter"][(m, ratio)]["alternating"] == 0 and not r["chatter"][(m, ratio)]["nan"]
                for r in rows
                for m in SUBSTEPS + (FINE_SUBSTEPS,)
                if m >= n
            )
        ]

    def say(n):
        return f"{n}" if n is not None else f"none up to {max(EXTRA_SUBSTEPS)}"

    out += [
        "",
        f"## Smallest substeps below {TOLERANCE_PERCENT:g}% of full scale",
        "",
        f"- clamped rod (b), all tubes and couplings: {say(smallest_substeps(clamped))}",
        f"- free rod (c), both cylinders: {say(smallest_substeps(free))}",
        f"- every scenario: {say(smallest_substeps(rows))}",
        "- without chatter (period-2 dp/dt alternation) or NaN in any scenario, from: "
        + ", ".join(
            f"{calm(r)[0] if calm(r) else 'none'} substeps at flow_linear_ratio {r}"
            for r in LINEAR_RATIOS
        ),
        "",
    ]
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m pneumatic_env.studies.convergence", description=__doc__.splitlines()[0]
    )
    parser.add_argument("--quick", action="store_true", help="shorter scenarios")
    parser.add_argument(
        "--no-scipy",
        action="store_true",
        help=f"use the kernel at {KERNEL_REFERENCE_SUBSTEPS} substeps as "
        "the reference instead of the SciPy reference solution",
    )
    args = parser.parse_args(argv)
    start = time.perf_counter()
    result = study(quick=args.quick, use_scipy=not args.no_scipy)
    print(markdown(result))
    print(f"(computed in {time.perf_counter() - start:.0f} s)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
