"""Identifiers: cylinders, tube lengths, tasks, piston modes and environment ids.

The one home of every name the package registers, parses or writes into a file. Plain
Python (no NumPy, no Numba), so ``import pneumatic_env`` stays cheap and every layer, the
physics included, may import it.

An environment id reads ``pneumatic_env/{task}-{cylinder}-{tube}m-v0``, for example
``pneumatic_env/ForceTrack-Numatics-2m-v0``: ``task`` from :data:`TASK_IDS`, ``cylinder``
a key of :data:`CYLINDER_IDS` (its value is the parameter file's name under
``configs/cylinders/``) and ``tube`` a key of :data:`TUBE_LENGTHS_M`. The cylinder-and-tube
part, ``Numatics-2m``, is a *variant* (the benchmark's and the agent configs' name).
"""

from __future__ import annotations

from typing import NamedTuple

__all__ = [
    "PACKAGE_VERSION",
    "CYLINDER_IDS",
    "CYLINDERS",
    "CYLINDER_ALIASES",
    "DEFAULT_CYLINDER",
    "TUBE_LENGTHS_M",
    "FORCE_TRACK",
    "POSITION_TRACK",
    "TASK_IDS",
    "EPISODE_STEPS",
    "ENV_PREVIEW_STEPS",
    "PISTON_MODE_CODES",
    "PISTON_MODE_NAMES",
    "MODE_FIXED",
    "MODE_FREE",
    "MODE_SPRING",
    "ENV_NAMESPACE",
    "ENV_VERSION",
    "EnvId",
    "env_id",
    "parse_env_id",
    "registered_ids",
    "variant_id",
    "split_variant",
    "cylinder_name",
    "tube_name",
]

#: the package's version (``pneumatic_env.__version__``; written into the notes of a
#: simulated recording)
PACKAGE_VERSION = "0.1.0"

# --------------------------------------------------------------------------- cylinders

#: Cylinder name in env ids -> its config id (file stem under configs/cylinders/).
CYLINDER_IDS = {"Numatics": "numatics-0750D02-03A", "Airpel": "airpel-E16D3.0N"}
#: Config id -> short aliases the loaders accept (any case): the env-id name, lower case.
CYLINDERS: dict[str, tuple[str, ...]] = {
    config_id: (name.lower(),) for name, config_id in CYLINDER_IDS.items()
}
#: Lower-case config id or alias -> config id.
CYLINDER_ALIASES: dict[str, str] = {
    **{config_id.lower(): config_id for config_id in CYLINDERS},
    **{alias: config_id for config_id, aliases in CYLINDERS.items() for alias in aliases},
}
DEFAULT_CYLINDER = CYLINDER_IDS["Numatics"]

# --------------------------------------------------------------------------- tubes, tasks

#: Tube length in env ids (without the "m") -> tube length (m).
TUBE_LENGTHS_M = {"0.5": 0.5, "1": 1.0, "2": 2.0, "3": 3.0}

FORCE_TRACK = "ForceTrack"  # rod clamped to a load cell, track a force
POSITION_TRACK = "PositionTrack"  # rod free, track a piston position
TASK_IDS = (FORCE_TRACK, POSITION_TRACK)

#: The registered ``max_episode_steps``: 2 s at the 1 ms control period.
EPISODE_STEPS = 2000
#: The env's default reference preview (``preview_steps``, control periods). The benchmark
#: sets its own (``env.preview_steps`` of configs/benchmark.yaml, 20): a different fact.
ENV_PREVIEW_STEPS = 10

# --------------------------------------------------------------------------- piston modes

#: Piston (rod) mode name -> the physics core's code (the ``piston_mode`` parameter row).
PISTON_MODE_CODES = {"fixed": 0, "free": 1, "spring": 2}
PISTON_MODE_NAMES = {code: name for name, code in PISTON_MODE_CODES.items()}
MODE_FIXED = PISTON_MODE_CODES["fixed"]  # rod clamped (to a rigid load cell)
MODE_FREE = PISTON_MODE_CODES["free"]  # rod free, a mass and a force load
MODE_SPRING = PISTON_MODE_CODES["spring"]  # rod on a spring (a compliant load cell)

# --------------------------------------------------------------------------- env ids

ENV_NAMESPACE = "pneumatic_env"
ENV_VERSION = 0


def _not_allowed(field: str, value, allowed) -> ValueError:
    return ValueError(f"{field} = {value!r} is not allowed: use one of {list(allowed)}")


def cylinder_name(cylinder: str) -> str:
    """The env-id name (``"Numatics"``) of a cylinder given by that name, its config id or
    an alias, in any case."""
    key = str(cylinder).strip().lower()
    for name, config_id in CYLINDER_IDS.items():
        if key in (name.lower(), config_id.lower()) or CYLINDER_ALIASES.get(key) == config_id:
            return name
    raise _not_allowed("cylinder", cylinder, CYLINDER_IDS)


def tube_name(tube) -> str:
    """The env-id name (``"0.5"``) of a tube given by that name or its length in m."""
    if isinstance(tube, str) and tube in TUBE_LENGTHS_M:
        return tube
    for name, length_m in TUBE_LENGTHS_M.items():
        try:
            if not isinstance(tube, bool) and float(tube) == length_m:
                return name
        except (TypeError, ValueError):
            break
    raise _not_allowed("tube", tube, TUBE_LENGTHS_M)


class EnvId(NamedTuple):
    """The parts of an environment id: ``task``, ``cylinder`` and ``tube`` names."""

    task: str
    cylinder: str  # a key of CYLINDER_IDS
    tube: str  # a key of TUBE_LENGTHS_M

    @property
    def id(self) -> str:
        """``pneumatic_env/{task}-{cylinder}-{tube}m-v0``."""
        return f"{ENV_NAMESPACE}/{self.task}-{self.variant}-v{ENV_VERSION}"

    @property
    def variant(self) -> str:
        """``{cylinder}-{tube}m``."""
        return f"{self.cylinder}-{self.tube}m"

    @property
    def cylinder_id(self) -> str:
        """The cylinder's config id (``configs/cylinders/<id>.yaml``)."""
        return CYLINDER_IDS[self.cylinder]

    @property
    def tube_length_m(self) -> float:
        return TUBE_LENGTHS_M[self.tube]


def env_id(task: str, cylinder: str, tube) -> str:
    """``pneumatic_env/{task}-{cylinder}-{tube}m-v0``, checked.

    ``cylinder`` may be the env-id name, the config id or an alias; ``tube`` the name
    (``"0.5"``) or the length in m (``0.5``). ``env_id("ForceTrack", "numatics", 2.0)`` is
    ``"pneumatic_env/ForceTrack-Numatics-2m-v0"``.
    """
    if task not in TASK_IDS:
        raise _not_allowed("task", task, TASK_IDS)
    return EnvId(task, cylinder_name(cylinder), tube_name(tube)).id


def variant_id(cylinder: str, tube) -> str:
    """``{cylinder}-{tube}m`` (e.g. ``"Numatics-2m"``), checked as :func:`env_id`."""
    return EnvId(TASK_IDS[0], cylinder_name(cylinder), tube_name(tube)).variant


def _variants() -> list[str]:
    return [f"{c}-{t}m" for c in CYLINDER_IDS for t in TUBE_LENGTHS_M]


def split_variant(variant: str) -> tuple[str, str]:
    """``"Numatics-2m"`` -> ``("Numatics", "2")``; names exactly as in env ids."""
    parts = str(variant).rsplit("-", 1)
    if (
        len(parts) != 2
        or parts[0] not in CYLINDER_IDS
        or not parts[1].endswith("m")
        or parts[1][:-1] not in TUBE_LENGTHS_M
    ):
        raise _not_allowed("variant", variant, _variants())
    return parts[0], parts[1][:-1]


def parse_env_id(id: str) -> EnvId:
    """``"pneumatic_env/ForceTrack-Numatics-2m-v0"`` -> ``EnvId("ForceTrack", "Numatics",
    "2")``; the inverse of :func:`env_id` (the namespace may be left out)."""
    text = str(id)
    name = text[len(ENV_NAMESPACE) + 1 :] if text.startswith(ENV_NAMESPACE + "/") else text
    suffix = f"-v{ENV_VERSION}"
    task, _, variant = name.removesuffix(suffix).partition("-")
    if not name.endswith(suffix) or task not in TASK_IDS or variant not in _variants():
        raise ValueError(
            f"env id = {id!r} is not allowed: use {ENV_NAMESPACE}/"
            f"{{task}}-{{cylinder}}-{{tube}}m-v{ENV_VERSION} with task in "
            f"{list(TASK_IDS)}, cylinder-tube in {_variants()}"
        )
    return EnvId(task, *split_variant(variant))


def registered_ids() -> list[str]:
    """Every environment id this package registers (task x cylinder x tube)."""
    return [EnvId(t, c, L).id for t in TASK_IDS for c in CYLINDER_IDS for L in TUBE_LENGTHS_M]
