"""``pneumatic-env identify``: calibrate on recordings, diagnose the residual, write a report.

Example: ``pneumatic-env identify runs/*.csv --report report/``. Exit status 0 on success,
2 when the data are refused (the reasons are printed; see :mod:`.checks`).
"""

from __future__ import annotations

import logging
import sys
from contextlib import nullcontext as _nothing

from pneumatic_env.params import ConfigError
from pneumatic_env.recording import RecordingError

from .checks import BadDataError, read_checked

__all__ = ["add_arguments", "run"]


def _names(text: str | None) -> list[str] | None:
    if text is None:
        return None
    return [t.strip() for t in text.split(",") if t.strip()]


def add_arguments(p) -> None:
    p.add_argument(
        "recordings",
        nargs="+",
        metavar="REC",
        help="recordings (NAME.csv, NAME.json or the stem NAME); several are fitted at once",
    )
    p.add_argument(
        "--report",
        required=True,
        metavar="DIR",
        help="directory for report.md, diagnosis.json, plots and fitted parameter "
        "sets (the recordings are never modified)",
    )
    p.add_argument(
        "--params",
        metavar="FILE",
        default=None,
        help="parameter YAML layered under each recording's sidecar (warm start)",
    )
    p.add_argument(
        "--candidates",
        metavar="A,B,...",
        default=None,
        help="candidate effects to try (default: all available; see configs/identification.yaml)",
    )
    p.add_argument(
        "--fit",
        metavar="A,B,...",
        default=None,
        help="base parameters to calibrate (default: the config's set for the data)",
    )
    p.add_argument(
        "--holdout",
        choices=("auto", "time", "recordings", "campaign"),
        default="auto",
        help="held-out data: the end of each recording (time), the last recording "
        "(recordings), per experiment type (campaign: the last recording of "
        "each rod mode with two or more, the end of the others), or campaign "
        "from three recordings on, else time (auto)",
    )
    p.add_argument(
        "--quick",
        action="store_true",
        help="screening only: rank every candidate in seconds (one Gauss-Newton "
        "step each), refit nothing; shows which effects are worth a full run",
    )
    p.add_argument(
        "--jobs",
        type=int,
        default=None,
        metavar="N",
        help="processes for the candidate refits (default: screening.jobs)",
    )
    p.add_argument(
        "--max-effects",
        type=int,
        default=None,
        metavar="N",
        help="greedy selection stops after N effects (default: config)",
    )
    p.add_argument(
        "--config",
        metavar="FILE",
        default=None,
        help="identification settings (default: configs/identification.yaml)",
    )
    p.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    p.add_argument("--quiet", action="store_true", help="no progress bar or log lines")
    p.add_argument(
        "--verbose", action="store_true", help="a log line per Jacobian as well as the progress bar"
    )


def run(args) -> int:
    from . import progress
    from .config import load_config
    from .diagnose import diagnose
    from .report import write_report

    bar = None
    if not args.quiet:
        logging.basicConfig(
            level=logging.INFO, format="%(asctime)s %(message)s", datefmt="%H:%M:%S"
        )
        logger = logging.getLogger("pneumatic_env.identification")
        bar = progress.Progress()
        # with a bar, only warnings and the stages' outcome lines; without, every line
        logger.setLevel(logging.INFO if args.verbose or bar._bar is None else logging.WARNING)
    try:
        config = load_config(args.config)
        recordings = [read_checked(path) for path in args.recordings]
        with progress.tracking(bar) if bar is not None else _nothing():
            diag = diagnose(
                recordings,
                params=args.params,
                candidates=_names(args.candidates),
                base_fit=_names(args.fit),
                holdout=args.holdout,
                config=config,
                max_effects=args.max_effects,
                quick=args.quick,
                jobs=args.jobs,
                on_round=lambda so_far: write_report(so_far, args.report, plots=False),
            )
    except BadDataError as exc:
        print(f"pneumatic-env identify: {exc}", file=sys.stderr)
        return 2
    except (RecordingError, ConfigError) as exc:
        print(f"pneumatic-env identify: {exc}", file=sys.stderr)
        return 2
    for issue in diag.issues:
        print(f"pneumatic-env identify: {issue}", file=sys.stderr)
    data = write_report(diag, args.report, plots=not args.no_plots)
    if args.quick:
        ranking = data["screening"][0]["ranking"] if data["screening"] else []
        th = data["thresholds"]
        worth = [
            f"{r['name']} (BIC {r['predicted_delta_ic']:.0f}, "
            f"{100 * r['predicted_training_improvement']:.0f} %)"
            for r in ranking
            if (r["predicted_delta_ic"] or 0) <= -th["min_ic_drop"]
            and (r["predicted_training_improvement"] or 0) >= th["min_predicted_improvement"]
        ]
        print(
            f"{args.report}: screening only ({data['timings_s']['total']:.0f} s); worth a full "
            f"fit (predicted BIC change, training error drop): {', '.join(worth) or 'none'}"
        )
        return 0
    selected = ", ".join(data["selected"]) or "none"
    print(
        f"{args.report}: selected effect(s): {selected}; mean held-out NRMSE "
        f"{data['baseline_nrmse_mean']:.4g} -> {data['after_nrmse_mean']:.4g} "
        f"({data['timings_s']['total']:.0f} s)"
    )
    if data["suggested_experiment"]:
        print(f"suggested experiment: {data['suggested_experiment']}")
    return 0
