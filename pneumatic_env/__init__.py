"""pneumatic_env: a fast, physically faithful Gymnasium simulation of a pneumatic force actuator.

The model is Richer & Hurmuzlu (2000), Part I (see docs/model.md): a proportional spool
valve, tubes with delay and attenuation, a double-acting cylinder clamped to a load cell
or free. Importing the package registers the environments listed by ``registered_ids()``
(``pneumatic_env/{task}-{cylinder}-{tube}m-v0``)::

    import pneumatic_env
    env = pneumatic_env.make("ForceTrack", "Numatics", 2.0)   # = gym.make(env_id(...))
    obs, info = env.reset(seed=0, options={"reference": {"kind": "sine", "amplitude": 40,
                                                         "frequency_hz": 5}})
    venv = pneumatic_env.make_vec("ForceTrack", "Numatics", 2.0, num_envs=64)

The public API (``__all__``), what a user needs:

* environments: ``make``, ``make_vec``, ``registered_ids``, ``env_id``,
  ``PneumaticTrackingEnv``, ``PneumaticTrackingVectorEnv``, ``make_reference``;
* parameters: ``load_parameters``, ``save_parameters``, ``ConfigError``;
* recordings and replay: ``read_recording``, ``write_recording``, ``simulate_recording``;
* the simulator: ``BatchSimulator``.

Everything else is imported from its module: the ids and constants from
``pneumatic_env.ids`` (``parse_env_id``, ``TUBE_LENGTHS_M``, ...), the tasks from
``pneumatic_env.envs.tasks``, ``parameter_info`` from ``pneumatic_env.params``, the
``Recording`` class from ``pneumatic_env.recording``, ``ReferenceSpec`` from
``pneumatic_env.references``.

Only ``ids`` and Gymnasium load on import; the other names load their module on first use
(NumPy, Numba, SciPy, PyYAML), and nothing here imports torch, Matplotlib or
Stable-Baselines3.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

import gymnasium as gym
from gymnasium.envs.registration import register, registry

from .ids import EPISODE_STEPS, PACKAGE_VERSION, env_id, parse_env_id, registered_ids

if TYPE_CHECKING:
    from .envs.env import PneumaticTrackingEnv, PneumaticTrackingVectorEnv
    from .params import ConfigError, load_parameters, save_parameters
    from .recording import read_recording, write_recording
    from .references import make_reference
    from .replay import simulate_recording
    from .simulator import BatchSimulator

__version__ = PACKAGE_VERSION

__all__ = [
    # environments
    "make",
    "make_vec",
    "registered_ids",
    "env_id",
    "PneumaticTrackingEnv",
    "PneumaticTrackingVectorEnv",
    "make_reference",
    # parameters
    "load_parameters",
    "save_parameters",
    "ConfigError",
    # recordings and replay
    "read_recording",
    "write_recording",
    "simulate_recording",
    # simulator
    "BatchSimulator",
]

# public name -> the module that defines it, imported on first use
_LAZY = {
    "PneumaticTrackingEnv": "envs.env",
    "PneumaticTrackingVectorEnv": "envs.env",
    "make_reference": "references",
    "load_parameters": "params",
    "save_parameters": "params",
    "ConfigError": "params",
    "read_recording": "recording",
    "write_recording": "recording",
    "simulate_recording": "replay",
    "BatchSimulator": "simulator",
}


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'pneumatic_env' has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{module}", __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))


def make(task: str, cylinder: str, tube_length_m: float | str, **kwargs: Any) -> gym.Env:
    """``gym.make(env_id(task, cylinder, tube_length_m), **kwargs)``: one registered env.

    ``cylinder`` is a name, alias or config id (``"Numatics"``, ``"airpel"``);
    ``tube_length_m`` one of ``TUBE_LENGTHS_M`` (0.5, 1, 2, 3). ``kwargs`` are the env's
    keyword arguments (see ``PneumaticTrackingEnv``).
    """
    return gym.make(env_id(task, cylinder, tube_length_m), **kwargs)


def make_vec(
    task: str, cylinder: str, tube_length_m: float | str, num_envs: int = 1, **kwargs: Any
) -> gym.vector.VectorEnv:
    """``gym.make_vec(env_id(...), num_envs, **kwargs)``: the native vector env
    (``PneumaticTrackingVectorEnv``), ``num_envs`` actuators stepped in one jitted call."""
    return gym.make_vec(env_id(task, cylinder, tube_length_m), num_envs=num_envs, **kwargs)


def _register_all() -> None:
    for name in registered_ids():
        if name in registry:
            continue
        parts = parse_env_id(name)
        register(
            id=name,
            entry_point="pneumatic_env.envs.env:PneumaticTrackingEnv",
            vector_entry_point="pneumatic_env.envs.env:PneumaticTrackingVectorEnv",
            max_episode_steps=EPISODE_STEPS,
            kwargs={
                "task": parts.task,
                "cylinder": parts.cylinder_id,
                "tube_length_m": parts.tube_length_m,
            },
        )


_register_all()
