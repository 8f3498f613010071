"""Held-out data of a diagnosis: which samples fit the models and which score them.

Modes (``--holdout``):

- ``time``: fit on the first ``fit.train_fraction`` of every recording, score on the rest;
- ``recordings``: fit on all recordings but the last, score on the whole last one;
- ``campaign``: a user's campaign of experiments (rod clamped, on a spring, free). The
  recordings are grouped by experiment type (the sidecar's rod mode); of every type with
  two or more recordings the last is held out whole, and every type with one recording
  is split in time (its start fits, its end scores). So every experiment type is scored
  on data no fit saw, and a whole held-out recording tests an effect on an experiment
  the fit never saw;
- ``auto`` (default): ``campaign`` from three recordings on, else ``time``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from .calibrate import Dataset, FitResult, channel_nrmse
from .candidates import Candidate, applicable
from .config import FitParameter, IdentificationConfig
from .problem import FitProblem

__all__ = ["HOLDOUT_MODES", "Holdout", "index_of"]

HOLDOUT_MODES = ("auto", "time", "recordings", "campaign")


def index_of(ds: Dataset, datasets: Sequence[Dataset]) -> int:
    """Position of ``ds`` (by identity: datasets hold arrays) in ``datasets``, or -1."""
    return next((k for k, other in enumerate(datasets) if other is ds), -1)


class Holdout:
    """Training and held-out parts of the datasets (see the module docstring)."""

    def __init__(self, datasets: Sequence[Dataset], mode: str, config: IdentificationConfig):
        self.config = config
        self.datasets = list(datasets)
        n = len(self.datasets)
        if mode not in HOLDOUT_MODES:
            raise ValueError(
                f"holdout = {mode!r} is not allowed: must be one of "
                f"{', '.join(repr(m) for m in HOLDOUT_MODES)}"
            )
        if mode == "auto":  # a time split keeps every recording (e.g. both tube lengths) in the fit
            mode = "campaign" if n >= 3 else "time"
        frac = config.number("fit", "train_fraction", positive=True)
        if mode in ("time", "campaign") and not frac < 1:
            raise ValueError(f"fit.train_fraction = {frac!r} must be < 1 for a time split")
        whole: list[Dataset] = []
        timed: list[Dataset] = []
        if mode == "time":
            timed = list(self.datasets)
        elif mode == "recordings":
            if n < 2:
                raise ValueError("holdout mode 'recordings' needs at least 2 recordings")
            whole = self.datasets[-1:]
        else:
            groups: dict[str, list[Dataset]] = {}
            for ds in self.datasets:
                groups.setdefault(ds.rod_mode, []).append(ds)
            for members in groups.values():
                if len(members) >= 2:
                    whole.append(members[-1])
                else:
                    timed.extend(members)
        self.train = [ds for ds in self.datasets if index_of(ds, whole) < 0]
        self.train_n = [
            max(2, int(round(frac * ds.n_samples))) if index_of(ds, timed) >= 0 else ds.n_samples
            for ds in self.train
        ]
        self.held = [
            ds for ds in self.datasets if index_of(ds, whole) >= 0 or index_of(ds, timed) >= 0
        ]
        self.held_masks = []
        for ds in self.held:
            m = np.ones(ds.n_samples, dtype=bool)
            if index_of(ds, timed) >= 0:
                m[: max(2, int(round(frac * ds.n_samples)))] = False
            self.held_masks.append(dict.fromkeys(ds.channels, m))
        self.mode = mode
        if mode == "time":
            self.info = {"mode": "time", "train_fraction": frac}
        elif mode == "recordings":
            self.info = {"mode": "recordings", "held_out": [ds.name for ds in whole]}
        else:
            self.info = {
                "mode": "campaign",
                "held_out": [ds.name for ds in whole],
                "time_split": [ds.name for ds in timed],
                "train_fraction": frac,
            }

    def training_problem(
        self,
        free: Sequence[FitParameter],
        fixed: Mapping[str, float | str],
        label: str,
        scopes: Mapping[str, Sequence[str]] | None = None,
    ) -> FitProblem:
        """The fit problem of ``free`` parameters (the rest ``fixed``) on the training data."""
        return FitProblem(
            self.train,
            free,
            fixed=fixed,
            n_samples=self.train_n,
            config=self.config,
            label=label,
            scopes=scopes,
        )

    def predict(self, fit: FitResult, datasets=None) -> list[dict[str, np.ndarray]]:
        """Whole-recording predictions of ``datasets`` (default: the held-out ones)."""
        datasets = self.held if datasets is None else datasets
        problem = FitProblem(
            datasets,
            [],
            fixed=fit.all_values(),
            config=self.config,
            label="predict",
            scopes=fit.scopes,
        )
        return problem.predict(np.zeros(0), [ds.n_samples for ds in datasets])

    def heldout_nrmse(self, fit: FitResult) -> tuple[dict, list]:
        preds = self.predict(fit)
        return channel_nrmse(self.held, preds, self.held_masks), preds

    def acted_on(self, cand: Candidate) -> set[str]:
        """The held-out recordings that could show ``cand`` on their own
        (:func:`.candidates.applicable`: a load cell's compliance on clamped rods, a
        friction law where the rod moves, else all)."""
        return {
            ds.name
            for ds in self.held
            if applicable(cand, ds.channels, ds.moving, [ds.rod_mode]) is None
        }

    def per_recording(self, preds: Sequence[dict]) -> dict[str, dict[str, float]]:
        """Held-out NRMSE per held-out recording and channel, from ``predict``'s output."""
        return {
            ds.name: channel_nrmse([ds], [pred], [mask])
            for ds, pred, mask in zip(self.held, preds, self.held_masks)
        }
