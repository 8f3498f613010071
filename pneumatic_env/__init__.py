"""pneumatic_env: a fast, physically faithful Gymnasium simulation of a pneumatic force actuator.

The model is Richer & Hurmuzlu (2000), Part I; see docs/model.md. Importing the package
registers the environments listed by ``registered_ids()``.
"""
from gymnasium.envs.registration import register, registry

from ._numba_cache import invalidate_stale_numba_cache

invalidate_stale_numba_cache()  # before any jitted function is loaded from the cache

__version__ = "0.1.0"

CYLINDER_IDS = {"Numatics": "numatics-0750D02-03A", "Airpel": "airpel-E16D3.0N"}
TUBE_LENGTHS_M = {"0.5": 0.5, "1": 1.0, "2": 2.0, "3": 3.0}
TASK_IDS = ("ForceTrack", "PositionTrack")
EPISODE_STEPS = 2000  # 2 s at the 1 ms control period


def env_id(task: str, cylinder: str, tube: str) -> str:
    """``pneumatic_env/{task}-{cylinder}-{tube}m-v0``."""
    return f"pneumatic_env/{task}-{cylinder}-{tube}m-v0"


def registered_ids() -> list[str]:
    """Every environment id this package registers."""
    return [env_id(t, c, L) for t in TASK_IDS for c in CYLINDER_IDS for L in TUBE_LENGTHS_M]


def _register_all() -> None:
    for task in TASK_IDS:
        for short, cylinder in CYLINDER_IDS.items():
            for tube, length in TUBE_LENGTHS_M.items():
                name = env_id(task, short, tube)
                if name in registry:
                    continue
                register(
                    id=name,
                    entry_point="pneumatic_env.envs.env:PneumaticTrackingEnv",
                    vector_entry_point="pneumatic_env.envs.env:PneumaticTrackingVectorEnv",
                    max_episode_steps=EPISODE_STEPS,
                    kwargs={"task": task, "cylinder": cylinder, "tube_length_m": length},
                )


_register_all()
