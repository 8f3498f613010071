"""The base calibration of virtual-rig campaigns against the rig's truth (issue 20).

``python -m pneumatic_env.studies.calibration_check DIR [DIR ...] [--config FILE]``
calibrates the base model (``identification.calibrate.calibrate``, every recording of
each directory at once, default fit settings or those of ``FILE``) and prints a Markdown
table per campaign: each fitted base parameter over the rig's value (from the first
recording's ``.truth.json``, written by ``pneumatic-env rig`` or ``rig_campaign``), the
final cost, the Jacobians, the wall time and the fit's stated reason. Synthetic data
only: a user's recordings have no truth file. A campaign whose fit lands in a wrong
stick-event basin shows a static friction far from 1.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

__all__ = ["check_campaign", "main"]

COLUMNS = ("static_friction_n", "dynamic_friction_n", "viscous_friction_n_s_per_m")


def check_campaign(directory: Path, config=None) -> dict:
    """Calibrate every recording of ``directory``; fitted over the rig's values and stats."""
    from pneumatic_env.identification.calibrate import calibrate
    from pneumatic_env.identification.checks import read_checked

    paths = sorted(directory.glob("*.csv"))
    if not paths:
        raise FileNotFoundError(f"{directory}: no recordings (*.csv)")
    truth_path = paths[0].with_suffix(".truth.json")
    if not truth_path.is_file():
        raise FileNotFoundError(f"{truth_path}: no truth file (synthetic campaigns only)")
    truth = json.loads(truth_path.read_text(encoding="utf-8"))["parameters"]
    t0 = time.monotonic()
    result = calibrate([read_checked(p) for p in paths], config=config).result
    return {
        "campaign": directory.name,
        "ratios": {k: v / truth[k] for k, v in result.values.items() if truth.get(k)},
        "cost": result.cost,
        "jacobians": result.n_jacobians,
        "seconds": time.monotonic() - t0,
        "message": result.message,
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m pneumatic_env.studies.calibration_check", description=__doc__.split("\n")[0]
    )
    ap.add_argument("dirs", nargs="+", type=Path, help="campaign directories with truth files")
    ap.add_argument("--config", help="identification config (default: the package's)")
    args = ap.parse_args(argv)
    from pneumatic_env.identification.config import load_config

    config = load_config(args.config)
    print("| campaign | " + " | ".join(COLUMNS) + " | cost | Jacobians | s | stopped |")
    print("|---" * (len(COLUMNS) + 5) + "|")
    for d in args.dirs:
        row = check_campaign(d, config)
        ratios = " | ".join(f"{row['ratios'].get(k, float('nan')):.3f}" for k in COLUMNS)
        print(
            f"| {row['campaign']} | {ratios} | {row['cost']:.4g} | {row['jacobians']} | "
            f"{row['seconds']:.0f} | {row['message']} |",
            flush=True,
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
