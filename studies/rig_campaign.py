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
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import NamedTuple

from .rig_excitation import UserExcitation
from .virtual_rig import MOVING_EFFECTS, make_recording

__all__ = ["CAMPAIGNS", "Experiment", "make_campaign"]


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
    **rig,
) -> list[Path]:
    """Record every experiment of ``campaign`` on the rig ``seed``; returns the CSV paths.

    ``rig`` passes further keywords to :func:`.virtual_rig.run_rig` (e.g. ``cylinder``,
    ``tube_length_m``).
    """
    if isinstance(campaign, str):
        if campaign not in CAMPAIGNS:
            raise ValueError(
                f"campaign = {campaign!r} is not known; allowed: {', '.join(CAMPAIGNS)}"
            )
        campaign = CAMPAIGNS[campaign]
    paths = []
    for k, ex in enumerate(campaign, start=1):
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
