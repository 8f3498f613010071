"""Tracking tasks and the batched episode logic shared by the single and the vector env.

A ``TaskSpec`` says what is tracked (force with the rod clamped, or position with the
rod free), the default reference and how the reward scales the error. ``TaskCore`` runs
``n_envs`` episodes of one task on a ``BatchSimulator``: references, domain
randomisation, sensor model, observations and rewards, all as arrays. The single env is a
``TaskCore`` of one environment, so single and vector envs share every line of task code.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import gymnasium as gym
import numpy as np

import pneumatic_env.ids as ids
import pneumatic_env.params as P

from ..physics import layout as L
from ..physics.derived import force_scale_n
from ..references import ArrayReference, ReferenceSpec, make_reference
from ..simulator import BatchSimulator
from . import task_kernel
from .features import FeatureConfig, FeatureState
from .observation import OBSERVED_CHANNELS, fill_observation, observation_dim, observation_scales
from .randomization import check_randomization

REFERENCE_BLOCK_ENVS = 256  # episodes whose references an autoreset generates together
_CHANNEL_OUTPUT = {"p1": L.O_P1, "p2": L.O_P2, "x": L.O_X, "f": L.O_F}


@dataclass(frozen=True)
class TaskSpec:
    """What a task tracks and how it scores it."""

    name: str
    piston_mode: str  # a key of ids.PISTON_MODE_CODES: "fixed" or "free"
    tracked: str  # "f" or "x"
    reference: dict  # default reference spec, in units of `reference_scale` (see scale_of)
    # rod modes a parameter file (e.g. a fitted rig) or a keyword may bring instead
    rod_modes: tuple = ()
    description: str = ""
    extra_defaults: dict = field(default_factory=dict)


FORCE_TRACK = TaskSpec(
    name=ids.FORCE_TRACK,
    piston_mode="fixed",
    tracked="f",
    # a fitted compliant load cell (identification's load_cell_compliance) is the spring mode
    rod_modes=("fixed", "spring"),
    reference={
        "kind": "mixture",
        "choices": [
            {"kind": "random_step", "amplitude": 0.6, "hold_min_s": 0.1, "hold_max_s": 0.5},
            {
                "kind": "multisine",
                "amplitude": 0.5,
                "frequencies_hz": [0.5, 2.0, 5.0],
                "offset": 0.1,
            },
            {
                "kind": "multisine",
                "amplitude": 0.5,
                "frequencies_hz": [1.0, 3.0, 7.0, 12.0],
                "offset": 0.1,
            },
        ],
    },
    description="rod clamped to a load cell at mid-stroke; track a force reference (N)",
    extra_defaults={"fixed_position_m": 0.0},
)
POSITION_TRACK = TaskSpec(
    name=ids.POSITION_TRACK,
    piston_mode="free",
    tracked="x",
    rod_modes=("free",),
    reference={
        "kind": "mixture",
        "choices": [
            {"kind": "random_step", "amplitude": 0.6, "hold_min_s": 0.2, "hold_max_s": 0.6},
            {"kind": "multisine", "amplitude": 0.6, "frequencies_hz": [0.5, 1.0, 2.0]},
            {"kind": "multisine", "amplitude": 0.4, "frequencies_hz": [1.0, 3.0, 5.0]},
        ],
    },
    description="rod free, no load; track a piston position reference (m)",
)
TASKS = {t.name: t for t in (FORCE_TRACK, POSITION_TRACK)}
assert tuple(TASKS) == ids.TASK_IDS  # the registered task names


def scale_of(task: TaskSpec, param: dict) -> float:
    """The task's natural unit: a force a cylinder can hold both ways (N), or the half stroke (m).

    Reference specs of the registered tasks are written in this unit, so one spec fits both
    cylinders; the reward divides the error by it.
    """
    if task.tracked == "x":
        return 0.5 * param["stroke_m"]
    return force_scale(param)


def force_scale(param: dict) -> float:
    """The force the cylinder can hold in both directions, (P_s - P_a) min(A1, A2) (N)."""
    return float(
        force_scale_n(
            param["supply_pressure_pa"],
            param["ambient_pressure_pa"],
            param["bore_diameter_m"],
            param["rod_diameter_m"],
        )
    )


def scale_spec(spec: dict, scale: float) -> dict:
    """Multiply a reference spec's amplitude/offset/values by ``scale`` (recursively)."""
    out = dict(spec)
    for key in ("amplitude", "offset"):
        if key in out:
            out[key] = out[key] * scale
    if "values" in out:
        out["values"] = np.asarray(out["values"], dtype=float) * scale
    if "choices" in out:
        out["choices"] = [scale_spec(c, scale) for c in out["choices"]]
    return out


@dataclass
class EnvOptions:
    """Options of a tracking env beyond the physical parameters (all keyword arguments)."""

    reference_steps: int = ids.EPISODE_STEPS  # reference length; held at its end
    preview_steps: int = ids.ENV_PREVIEW_STEPS
    reference: dict | ReferenceSpec | None = None  # in the tracked channel's SI unit
    normalize_observation: bool = False
    effort_weight: float = 0.0
    chatter_weight: float = 0.0
    domain_randomization: dict | None = None
    # parameters of the simulated plant that differ from the model the task, the
    # observation scales and base_params are built from (model mismatch)
    plant: dict | None = None
    sensor_noise: dict | None = None  # channel -> standard deviation (SI)
    sensor_lag_s: float = 0.0
    control_dt_s: float | None = None
    substeps: int | None = None
    # observation features after the base layout (envs.features; off by default)
    action_history: int = 0
    measurement_history: int = 0
    tracking_error: bool = False
    error_integral_tau_s: float = 0.2
    error_integral_leaky: bool = True
    relative_preview: bool = False

    def validate(self) -> None:
        def bad(name, value, allowed):
            raise ValueError(f"{name} = {value!r} is not allowed: {allowed}")

        if int(self.reference_steps) != self.reference_steps or self.reference_steps < 1:
            bad("reference_steps", self.reference_steps, "must be an integer >= 1")
        if int(self.preview_steps) != self.preview_steps or self.preview_steps < 0:
            bad("preview_steps", self.preview_steps, "must be an integer >= 0")
        for name in ("effort_weight", "chatter_weight", "sensor_lag_s"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= 0):
                bad(name, value, "must be a finite number >= 0")
        for channel, std in (self.sensor_noise or {}).items():
            if channel not in OBSERVED_CHANNELS:
                bad("sensor_noise key", channel, f"must be one of {list(OBSERVED_CHANNELS)}")
            if not (np.isfinite(std) and std >= 0):
                bad(f"sensor_noise['{channel}']", std, "must be a finite number >= 0")
        FeatureConfig.from_options(self).validate()


def _rod_mode(task: TaskSpec, cylinder: str, params, overrides: dict) -> str:
    """The rod mode of a task's environments: ``piston_mode`` from the keyword arguments or
    the parameter file if it is one of ``task.rod_modes``, else the task's own.

    A keyword outside ``rod_modes`` is an error; a parameter file's mode outside it (a rig
    fitted with the rod free, used for force tracking) gives way to the task's with a
    warning, never silently.
    """
    names = ids.PISTON_MODE_NAMES
    if "piston_mode" in overrides:
        value = overrides["piston_mode"]
        mode = names.get(value, value) if not isinstance(value, str) else value
        if mode not in task.rod_modes:
            raise ValueError(
                f"piston_mode = {value!r} is not allowed for {task.name}: "
                f"allowed {list(task.rod_modes)}"
            )
        return mode
    if params is None:
        return task.piston_mode
    data = params if isinstance(params, Mapping) else P.read_yaml(Path(params).expanduser())
    if not isinstance(data, Mapping) or "piston_mode" not in data:
        return task.piston_mode  # the file says nothing of the rod (load_parameters checks it)
    mode = names[int(P.load_parameters(cylinder, params=params)["piston_mode"])]
    if mode in task.rod_modes:
        return mode
    gym.logger.warn(
        f"the parameter file's piston_mode '{mode}' does not fit {task.name} "
        f"(allowed {list(task.rod_modes)}); using '{task.piston_mode}'"
    )
    return task.piston_mode


class TaskCore:
    """``n_envs`` episodes of one tracking task, advanced together."""

    def __init__(
        self,
        task: TaskSpec,
        n_envs: int,
        cylinder: str,
        tube_length_m: float | None,
        params=None,
        options: EnvOptions | None = None,
        **overrides,
    ):
        self.task = task
        self.options = options or EnvOptions()
        self.options.validate()
        numerics = P.load_numerics()
        control_dt = self.options.control_dt_s or numerics["control_dt_s"]
        substeps = self.options.substeps or numerics["substeps"]
        overrides = {**task.extra_defaults, **overrides}
        base = P.load_parameters(
            cylinder,
            tube_length_m=tube_length_m,
            params=params,
            piston_mode=_rod_mode(task, cylinder, params, overrides),
            **{k: v for k, v in overrides.items() if k != "piston_mode"},
        )
        self.base_params = base
        self.cylinder = cylinder
        self.plant_params = self._plant(self.options.plant, cylinder, base)
        self._randomization = check_randomization(
            self.options.domain_randomization, self.plant_params, cylinder
        )
        self.n_envs = n_envs
        self.sim = BatchSimulator(
            P.parameter_array([self.plant_params] * n_envs), control_dt, substeps
        )
        self.dt = control_dt
        self.scale = scale_of(task, base)
        self.force_scale = force_scale(base)
        self.reference_spec = make_reference(
            self.options.reference
            if self.options.reference is not None
            else scale_spec(task.reference, self.scale)
        )
        self.i_max = base["coil_current_max_a"]
        self.pa, self.ps = base["ambient_pressure_pa"], base["supply_pressure_pa"]
        self.half_stroke = 0.5 * base["stroke_m"]
        self._init_episode_arrays(n_envs, control_dt)
        self._init_observation(task, n_envs, control_dt, base)
        self._init_step_arguments()

    def _init_episode_arrays(self, n_envs: int, control_dt: float) -> None:
        """The per-env arrays of the episodes (references, counters, measurements, the
        last step's outputs) and the sensor model's noise and lag."""
        # Generated per episode for `reference_steps` (not the episode length, which a single
        # env under gym.make cannot see), so single and vector envs draw alike.
        self.references = np.zeros(
            (n_envs, self.options.reference_steps + self.options.preview_steps + 1)
        )
        self.step_count = np.zeros(n_envs, dtype=np.int64)
        self.prev_action = np.zeros(n_envs)
        self.measured = np.zeros((n_envs, len(OBSERVED_CHANNELS)))
        self._noise_std = np.array(
            [(self.options.sensor_noise or {}).get(c, 0.0) for c in OBSERVED_CHANNELS]
        )
        self._noise_on = bool(np.any(self._noise_std > 0))
        self._noise = np.zeros((n_envs, len(OBSERVED_CHANNELS)))
        self.last_reward, self.last_error = np.zeros(n_envs), np.zeros(n_envs)
        self.last_reference, self.last_applied = np.zeros(n_envs), np.zeros(n_envs)
        self._last_action = np.zeros(n_envs)
        self._lag = (
            np.exp(-control_dt / self.options.sensor_lag_s)
            if self.options.sensor_lag_s > 0
            else 0.0
        )

    def _init_observation(self, task: TaskSpec, n_envs: int, control_dt: float, base) -> None:
        """The observation's channel rows, scales and optional features."""
        self._out_rows = np.array([_CHANNEL_OUTPUT[c] for c in OBSERVED_CHANNELS])
        self._tracked_row = _CHANNEL_OUTPUT[task.tracked]
        self.base_obs_dim = observation_dim(self.options.preview_steps)
        self.observation_scales = observation_scales(
            base, self.force_scale, self.scale, self.options.normalize_observation
        )
        self.feature_config = FeatureConfig.from_options(self.options)
        self.features = (
            FeatureState(
                self.feature_config,
                n_envs,
                self.options.preview_steps,
                self.observation_scales,
                control_dt,
                task.tracked,
            )
            if self.feature_config.enabled
            else None
        )
        self.obs_dim = self.base_obs_dim + (self.features.dim if self.features else 0)
        self._si_scales = self.observation_scales._replace(normalize=False)

    def _init_step_arguments(self) -> None:
        """The task step's fixed arguments and outputs, views of the arrays above."""
        self._task_params = task_kernel.TaskParams(
            float(self.i_max),
            float(self.options.effort_weight),
            float(self.options.chatter_weight),
            float(self._lag),
            self._out_rows,
            int(self._tracked_row),
        )
        # the arrays above, updated in place by the task step
        self._task_state = task_kernel.TaskState(
            self.references, self.step_count, self.prev_action, self.measured
        )
        # the fixed arguments of the task step, as the plain tuples it takes
        self._step_fixed = (
            tuple(self._task_params),
            tuple(self.observation_scales),
            tuple(self._task_state),
        )
        self._step_outputs = tuple(
            task_kernel.StepOutputs(
                self.last_reward, self.last_error, self.last_reference, self.last_applied, None
            )
        )

    # -- parameters ----------------------------------------------------------------------
    @staticmethod
    def _plant(spec, cylinder: str, base: dict) -> dict:
        """``base`` with the ``plant`` option's parameters (``{name: value}``) replaced."""
        if spec is None:
            return base
        if not isinstance(spec, Mapping):
            raise ValueError(
                f"plant = {spec!r} is not allowed: must be None or a dict {{parameter: value}}"
            )
        return P.load_parameters(cylinder, params=base, **spec)

    # -- episodes ------------------------------------------------------------------------
    def episode_reference(self, value, field: str = "reference") -> ReferenceSpec:
        """A reference for one episode: a spec (``ReferenceSpec`` or dict, in the tracked
        channel's SI unit) or samples one control period apart from step 0 (held at the
        end). ``field`` names the value in errors."""
        if isinstance(value, (ReferenceSpec, Mapping)):
            try:
                return make_reference(value)
            except (TypeError, ValueError) as exc:
                raise ValueError(f"{field} = {value!r} is not allowed: {exc}") from None
        try:
            values = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError):
            values = None
        if (
            values is None
            or values.ndim != 1
            or values.size == 0
            or not np.all(np.isfinite(values))
        ):
            raise ValueError(
                f"{field} = {value!r} is not allowed: must be a reference spec "
                "(a ReferenceSpec or a dict with a 'kind') or a non-empty 1-D "
                "array of finite samples, one per control period"
            )
        return ArrayReference(values, self.dt)

    def reset_envs(
        self,
        envs: np.ndarray,
        rngs: list,
        references: list[ReferenceSpec | None] | None = None,
        start_steps: np.ndarray | None = None,
    ) -> None:
        """Start new episodes in ``envs``; ``rngs[i]`` is env i's own generator.

        ``references[j]`` (if given and not None) is the reference of env ``envs[j]``'s new
        episode instead of ``reference_spec``, drawn from the same generator at the same
        point, so the episode is the one of an env made with that ``reference``.
        ``start_steps[j]`` (default 0): the step count env ``envs[j]`` starts at (its
        reference is read from that sample on).
        """
        n_ref = self.references.shape[1]
        if self._randomization:
            columns = []
            for env in envs:
                drawn = self._randomization.draw(rngs[env])
                columns.append(P.load_parameters(self.cylinder, params=self.plant_params, **drawn))
            self.sim.set_params(envs, P.parameter_array(columns))
        self.sim.reset(envs)
        own = envs
        if references is not None:
            given = np.array([spec is not None for spec in references], dtype=bool)
            for env, spec in zip(envs[given], (s for s in references if s is not None)):
                self.references[env] = spec.generate(n_ref, self.dt, rngs[env])
            own = envs[~given]
        for first in range(0, len(own), REFERENCE_BLOCK_ENVS):  # temporaries stay in cache
            block = own[first : first + REFERENCE_BLOCK_ENVS]
            self.references[block] = self.reference_spec.generate_rows(
                n_ref, self.dt, [rngs[env] for env in block]
            )
        self.step_count[envs] = 0 if start_steps is None else start_steps
        self.prev_action[envs] = 0.0
        self.measured[envs] = self.sim.outputs[self._out_rows][:, envs].T
        self._add_noise(envs, rngs)
        if self.features is not None:
            self.features.reset(envs, self._base_observation(self._si_scales)[envs])

    def _draw_noise(self, envs, rngs) -> np.ndarray:
        """Sensor noise for ``envs``, drawn from each env's own generator (zeros when off)."""
        self._noise[:] = 0.0
        if self._noise_on:
            for env in envs:
                self._noise[env] = self._noise_std * rngs[env].standard_normal(
                    len(OBSERVED_CHANNELS)
                )
        return self._noise

    def _add_noise(self, envs, rngs):
        if self._noise_on:
            self.measured[envs] += self._draw_noise(envs, rngs)[envs]

    def check_action(self, action) -> np.ndarray:
        """Coil currents as float64 (n_envs,); clear errors for NaN, inf and wrong shapes."""
        a = np.asarray(action, dtype=np.float64)
        if a.size != self.n_envs or a.ndim > 2:
            raise ValueError(
                f"action has shape {a.shape}, expected ({self.n_envs}, 1) or "
                f"({self.n_envs},): one coil current (A) per environment"
            )
        a = a.reshape(self.n_envs)
        if not np.isfinite(a).all():
            raise ValueError(
                f"action contains {a[~np.isfinite(a)][0]}: the coil current must be "
                f"finite, in [-{self.i_max}, {self.i_max}] A"
            )
        return a

    def step(self, coil_current_a: np.ndarray, rngs: list) -> tuple[np.ndarray, np.ndarray]:
        """Advance all envs one control period (one jitted call); returns the observation
        (as ``observation()``) and the reward.

        Per-env details are left in ``self.last_*`` arrays: tracking error, reference,
        applied (clipped) current.
        """
        sim = self.sim
        self._last_action = coil_current_a
        noise = self._draw_noise(range(self.n_envs), rngs) if self._noise_on else self._noise
        obs = np.empty((self.n_envs, self.base_obs_dim), dtype=np.float32)
        out = self._step_outputs[:-1] + (obs,)  # StepOutputs with this step's obs
        sim.call_step_kernel(
            task_kernel.task_step_serial,
            task_kernel.task_step_parallel,
            (tuple(sim.arrays), *self._step_fixed, coil_current_a, noise, out),
        )
        sim.advance_clock()
        if self.features is not None:
            si = (
                self._base_observation(self._si_scales)
                if self.options.normalize_observation
                else obs
            )
            self.features.update(si, self.last_applied)
            obs = np.concatenate([obs, self.features.values], axis=1)
        return obs, self.last_reward

    def info(self, env: int | None = None) -> dict:
        """The step's info: arrays over envs, or floats for one ``env``."""
        o = self.sim.outputs
        if env is None:
            return {
                "tracking_error": self.last_error.copy(),
                "reference": self.last_reference.copy(),
                "coil_current_a": self.last_applied.copy(),
                "action_clipped": self.last_applied != self._last_action,
                "exhaust_mass_kg": o[L.O_EXHAUST].copy(),
            }
        return {
            "tracking_error": float(self.last_error[env]),
            "reference": float(self.last_reference[env]),
            "coil_current_a": float(self.last_applied[env]),
            "action_clipped": bool(self.last_applied[env] != self._last_action[env]),
            "exhaust_mass_kg": float(o[L.O_EXHAUST, env]),
        }

    def observation(self) -> np.ndarray:
        """[p1, p2, x, f, ref(k), ref(k+1..k+H)] per env, float32 (SI or normalised), then
        the features of the last step or reset (``envs.features``) when any is on."""
        obs = self._base_observation(self.observation_scales)
        if self.features is not None:
            obs = np.concatenate([obs, self.features.values], axis=1)
        return obs

    def _base_observation(self, scales) -> np.ndarray:
        obs = np.empty((self.n_envs, self.base_obs_dim), dtype=np.float32)
        fill_observation(self.measured, self.references, self.step_count, scales, obs)
        return obs

    def observation_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        # Unbounded: sensor noise can put a measured channel anywhere.
        return (
            np.full(self.obs_dim, -np.inf, np.float32),
            np.full(self.obs_dim, np.inf, np.float32),
        )
