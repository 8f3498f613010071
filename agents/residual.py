"""Residual control: a bounded learned correction on top of a classical controller.

The policy's action ``a`` in [-1, 1] is added to the classical controller's current,

    u = clip(u_b + correction_fraction * i_max * g * a, -i_max, i_max),

where ``u_b`` is the output of the benchmark's sliding mode or PID (per-variant gains from
``configs/agents/<name>-<variant>.yaml``, or the config's ``gains``) and ``g`` an optional
gate in [0, 1] that shrinks the bound on slow references (:func:`residual_gate`; off by
default). Zero action is the classical controller, bit for bit, so training starts at its
performance (Johannink et al., ICRA 2019; Silver et al., 2018). The observation gets two
columns after the env's: ``base_current`` (u_b, A) and ``base_error`` (the controller's
error estimate divided by the reference scale: the sliding mode's predicted error
``f^(k+d) - r(k+lead)``, else ``y - r(k)``). The sliding mode is told the applied current
(``applied``), so its predictor knows the command in flight.

The Gymnasium wrappers over an env and the registered ``Residual...`` ids are in
:mod:`pneumatic_env.agents.residual_env`; this module is the batched core they and a
learned residual controller (``agents.learned``) share, given a built base controller.
"""

from __future__ import annotations

import copy
import dataclasses
import inspect
import math
import numbers
import time
from collections.abc import Mapping
from dataclasses import asdict, dataclass, fields

import numpy as np

from pneumatic_env.envs.observation import OBS_F, OBS_REF, observation_dim
from pneumatic_env.ids import variant_id

from .base import Controller, ControllerContext
from .pid import PIDController
from .sliding_mode import SlidingModeController

__all__ = [
    "ResidualConfig",
    "base_gain_names",
    "ResidualCore",
    "residual_gate",
    "base_context",
    "env_variant",
    "RESIDUAL_COLUMNS",
    "BASE_CONTROLLERS",
    "BASE_CLASSES",
]

RESIDUAL_COLUMNS = ("base_current", "base_error")
#: the classical controllers a residual sits on: name -> class
BASE_CLASSES: dict[str, type[Controller]] = {
    "sliding_mode": SlidingModeController,
    "pid": PIDController,
}
BASE_CONTROLLERS = tuple(BASE_CLASSES)


def base_gain_names(base: str, required: bool = False) -> list[str]:
    """The gains of the base controller ``base``: its class's keyword-only arguments (with
    ``required``, those without a default)."""
    signature = inspect.signature(BASE_CLASSES[base].__init__)
    return [
        p.name
        for p in signature.parameters.values()
        if p.kind is p.KEYWORD_ONLY and not (required and p.default is not p.empty)
    ]


@dataclass(frozen=True)
class ResidualConfig:
    """How the correction is bounded and what it sits on."""

    base: str = "sliding_mode"  # one of BASE_CONTROLLERS
    correction_fraction: float = 0.15  # bound of the correction, fraction of i_max
    gate_floor: float = 1.0  # residual_gate's floor; >= 1: no gate
    gate_scale: float = 0.3  # reference span (fraction of the scale) that opens the gate
    gate_steps: int = 20  # preview steps the gate looks at
    consistent_predictor: bool = True  # tell the base controller the applied current
    variant: str | None = None  # whose gains (default: the env's cylinder and tube)
    gains: Mapping | None = None  # the base's gains (default: the variant's, ``variant``)
    # the model parameters the base runs on (default: the env's; ``base_context``)
    base_model_params: Mapping | None = None

    def validate(self) -> None:
        if self.base not in BASE_CONTROLLERS:
            raise ValueError(
                f"base = {self.base!r} is not allowed: use one of {list(BASE_CONTROLLERS)}"
            )
        self._check_gains()
        self._check_base_model()
        for name, low in (("correction_fraction", 0.0), ("gate_floor", 0.0)):
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= low):
                raise ValueError(
                    f"{name} = {value!r} is not allowed: must be a finite number >= {low:g}"
                )
        if not (np.isfinite(self.gate_scale) and self.gate_scale > 0):
            raise ValueError(
                f"gate_scale = {self.gate_scale!r} is not allowed: must be a finite number > 0"
            )
        if int(self.gate_steps) != self.gate_steps or self.gate_steps < 0:
            raise ValueError(
                f"gate_steps = {self.gate_steps!r} is not allowed: must be an integer >= 0"
            )

    def _check_gains(self) -> None:
        """``gains``: None, or every gain of the base controller (``base_gain_names``) as a
        finite number or a bool; the controller checks their ranges when built."""
        if self.gains is None:
            return
        allowed = base_gain_names(self.base)
        if not isinstance(self.gains, Mapping):
            raise ValueError(
                f"gains = {self.gains!r} is not allowed: a mapping of the {self.base} "
                f"gains {allowed} (or None: the variant's)"
            )
        unknown = [str(k) for k in self.gains if k not in allowed]
        missing = [k for k in base_gain_names(self.base, required=True) if k not in self.gains]
        if unknown or missing:
            raise ValueError(
                f"gains = {dict(self.gains)!r} is not allowed: unknown {unknown}, missing "
                f"{missing}; the {self.base} gains are {allowed}"
            )
        for name, value in self.gains.items():
            plain = isinstance(value, (bool, np.bool_)) or (
                isinstance(value, numbers.Real) and math.isfinite(value)
            )
            if not plain:
                raise ValueError(
                    f"gains.{name} = {value!r} is not allowed: a finite number or true/false"
                )

    def _check_base_model(self) -> None:
        """``base_model_params``: None, or parameter names with finite numbers."""
        params = self.base_model_params
        if params is None:
            return
        bad = (
            {"base_model_params": params}
            if not isinstance(params, Mapping)
            else {
                f"base_model_params.{k}": v
                for k, v in params.items()
                if isinstance(v, bool) or not isinstance(v, numbers.Real) or not math.isfinite(v)
            }
        )
        for name, value in bad.items():
            raise ValueError(
                f"{name} = {value!r} is not allowed: a mapping of model parameter names to "
                "finite numbers (or None: the env's model)"
            )

    def as_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def split(cls, kwargs: dict) -> tuple[ResidualConfig, dict]:
        """(the residual keywords of ``kwargs`` as a config, the rest)."""
        names = {f.name for f in fields(cls)}
        config = cls(**{k: v for k, v in kwargs.items() if k in names})
        return config, {k: v for k, v in kwargs.items() if k not in names}


def base_context(context: ControllerContext, config: ResidualConfig) -> ControllerContext:
    """The context the base controller is built for: ``context`` (the env's model, or the
    model a self-contained file holds) with ``config.base_model_params`` if given, e.g. the
    nominal model a sliding mode beats the fitted one with on a rig (``agents.rig_training``)."""
    if config.base_model_params is None:
        return context
    params = {k: float(v) for k, v in config.base_model_params.items()}
    return dataclasses.replace(context, base_params=params)


def residual_gate(
    obs_si: np.ndarray, scale: float, floor: float, span_scale: float, steps: int = 20
) -> np.ndarray:
    """Bound of the correction relative to its range, per row:
    ``clip(floor + (max - min of r(k..k+steps)) / (span_scale * scale), 0, 1)``; ones when
    ``floor >= 1``. Slow references (a 1 Hz sine moves 4 % of the scale in 20 ms) get a
    small bound, fast ones and coming steps the full one."""
    if floor >= 1.0:
        return np.ones(obs_si.shape[0])
    r = obs_si[:, OBS_REF : OBS_REF + steps + 1]
    span = (r.max(axis=1) - r.min(axis=1)) / scale
    return np.clip(floor + span / span_scale, 0.0, 1.0)


def env_variant(env) -> str:
    """``"Numatics-2m"``: the cylinder and tube of an env (any wrappers, single or vector)."""
    core = env.unwrapped.core
    return variant_id(core.cylinder, core.base_params["tube_length_m"])


class ResidualCore:
    """The batched residual logic of the wrappers and of a learned residual controller.

    Per step: ``observe(obs)`` (the env's observation; its base columns go to the
    controller) -> the two residual columns; ``current(action)`` -> u; ``applied(u)``
    after choosing it. ``reset(rows)`` on new episodes; ``peek(obs, rows)`` gives the
    columns of final observations without changing the state.
    """

    def __init__(self, base: Controller, config: ResidualConfig):
        config.validate()
        self.base, self.config = base, config
        ctx = base.context
        self.base_dim = observation_dim(ctx.preview_steps)
        self.scale = float(ctx.scale_n)
        self.bound_a = config.correction_fraction * ctx.i_max_a
        self.i_max = ctx.i_max_a
        self.base_time_s = 0.0
        self._obs: np.ndarray | None = None

    def reset(self, rows=None) -> None:
        self.base.reset(rows)

    @staticmethod
    def _plain_error(obs_si) -> np.ndarray:
        return obs_si[:, OBS_F] - obs_si[:, OBS_REF]

    def _columns(self, current, error) -> np.ndarray:
        return np.stack([current, np.asarray(error) / self.scale], axis=1).astype(np.float32)

    def observe(self, obs) -> np.ndarray:
        """Run the base controller on the base columns of ``obs`` (n rows); returns the
        residual columns (n, 2) float32."""
        t0 = time.perf_counter()
        self._obs = np.asarray(obs, dtype=np.float64)[:, : self.base_dim]
        self.u_base = self.base.act(self._obs)
        si = self.base.observation_si(self._obs)
        error = getattr(self.base, "last_error", None)
        if error is None or not hasattr(self.base, "peek"):
            error = self._plain_error(si)
        self.gate = residual_gate(
            si, self.scale, self.config.gate_floor, self.config.gate_scale, self.config.gate_steps
        )
        self.base_time_s += time.perf_counter() - t0
        return self._columns(self.u_base, error)

    def current(self, action) -> np.ndarray:
        """u = clip(u_b + bound g a) (A) for actions in [-1, 1] (clipped to it)."""
        a = np.clip(np.asarray(action, dtype=np.float64).reshape(-1), -1.0, 1.0)
        self._correction = self.bound_a * self.gate * a
        return np.clip(self.u_base + self._correction, -self.i_max, self.i_max)

    def applied(self, current) -> None:
        """Tell the base controller the current applied after the last ``observe`` (rows
        with a correction; where it is zero the controller's own command was applied)."""
        if self.config.consistent_predictor and hasattr(self.base, "applied"):
            t0 = time.perf_counter()
            self.base.applied(self._obs, current, np.flatnonzero(self._correction != 0.0))
            self.base_time_s += time.perf_counter() - t0

    def follow(self, current) -> None:
        """Tell the base controller the current another controller chose after the last
        ``observe`` (a pure policy it teaches, ``agents.teacher``)."""
        self._correction = np.asarray(current, dtype=np.float64) - self.u_base
        self.applied(current)

    def peek(self, obs, rows) -> np.ndarray:
        """Residual columns for final observations ``obs`` of ``rows`` (no state change)."""
        t0 = time.perf_counter()
        o = np.asarray(obs, dtype=np.float64)[:, : self.base_dim]
        if hasattr(self.base, "peek"):
            current, error = self.base.peek(o, rows)
        else:  # a copy of the controller acts on the batch with those rows replaced
            assert self._obs is not None, "peek before the first act"
            batch = self._obs.copy()
            batch[rows] = o
            current = copy.deepcopy(self.base).act(batch)[rows]
            error = self._plain_error(self.base.observation_si(o))
        self.base_time_s += time.perf_counter() - t0
        return self._columns(current, error)
