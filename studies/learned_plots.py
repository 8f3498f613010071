"""Figures of the learned controllers (issue 19): learning curves over seeds, and tracking
traces of a learned controller against the sliding mode.

    python -m pneumatic_env.studies.learned_plots curves RUN_DIR [RUN_DIR ...] \\
        --out docs/figures/learning_curves.png
    python -m pneumatic_env.studies.learned_plots traces --controller ppo_residual \\
        [--variant Numatics-2m] [--tasks sine_10hz sine_20hz chirp] \\
        --out docs/figures/tracking_learned.png

``curves`` reads each run's ``progress.csv`` (``agents/ppo.py``): the validation RMS error
against wall time and against env steps, the median over the runs and their range.
``traces`` runs the benchmark suite (``agents.bench.run_suite``) for the controller and
the sliding mode and plots force against reference on the named tasks.
"""

from __future__ import annotations

import argparse
import csv
from collections.abc import Sequence
from pathlib import Path

import numpy as np

__all__ = ["read_curve", "plot_curves", "plot_traces", "main"]


def read_curve(run: str | Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(wall s, env steps, validation RMS %) at the run's validations."""
    path = Path(run) / "progress.csv"
    if not path.is_file():
        raise FileNotFoundError(f"no progress.csv in {str(run)!r}: give ppo_fast run directories")
    with path.open(encoding="utf-8") as f:
        rows = [r for r in csv.DictReader(f) if r.get("val_rms_pct")]
    if not rows:
        raise ValueError(f"{path}: no validation rows (val_rms_pct) yet")
    cols = [np.array([float(r[k]) for r in rows]) for k in ("wall_s", "steps", "val_rms_pct")]
    return cols[0], cols[1], cols[2]


def _band(xs: list[np.ndarray], ys: list[np.ndarray], n: int = 60):
    grid = np.linspace(max(x[0] for x in xs), min(x[-1] for x in xs), n)  # where all have data
    stacked = np.array([np.interp(grid, x, y) for x, y in zip(xs, ys)])
    return grid, np.median(stacked, axis=0), stacked.min(axis=0), stacked.max(axis=0)


def plot_curves(runs: Sequence[str | Path], out: Path, baseline_pct: float | None = None):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    curves = [read_curve(r) for r in runs]
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.2), sharey=True)
    for ax, index, label, unit in ((axes[0], 0, "wall time", 60.0), (axes[1], 1, "env steps", 1e6)):
        xs = [c[index] / unit for c in curves]
        ys = [c[2] for c in curves]
        grid, median, low, high = _band(xs, ys)
        ax.fill_between(grid, low, high, alpha=0.3, label=f"range over {len(runs)} runs")
        ax.plot(grid, median, lw=1.5, label="median")
        if baseline_pct is not None:
            ax.axhline(baseline_pct, color="k", ls="--", lw=1, label="sliding mode")
        ax.set_xlabel(f"{label} ({'min' if index == 0 else 'M'})")
    axes[0].set_ylabel("validation RMS error (% of scale)")
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=90)
    plt.close(fig)
    return out


def plot_traces(controller: str, variant: str, tasks: Sequence[str], out: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from pneumatic_env.agents.bench import run_suite
    from pneumatic_env.agents.suite import load_suite

    suite = load_suite()
    names = [t.name for t in suite.tasks]
    unknown = [t for t in tasks if t not in names]
    if unknown:
        raise ValueError(f"--tasks names {unknown}, not allowed: the suite's tasks are {names}")
    traces = {c: run_suite(c, [variant], suite)[1][variant] for c in ("sliding_mode", controller)}
    fig, axes = plt.subplots(len(tasks), 1, figsize=(8, 2.3 * len(tasks)), squeeze=False)
    for ax, task in zip(axes[:, 0], tasks):
        i = names.index(task)
        ref = traces["sliding_mode"]
        k = ref["steps"][i]
        t = (np.arange(k) + 1) * ref["dt_s"]
        ax.plot(t, ref["reference_n"][:k, i], "k--", lw=1, label="reference")
        for c, tr in traces.items():
            e = tr["force_n"][:k, i] - tr["reference_n"][:k, i]
            rms = 100 * np.sqrt(np.mean(e**2)) / tr["scale_n"]
            ax.plot(t, tr["force_n"][:k, i], lw=1, label=f"{c} ({rms:.2f} %)")
        ax.set_title(f"{variant}: {task}", fontsize=9)
        ax.set_ylabel("F (N)")
        ax.legend(loc="upper right", fontsize=7)
    axes[-1, 0].set_xlabel("t (s)")
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=90)
    plt.close(fig)
    return out


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m pneumatic_env.studies.learned_plots")
    sub = p.add_subparsers(dest="what", required=True)
    c = sub.add_parser("curves", help="learning curves over runs")
    c.add_argument("runs", nargs="+")
    c.add_argument("--baseline-pct", type=float, help="a horizontal line (the sliding mode)")
    c.add_argument("--out", type=Path, default=Path("docs/figures/learning_curves.png"))
    t = sub.add_parser("traces", help="tracking traces against the sliding mode")
    t.add_argument("--controller", default="ppo_residual")
    t.add_argument("--variant", default="Numatics-2m")
    t.add_argument("--tasks", nargs="+", default=["sine_10hz", "sine_20hz", "chirp"])
    t.add_argument("--out", type=Path, default=Path("docs/figures/tracking_learned.png"))
    args = p.parse_args(argv)
    if args.what == "curves":
        path = plot_curves(args.runs, args.out, args.baseline_pct)
    else:
        path = plot_traces(args.controller, args.variant, args.tasks, args.out)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
