"""The force-tracking benchmark: ``pneumatic-env bench`` (suite: configs/benchmark.yaml).

One native vector env per variant runs every task of the suite at once (one env per task,
each with its own reference and seed); the controller acts on the whole batch. Metrics per
task: RMS and peak tracking error (N and % of the force scale), control effort (RMS
current), chatter (RMS of current differences), air consumption (exhaust mass), and from the
chirp the closed-loop -3 dB bandwidth (method: docs/benchmark.md, :func:`frequency_response`).
Output: results.csv, results.md, results.json and PNG plots in ``--out``; :func:`leaderboard`
merges several result directories into one Markdown table. The suite file is read by
``agents/suite.py`` (re-exported here).
"""

from __future__ import annotations

import argparse
import math
import shlex
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

import gymnasium as gym
import numpy as np

from pneumatic_env import ids
from pneumatic_env.envs.tasks import scale_spec  # scale-unit reference spec -> SI
from pneumatic_env.params import load_numerics

from .base import Controller, ControllerContext, ControllerSpec
from .bench_results import (
    CSV_COLUMNS,
    METRIC_COLUMNS,
    leaderboard,
    read_results,
    write_results,
)
from .registry import controller_names, resolve_controller
from .suite import BenchTask, Suite, load_suite, parse_variant

__all__ = [
    "Suite",
    "BenchTask",
    "load_suite",
    "parse_variant",
    "make_env",
    "closed_loop",
    "frequency_response",
    "bandwidth",
    "error_bandwidth",
    "task_metrics",
    "resolve_controller",
    "run_suite",
    "write_results",
    "read_results",
    "leaderboard",
    "METRIC_COLUMNS",
    "CSV_COLUMNS",
    "add_arguments",
    "run",
]


def make_env(variant: str, n_envs: int, n_steps: int, task: str = ids.FORCE_TRACK, **options):
    """The native vector env of ``variant`` with ``n_envs`` envs and ``n_steps``-step episodes."""
    return gym.make_vec(
        parse_variant(variant, task), num_envs=n_envs, max_episode_steps=int(n_steps), **options
    )


# --------------------------------------------------------------------------- running


def closed_loop(
    env, controller: Controller, references: Sequence[dict], seeds: Sequence[int], n_steps: int
) -> dict:
    """Run ``controller`` on the vector ``env``, env i tracking ``references[i]`` (scale units).

    Env i is reset with ``seeds[i]`` and ``options={"reference": ...}`` (its reference in SI),
    so its episode is that of the single env ``gym.make(id, reference=<SI spec>)`` reset
    with that seed. Returns arrays of shape (n_steps, n_envs): ``force_n``, ``reference_n``,
    ``current_a``, ``exhaust_kg``.
    """
    n = env.num_envs
    if len(references) != n or len(seeds) != n:
        raise ValueError(
            f"closed_loop: {len(references)} references and {len(seeds)} seeds for {n} envs"
        )
    limit = getattr(env, "max_episode_steps", None)
    if limit is not None and n_steps > limit:
        raise ValueError(
            f"closed_loop: n_steps = {n_steps} is longer than the env's episodes "
            f"({limit} steps): make the env with max_episode_steps >= n_steps"
        )
    scale = env.unwrapped.reference_scale
    obs, _ = env.reset(
        seed=[int(s) for s in seeds],
        options={"reference": [scale_spec(spec, scale) for spec in references]},
    )
    controller.reset()
    out = {k: np.empty((n_steps, n)) for k in ("force_n", "reference_n", "current_a", "exhaust_kg")}
    for k in range(n_steps):
        action = controller.act(obs)
        obs, _, _, _, info = env.step(np.asarray(action, dtype=np.float64).reshape(n, 1))
        out["reference_n"][k] = info["reference"]
        out["force_n"][k] = info["reference"] + info["tracking_error"]
        out["current_a"][k] = info["coil_current_a"]
        out["exhaust_kg"][k] = info["exhaust_mass_kg"]
    return out


# --------------------------------------------------------------------------- metrics


def frequency_response(
    reference: np.ndarray,
    output: np.ndarray,
    dt_s: float,
    f_lo_hz: float,
    f_hi_hz: float,
    bins_per_octave: float = 6.0,
):
    """Closed-loop frequency response from a chirp: band-averaged H1 estimate.

    With R, Y the FFTs of the mean-removed reference and output, each log-frequency band
    (``bins_per_octave`` per octave between f_lo and f_hi) gets H = sum(Y conj(R)) / sum(|R|^2)
    over the FFT lines in it. Returns (band centre frequencies in Hz, complex H).
    """
    r = np.asarray(reference, float) - np.mean(reference)
    y = np.asarray(output, float) - np.mean(output)
    R, Y = np.fft.rfft(r), np.fft.rfft(y)
    f = np.fft.rfftfreq(r.size, dt_s)
    n_bands = max(int(np.ceil(np.log2(f_hi_hz / f_lo_hz) * bins_per_octave)), 1)
    edges = f_lo_hz * 2.0 ** (np.arange(n_bands + 1) / bins_per_octave)
    centres, H = [], []
    for lo, hi in zip(edges[:-1], edges[1:]):
        sel = (f >= lo) & (f < hi)
        power = np.sum(np.abs(R[sel]) ** 2)
        if not sel.any() or power == 0:
            continue
        centres.append(np.sqrt(lo * hi))
        H.append(np.sum(Y[sel] * np.conj(R[sel])) / power)
    return np.array(centres), np.array(H)


def _first_crossing(freqs_hz, values, level, falling: bool):
    """First frequency where ``values`` crosses ``level`` (log-f interpolation between bands)."""
    bad = values < level if falling else values >= level
    hits = np.flatnonzero(bad)
    if hits.size == 0:
        return float(freqs_hz[-1]), True
    j = int(hits[0])
    if j == 0:
        return float(freqs_hz[0]), False
    v0, v1 = values[j - 1], values[j]
    w = (v0 - level) / (v0 - v1)
    return float(np.exp(np.log(freqs_hz[j - 1]) + w * np.log(freqs_hz[j] / freqs_hz[j - 1]))), False


def bandwidth(freqs_hz: np.ndarray, response: np.ndarray, level: float = 1 / math.sqrt(2)):
    """First frequency where the closed-loop gain |H| = |F/r| falls below ``level`` (-3 dB).

    Returns (bandwidth in Hz, lower_bound); ``lower_bound`` is True when |H| stays above the
    level over the whole band, and the bandwidth is then the highest band centre.
    """
    return _first_crossing(freqs_hz, np.abs(response), level, falling=True)


def error_bandwidth(freqs_hz: np.ndarray, response: np.ndarray, level: float = 1 / math.sqrt(2)):
    """First frequency where the tracking error |1 - H| = |E/r| rises to ``level`` (-3 dB).

    Unlike :func:`bandwidth` it counts phase errors: a pure delay D keeps |H| = 1 but has
    |1 - H| = 2 |sin(pi f D)|. Returns (Hz, lower_bound) as :func:`bandwidth`.
    """
    return _first_crossing(freqs_hz, np.abs(1.0 - response), level, falling=False)


def task_metrics(force_n, reference_n, current_a, exhaust_kg, scale_n: float) -> dict:
    """Tracking, effort, chatter and air metrics of one task (arrays over its steps)."""
    e = np.asarray(force_n) - np.asarray(reference_n)
    rms, peak = float(np.sqrt(np.mean(e**2))), float(np.max(np.abs(e)))
    i = np.asarray(current_a)
    return {
        "rms_error_n": rms,
        "rms_error_pct": 100 * rms / scale_n,
        "peak_error_n": peak,
        "peak_error_pct": 100 * peak / scale_n,
        "effort_rms_a": float(np.sqrt(np.mean(i**2))),
        "chatter_rms_a": float(np.sqrt(np.mean(np.diff(i) ** 2))) if i.size > 1 else 0.0,
        "air_mg": 1e6 * float(exhaust_kg[-1]),
    }


# --------------------------------------------------------------------------- controllers

# --------------------------------------------------------------------------- suite run


def run_suite(
    controller: str | ControllerSpec,
    variants: Sequence[str] | None = None,
    suite: Suite | None = None,
    config: str | None = None,
    progress: Callable[[str], None] | None = None,
    env_options: dict | None = None,
):
    """Run every task on every variant; returns (rows for the CSV, traces per variant).

    ``controller``: a name or file for ``resolve_controller``, or a ``ControllerSpec`` (the
    same for every variant). ``env_options``: more env keyword arguments (e.g. ``plant``
    for a perturbed plant, a fitted rig's ``params``: ``agents.rig``)."""
    suite = suite or load_suite()
    variants = list(variants or suite.variants)
    rows, traces = [], {}
    dt = load_numerics()["control_dt_s"]
    steps = [int(round(t.duration_s / dt)) for t in suite.tasks]
    n_steps = max(steps)
    for variant in variants:
        parse_variant(variant, suite.task)
        cspec = (
            controller
            if isinstance(controller, ControllerSpec)
            else resolve_controller(controller, variant, config, suite.preview_steps)
        )
        options = {**cspec.env_options, **(env_options or {})}
        env = make_env(variant, len(suite.tasks), n_steps, suite.task, **options)
        dt, scale = env.unwrapped.control_dt_s, env.unwrapped.reference_scale
        ctrl = cspec.build(ControllerContext.from_env(env))
        if progress:
            progress(f"{cspec.name} on {variant}: {len(suite.tasks)} tasks, {n_steps} steps")
        tr = closed_loop(
            env, ctrl, [t.reference for t in suite.tasks], [t.seed for t in suite.tasks], n_steps
        )
        env.close()
        traces[variant] = {"dt_s": dt, "scale_n": scale, "steps": steps, **tr}
        for i, task in enumerate(suite.tasks):
            k = steps[i]
            m = task_metrics(
                tr["force_n"][:k, i],
                tr["reference_n"][:k, i],
                tr["current_a"][:k, i],
                tr["exhaust_kg"][:k, i],
                scale,
            )
            for key in ("bandwidth", "error_bandwidth"):
                m[f"{key}_hz"], m[f"{key}_lower_bound"] = math.nan, ""
            if task.name == suite.bandwidth_task:
                ref = task.reference
                kk = min(k, int(round(ref["duration_s"] / dt)))
                f, H = frequency_response(
                    tr["reference_n"][:kk, i],
                    tr["force_n"][:kk, i],
                    dt,
                    ref["f0_hz"],
                    ref["f1_hz"],
                    suite.bins_per_octave,
                )
                bw, lower = bandwidth(f, H, suite.bandwidth_level)
                m["bandwidth_hz"], m["bandwidth_lower_bound"] = bw, bool(lower)
                bw, lower = error_bandwidth(f, H, suite.bandwidth_level)
                m["error_bandwidth_hz"], m["error_bandwidth_lower_bound"] = bw, bool(lower)
                traces[variant]["response"] = (f, H)
            rows.append(
                {
                    "suite_version": suite.version,
                    "controller": cspec.name,
                    "variant": variant,
                    "task": task.name,
                    "duration_s": task.duration_s,
                    "force_scale_n": scale,
                    **m,
                }
            )
    return rows, traces


# --------------------------------------------------------------------------- CLI


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--controller",
        help="pid | sliding_mode | zero | a shipped policy "
        "(--list) | path to a trained policy (.npz export or SB3 .zip)",
    )
    parser.add_argument(
        "--list",
        action="store_true",
        help="print every controller name --controller accepts, one a line",
    )
    parser.add_argument(
        "--variants",
        nargs="+",
        metavar="VARIANT",
        help="subset of the suite's variants, e.g. Numatics-0.5m Airpel-2m",
    )
    parser.add_argument(
        "--config",
        help="controller config YAML (default: "
        "configs/agents/<controller>-<variant>.yaml or <controller>.yaml)",
    )
    parser.add_argument("--suite", help="suite file (default configs/benchmark.yaml)")
    parser.add_argument(
        "--rig",
        metavar="REPORT_DIR",
        help="run on the fitted rig of an identification report (`pneumatic-env identify "
        "... --report REPORT_DIR`; agents/rig.py) instead of the suite's variants",
    )
    parser.add_argument("--out", help="output directory (default runs/bench/<controller>)")
    parser.add_argument(
        "--leaderboard",
        nargs="+",
        metavar="RESULTS",
        help="instead of running: merge these result dirs/CSVs into one "
        "Markdown table (written to --out if given, else printed)",
    )


def run(args: argparse.Namespace) -> int:
    if args.list:
        print("\n".join(controller_names()))
        return 0
    if args.leaderboard:
        text = leaderboard(args.leaderboard)
        if args.out:
            Path(args.out).write_text(text + "\n", encoding="utf-8")
            print(f"wrote {args.out}")
        else:
            print(text)
        return 0
    if not args.controller:
        raise SystemExit("pneumatic-env bench: give --controller (or --leaderboard, --list)")
    suite = load_suite(args.suite)
    env_options = None
    if args.rig:
        from .rig import load_rig

        rig = load_rig(args.rig)
        args.variants, env_options = [rig.variant], rig.env_options
    for variant in args.variants or suite.variants:  # a bad name fails before any run
        resolve_controller(args.controller, variant, args.config, suite.preview_steps)
    name = Path(args.controller).stem if Path(args.controller).suffix else args.controller
    out = Path(args.out or Path("runs") / "bench" / name)
    command = (
        "pneumatic-env bench " + " ".join(shlex.quote(a) for a in sys.argv[2:])
        if len(sys.argv) > 1 and sys.argv[1] == "bench"
        else ""
    )
    rows, traces = run_suite(
        args.controller,
        args.variants,
        suite,
        args.config,
        progress=lambda msg: print(msg, flush=True),
        env_options=env_options,
    )
    for p in write_results(out, rows, traces, suite, command):
        print(f"wrote {p}")
    return 0
