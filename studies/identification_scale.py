"""How the identification's wall time grows with the data (issue 20, target 1's scale).

``python -m pneumatic_env.studies.identification_scale --out runs/ident-scale`` records one
virtual rig (synthetic data) as the ``standard`` campaign (``--campaign user13``: the 13 s
user campaign of issue 34) repeated four times (20 recordings: every experiment four
times with its own excitation and noise draws), then times ``pneumatic-env identify``
(calibration and diagnosis, default settings) on its first recording, on the first five
(one campaign) and on all twenty, one after the other in this process, and prints a
Markdown table: seconds and stages per run, and each run's time per second of data.
Ratios between the runs of one invocation are the figures that count on a shared machine.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from .rig_campaign import CAMPAIGNS, Experiment, make_campaign

__all__ = ["main", "scale_campaign"]

SIZES = (1, 5, 20)


def scale_campaign(repeats: int = 4, campaign: str = "standard") -> list[Experiment]:
    """The ``campaign`` ``repeats`` times, each experiment under its own name."""
    return [
        Experiment(f"r{r + 1}_{ex.name}", ex.piston, ex.excitation, ex.duration_s)
        for r in range(repeats)
        for ex in CAMPAIGNS[campaign]
    ]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m pneumatic_env.studies.identification_scale", description=__doc__
    )
    parser.add_argument("--out", default="runs/ident-scale", help="recordings and reports")
    parser.add_argument("--effect", default="none", help="the rig's effect (default: none)")
    parser.add_argument("--seed", type=int, default=1, help="the rig's seed")
    parser.add_argument(
        "--campaign",
        default="standard",
        choices=[name for name, exs in CAMPAIGNS.items() if len(exs) == 5],
        help="the five-experiment campaign repeated four times (default: standard)",
    )
    parser.add_argument(
        "--sizes",
        default=",".join(map(str, SIZES)),
        help="numbers of recordings to time, comma-separated (at most 20)",
    )
    parser.add_argument("--jobs", type=int, default=None, help="refit processes")
    args = parser.parse_args(argv)
    sizes = [int(s) for s in args.sizes.split(",")]
    if not sizes or min(sizes) < 1 or max(sizes) > 20:
        parser.error(f"--sizes {args.sizes!r}: each must be between 1 and 20")

    from pneumatic_env.identification.checks import read_checked
    from pneumatic_env.identification.diagnose import diagnose
    from pneumatic_env.identification.report import write_report

    out = Path(args.out)
    tag = "" if args.campaign == "standard" else f"{args.campaign}-"
    rec_dir = out / f"recordings-{tag}{args.effect}-seed{args.seed}"
    experiments = scale_campaign(campaign=args.campaign)
    paths = [rec_dir / f"{ex.name}.csv" for ex in experiments]
    if not all(p.is_file() for p in paths):  # recorded once, reused by later runs
        paths = make_campaign(
            rec_dir, effect=args.effect, seed=args.seed, campaign=experiments, overwrite=True
        )
    rows = []
    for n in sizes:
        recs = [read_checked(p) for p in paths[:n]]
        seconds_of_data = sum(r.t[-1] - r.t[0] for r in recs)
        t0 = time.perf_counter()
        diag = diagnose(recs, jobs=args.jobs)
        wall = time.perf_counter() - t0
        write_report(diag, out / f"report-{tag}{n}", plots=False)
        stages = ", ".join(f"{k} {v:.0f}" for k, v in diag.timings.items() if k != "total")
        rows.append(
            f"| {n} | {seconds_of_data:.1f} | {wall:.0f} | {wall / seconds_of_data:.1f} | "
            f"{', '.join(diag.selected) or 'none'} | {stages} |"
        )
        print(f"{n} recordings: {wall:.0f} s", file=sys.stderr, flush=True)
    print(
        f"Rig `{args.effect}`, seed {args.seed} (synthetic); `pneumatic-env identify` "
        "defaults, one run after the other.\n"
    )
    print("| recordings | s of data | wall s | wall s per s of data | selected | stages (s) |")
    print("|---|---|---|---|---|---|")
    print("\n".join(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
