"""Controllers, the force-tracking benchmark and learning agents for ``pneumatic_env``
(installed as ``pneumatic_env.agents``).

* ``base``: the controller interface (``Controller.reset()``, ``Controller.act(obs)``
  -> coil current in A, batched over rows) and ``ControllerContext``.
* ``pid``: PID with back-calculation anti-windup, rate feed-forward, dead-band
  compensation; ``tune_pid``: its grid-search tuning (configs/agents/tuning.yaml).
* ``sliding_mode``: model-based sliding-mode force control (docs/sliding-mode.md).
* ``bench``: the benchmark suite (configs/benchmark.yaml), ``pneumatic-env bench``.
* ``sb3``: the native vector env as a Stable-Baselines3 ``VecEnv``;
  ``train``: ``pneumatic-env train``; ``policy``: trained actors in numpy.

SB3 and torch are imported only by ``sb3``, ``train`` and the export side of
``policy``.
"""

from .base import Controller, ControllerContext, ZeroController
from .pid import PIDController
from .sliding_mode import SlidingModeController

__all__ = [
    "Controller",
    "ControllerContext",
    "ZeroController",
    "PIDController",
    "SlidingModeController",
]
