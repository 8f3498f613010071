"""A test campaign on the virtual rig: several experiments on one rig, as a user records.

A user with a rig does not make one long recording: they run a few experiments of 2-3 s
each, with the rod clamped on the load cell (steps, multisines, pulse trains), against a
spring, and free, and pass them all to ``pneumatic-env identify``. :func:`make_campaign`
records such a campaign (synthetic data) from one virtual rig (one ``seed``: the same perturbed
parameters and the same effect in every experiment), each experiment with its own
excitation and noise draws (``run_rig(experiment=k)``).

An effect the rig can only make with the rod clamped (the load cell's compliance) is left
out of the moving-rod experiments, and a friction effect (``stribeck``, ``lugre``) shows
only where the rod moves; the truth file of each experiment states what it had.

``pneumatic-env rig`` (:func:`add_arguments`, :func:`run`) writes one recording
(:func:`.virtual_rig.make_recording`) or, with ``--campaign``, a campaign.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path
from typing import NamedTuple

from pneumatic_env.recording import PISTON_MODES

from .rig_excitation import EXCITATIONS, UserExcitation
from .rig_multi_effect import parse_effects, run_rig_effects
from .virtual_rig import MOVING_EFFECTS, RIG_EFFECTS, make_recording, write_rig_result

__all__ = ["CAMPAIGNS", "Experiment", "make_campaign", "add_arguments", "run"]


class Experiment(NamedTuple):
    """One experiment of a campaign: a name, the rod's mode, the excitation, its length,
    and optionally its own load (``run_rig`` keywords: spring stiffness, load mass)."""

    name: str
    piston: str
    excitation: str | UserExcitation
    duration_s: float
    load: tuple[tuple[str, float], ...] = ()


#: Campaigns by name. ``standard``: five experiments, 13 s in all (three clamped, one
#: spring, one free), the campaign of issue 20; ``clamped``: its three clamped ones;
#: ``small``: three short experiments (clamped steps, clamped multisine, spring) for tests.
#: ``user13``: five experiments, 13 s, recorded as a user might (issue 34): their own
#: signals, a softer spring with 0.2 kg, a free rod with 0.5 kg.
#: The free rod is driven by a multisine that keeps it off its end stops, as a user would:
#: a rod held at an end stop costs the kernel 10-30x more time per second of data (its
#: stiffness refinement near the stop; 2.8 s per simulated column for a 2.6 s triangle).
CAMPAIGNS: dict[str, tuple[Experiment, ...]] = {
    "standard": (
        Experiment("e1_clamped_steps", "fixed", "steps", 2.6),
        Experiment("e2_clamped_msine", "fixed", "multisine", 2.6),
        Experiment("e3_clamped_pulses", "fixed", "prbs", 2.6),
        Experiment("e4_spring_pulses", "spring", "prbs", 2.6),
        Experiment("e5_free_msine", "free", "multisine", 2.6),
    ),
    "clamped": (
        Experiment("e1_clamped_steps", "fixed", "steps", 2.6),
        Experiment("e2_clamped_msine", "fixed", "multisine", 2.6),
        Experiment("e3_clamped_pulses", "fixed", "prbs", 2.6),
    ),
    "small": (
        Experiment("e1_clamped_steps", "fixed", "steps", 1.0),
        Experiment("e2_clamped_msine", "fixed", "multisine", 1.0),
        Experiment("e3_spring_msine", "spring", "multisine", 1.0),
    ),
    # issue 34: as a user records, 13 s: clamped random steps, multisine and pulses, a
    # multisine against a soft spring, a slow sine on a free loaded rod
    "user13": (
        Experiment("e1_clamped_steps", "fixed", UserExcitation("random_steps", 1.0, 0.3), 3.0),
        Experiment(
            "e2_clamped_msine", "fixed", UserExcitation("multisine", 0.8, band_hz=(0.5, 30.0)), 2.0
        ),
        Experiment("e3_clamped_pulses", "fixed", UserExcitation("pulses", 0.5, 0.03, 0.5), 3.0),
        Experiment(
            "e4_spring_msine",
            "spring",
            UserExcitation("multisine", 0.6, band_hz=(0.5, 20.0)),
            2.0,
            (("spring_stiffness_n_per_m", 3000.0), ("load_mass_kg", 0.2)),
        ),
        Experiment(
            "e5_free_sine",
            "free",
            UserExcitation("sine", 0.3, period_s=1.0),
            3.0,
            (("load_mass_kg", 0.5),),
        ),
    ),
}
_CLAMPED_ONLY = ("load_cell_compliance",)


def experiment_effect(effect: str, piston: str) -> str:
    """The effect the rig can make in an experiment with the rod in mode ``piston``."""
    if effect in MOVING_EFFECTS and piston == "fixed":
        return "none"  # a friction law does not show on a clamped rod
    if effect in _CLAMPED_ONLY and piston != "fixed":
        return "none"  # the rig's plant form needs a clamped rod
    return effect


def make_campaign(
    out_dir,
    effect: str = "none",
    strength: float = 1.0,
    seed: int = 0,
    campaign: str | Sequence[Experiment] = "standard",
    prefix: str = "",
    overwrite: bool = False,
    effects: dict[str, float] | None = None,
    **rig,
) -> list[Path]:
    """Record every experiment of ``campaign`` on the rig ``seed``; returns the CSV paths.

    ``rig`` passes further keywords to :func:`.virtual_rig.run_rig` (e.g. ``cylinder``,
    ``tube_length_m``). ``effects`` ({name: strength}, two or more): a multi-effect rig
    (:func:`.rig_multi_effect.run_rig_effects`) instead of ``effect``; one effect is
    recorded as ``effect`` is (``run_rig``).
    """
    if effects is not None and len(effects) == 1:  # one effect: the single-effect rig
        ((effect, strength),) = effects.items()
        effects = None
    if isinstance(campaign, str):
        if campaign not in CAMPAIGNS:
            raise ValueError(
                f"campaign = {campaign!r} is not known; allowed: {', '.join(CAMPAIGNS)}"
            )
        campaign = CAMPAIGNS[campaign]
    paths = []
    for k, ex in enumerate(campaign, start=1):
        if effects:
            kept = {e: s for e, s in effects.items() if experiment_effect(e, ex.piston) != "none"}
            result = run_rig_effects(
                kept,
                seed=seed,
                experiment=k,
                duration_s=ex.duration_s,
                piston=ex.piston,
                excitation_kind=ex.excitation,
                **dict(ex.load),
                **{key: v for key, v in rig.items() if key != "own_forms"},
            )
            paths.append(write_rig_result(Path(out_dir), f"{prefix}{ex.name}", result, overwrite))
            continue
        paths.append(
            make_recording(
                Path(out_dir),
                name=f"{prefix}{ex.name}",
                overwrite=overwrite,
                effect=experiment_effect(effect, ex.piston),
                strength=strength,
                seed=seed,
                experiment=k,
                duration_s=ex.duration_s,
                piston=ex.piston,
                excitation_kind=ex.excitation,
                **dict(ex.load),
                **rig,
            )
        )
    return paths


# --------------------------------------------------------------------------- CLI


def add_arguments(p) -> None:
    p.add_argument(
        "--effect",
        default="none",
        choices=RIG_EFFECTS,
        help="extra effect in the plant (default: none)",
    )
    p.add_argument(
        "--effects",
        type=parse_effects,
        default=None,
        metavar="E1,E2[=S],...",
        help="several effects at once (a multi-effect rig, strength 1 unless NAME=S), "
        "instead of --effect",
    )
    p.add_argument(
        "--strength",
        type=float,
        default=1.0,
        help="effect strength; 1 = the realistic value of configs/identification.yaml",
    )
    p.add_argument("--out", required=True, metavar="DIR", help="output directory")
    p.add_argument("--seed", type=int, default=0, help="seed of perturbation, excitation and noise")
    p.add_argument("--name", default=None, help="recording name (default: rig_EFFECT_sS_seedN)")
    p.add_argument(
        "--duration",
        type=float,
        default=None,
        metavar="S",
        help="recording length in s (default: virtual_rig.duration_s)",
    )
    p.add_argument("--cylinder", default="numatics")
    p.add_argument("--tube-length", type=float, default=0.5, metavar="M")
    p.add_argument("--piston", default="fixed", choices=tuple(PISTON_MODES))
    p.add_argument("--excitation", default="identification", choices=EXCITATIONS)
    p.add_argument(
        "--no-perturb", action="store_true", help="use the configs' default base parameters exactly"
    )
    p.add_argument(
        "--kernel-form",
        action="store_true",
        help="put the kernel's own form of valve_null_leak, tube_volume, "
        "iso_flow_law, exhaust_discharge or stribeck in the plant (the "
        "candidate's form; default: the rig's own, studies/rig_forms.py)",
    )
    p.add_argument(
        "--campaign",
        default=None,
        metavar="NAME",
        help="record a campaign of experiments on this rig instead of one "
        "recording (studies/rig_campaign.py: standard, clamped, small)",
    )
    p.add_argument("--overwrite", action="store_true")


def run(args) -> int:
    if args.effects and args.effect != "none":
        print("pneumatic-env rig: give --effect or --effects, not both", file=sys.stderr)
        return 2
    if args.effects and len(args.effects) == 1:  # one effect: the single-effect rig
        ((args.effect, args.strength),) = args.effects.items()
        args.effects = None
    try:
        if args.campaign:
            paths = make_campaign(
                args.out,
                effects=args.effects,
                effect=args.effect,
                strength=args.strength,
                seed=args.seed,
                campaign=args.campaign,
                prefix=f"{args.name}_" if args.name else "",
                overwrite=args.overwrite,
                cylinder=args.cylinder,
                tube_length_m=args.tube_length,
                perturb=not args.no_perturb,
                own_forms=not args.kernel_form,
            )
            for path in paths:
                print(
                    f"{path}: synthetic (virtual rig) recording, campaign {args.campaign}, "
                    f"{_effects_text(args)}, seed {args.seed}"
                )
            return 0
        if args.effects:
            return _one_multi_effect_recording(args)
        path = make_recording(
            args.out,
            name=args.name,
            overwrite=args.overwrite,
            effect=args.effect,
            strength=args.strength,
            own_forms=not args.kernel_form,
            **_recording_settings(args),
        )
    except (FileExistsError, ValueError) as exc:
        print(f"pneumatic-env rig: {exc}", file=sys.stderr)
        return 2
    print(f"{path}: synthetic (virtual rig) recording, {_effects_text(args)}, seed {args.seed}")
    return 0


def _recording_settings(args) -> dict:
    """The ``run_rig`` settings of one recording from the command line (seed, length, rig,
    rod, excitation, perturbation), shared by the single- and multi-effect rigs."""
    return dict(
        seed=args.seed,
        duration_s=args.duration,
        cylinder=args.cylinder,
        tube_length_m=args.tube_length,
        piston=args.piston,
        excitation_kind=args.excitation,
        perturb=not args.no_perturb,
    )


def _effects_text(args) -> str:
    if args.effects:
        return "effects " + ", ".join(f"{e} strength {s:g}" for e, s in args.effects.items())
    return f"effect {args.effect} strength {args.strength:g}"


def _one_multi_effect_recording(args) -> int:
    """``pneumatic-env rig --effects ...`` without ``--campaign``: one recording."""
    result = run_rig_effects(args.effects, **_recording_settings(args))
    name = args.name or f"rig_{'+'.join(args.effects)}_seed{args.seed}"
    path = write_rig_result(args.out, name, result, args.overwrite)
    print(f"{path}: synthetic (virtual rig) recording, {_effects_text(args)}, seed {args.seed}")
    return 0
