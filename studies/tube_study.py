"""Tube models against an independent segmented line (docs/effects.md, ``tube_waves``).

``python -m pneumatic_env.studies.tube_study`` prints, for current steps through tubes of several
lengths (rod clamped, chambers at ambient), the largest error of the chamber pressures
p1, p2 over 100 ms, as a fraction of (supply - ambient), of three tube models against
``reference_solution.simulate_segmented_line`` (a finite-volume line that conserves the
air): the paper's delayed and attenuated flow (Eqs. 30, 31), the same with the tube's
air added to the dead volumes (``tube_volume_fraction = 1``), and the transmission line
(``tube_waves = 1``).
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from pneumatic_env.params import load_numerics, load_parameters, parameter_array
from pneumatic_env.physics import layout as L
from pneumatic_env.simulator import BatchSimulator

from .reference_solution import simulate_segmented_line

#: The compared tube models: label -> parameter overrides.
TUBE_MODELS = {
    "paper tube (Eqs. 30, 31)": {},
    "paper tube + tube volume": {"tube_volume_fraction": 1.0},
    "transmission line": {"tube_waves": 1},
}
SCENARIOS = [(length, current) for length in (0.5, 2.0, 3.0) for current in (0.5, -0.3, 1.5)]
DURATION_S = 0.1
SEGMENTS = 30  # the reference changes by under 0.2 % of full scale from 20 to 40 segments


def tube_model_errors(
    tube_length_m: float, current_a: float, n_segments: int = SEGMENTS, cylinder: str = "numatics"
) -> dict[str, float]:
    """Largest |p - p_ref| of p1 and p2 over ``DURATION_S`` at the default numerics, as a
    fraction of (supply - ambient), for each of ``TUBE_MODELS``."""
    base = load_parameters(cylinder, tube_length_m=tube_length_m)
    num = load_numerics()
    ref = simulate_segmented_line(
        base, current_a, DURATION_S, n_segments=n_segments, sample_dt_s=num["control_dt_s"]
    )
    sets = [
        load_parameters(cylinder, tube_length_m=tube_length_m, **kw) for kw in TUBE_MODELS.values()
    ]
    sim = BatchSimulator(
        parameter_array(sets), num["control_dt_s"], num["substeps"], parallel=False
    )
    steps = int(round(DURATION_S / num["control_dt_s"]))
    out = sim.rollout(np.full((steps, len(sets)), current_a))
    span = base["supply_pressure_pa"] - base["ambient_pressure_pa"]
    return {
        label: max(
            float(np.abs(out[:, row, j] - ref[key][1 : steps + 1]).max())
            for row, key in ((L.O_P1, "p1"), (L.O_P2, "p2"))
        )
        / span
        for j, label in enumerate(TUBE_MODELS)
    }


def markdown(rows: list[tuple[float, float, dict]]) -> str:
    out = [
        "| tube (m) | current (A) | " + " | ".join(TUBE_MODELS) + " |",
        "|---|---|" + "---|" * len(TUBE_MODELS),
    ]
    for length, current, errors in rows:
        out.append(
            f"| {length:g} | {current:g} | "
            + " | ".join(f"{100 * errors[m]:.1f} %" for m in TUBE_MODELS)
            + " |"
        )
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m pneumatic_env.studies.tube_study", description=__doc__.splitlines()[0]
    )
    parser.add_argument(
        "--segments", type=int, default=SEGMENTS, help="finite volumes per tube of the reference"
    )
    args = parser.parse_args(argv)
    start = time.perf_counter()
    rows = [
        (length, current, tube_model_errors(length, current, args.segments))
        for length, current in SCENARIOS
    ]
    print(markdown(rows))
    print(f"(computed in {time.perf_counter() - start:.0f} s)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
