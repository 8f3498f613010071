"""``pneumatic-env identify``: calibrate on recordings, diagnose the residual, write a report.

Example: ``pneumatic-env identify runs/*.csv --report report/``. Exit status 0 on success,
2 when the data are refused (the reasons are printed; see :mod:`.checks`).
"""

from __future__ import annotations

import logging
import sys

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
        choices=("auto", "time", "recordings"),
        default="auto",
        help="held-out data: the end of each recording (time), the last recording "
        "(recordings), or recordings from three recordings on, else time (auto)",
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
    p.add_argument("--quiet", action="store_true", help="no progress lines")


def run(args) -> int:
    from .config import load_config
    from .diagnose import diagnose
    from .report import write_report

    if not args.quiet:
        logging.basicConfig(
            level=logging.INFO, format="%(asctime)s %(message)s", datefmt="%H:%M:%S"
        )
        logging.getLogger("pneumatic_env.identification").setLevel(logging.INFO)
    try:
        config = load_config(args.config)
        recordings = [read_checked(path) for path in args.recordings]
        diag = diagnose(
            recordings,
            params=args.params,
            candidates=_names(args.candidates),
            base_fit=_names(args.fit),
            holdout=args.holdout,
            config=config,
            max_effects=args.max_effects,
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
    selected = ", ".join(data["selected"]) or "none"
    print(
        f"{args.report}: selected effect(s): {selected}; mean held-out NRMSE "
        f"{data['baseline_nrmse_mean']:.4g} -> {data['after_nrmse_mean']:.4g}"
    )
    if data["suggested_experiment"]:
        print(f"suggested experiment: {data['suggested_experiment']}")
    return 0
