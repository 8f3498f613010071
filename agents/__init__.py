"""Controllers, the force-tracking benchmark and learning agents for ``pneumatic_env``.

* ``agents.base``: the controller interface (``Controller.reset()``, ``Controller.act(obs)``
  -> coil current in A, batched over rows) and ``ControllerContext``.
* ``agents.pid``: PID with back-calculation anti-windup, rate feed-forward, dead-band
  compensation; ``agents.tune_pid``: its grid-search tuning (configs/agents/tuning.yaml).
* ``agents.sliding_mode``: model-based sliding-mode force control (docs/sliding-mode.md).
* ``agents.bench``: the benchmark suite (configs/benchmark.yaml), ``pneumatic-env bench``.
* ``agents.sb3``: the native vector env as a Stable-Baselines3 ``VecEnv``;
  ``agents.train``: ``pneumatic-env train``; ``agents.policy``: trained actors in numpy.

SB3 and torch are imported only by ``agents.sb3``, ``agents.train`` and the export side of
``agents.policy``.
"""
from .base import Controller, ControllerContext, ZeroController
from .pid import PIDController
from .sliding_mode import SlidingModeController

__all__ = ["Controller", "ControllerContext", "ZeroController", "PIDController",
           "SlidingModeController"]
