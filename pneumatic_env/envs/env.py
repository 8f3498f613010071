"""Gymnasium environments: ``PneumaticTrackingEnv`` (single) and ``PneumaticTrackingVectorEnv``.

Both are thin shells over ``TaskCore``; their docstrings state the spaces, the reward, the
options and the episode end.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from types import MappingProxyType
from typing import TYPE_CHECKING, Any, SupportsFloat

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space
from numpy.typing import NDArray

import pneumatic_env.ids as ids

from ..references import ReferenceSpec
from .features import observation_columns
from .observation import ObservationScales
from .tasks import TASKS, EnvOptions, TaskCore, TaskSpec

if TYPE_CHECKING:
    from .render import Trace

__all__ = [
    "PneumaticTrackingEnv",
    "PneumaticTrackingVectorEnv",
    "RESET_OPTIONS",
    "VECTOR_RESET_OPTIONS",
]

_OPTION_NAMES = set(EnvOptions.__dataclass_fields__)
#: Keys ``reset(options=...)`` accepts.
RESET_OPTIONS = ("reference",)
#: Keys the vector env's ``reset(options=...)`` accepts.
VECTOR_RESET_OPTIONS = ("reference", "start_step")


def _split_kwargs(kwargs: dict) -> tuple[EnvOptions, dict]:
    options = EnvOptions(**{k: v for k, v in kwargs.items() if k in _OPTION_NAMES})
    return options, {k: v for k, v in kwargs.items() if k not in _OPTION_NAMES}


def _check_render_mode(render_mode) -> None:
    if render_mode not in (None, "rgb_array"):
        raise ValueError(f"render_mode = {render_mode!r} is not allowed: use 'rgb_array' or None")


def _task(name: str) -> TaskSpec:
    if name not in TASKS:
        raise ValueError(f"task = {name!r} is not known: allowed {sorted(TASKS)}")
    return TASKS[name]


def _start_steps(options, n_envs: int, limit: int) -> np.ndarray | None:
    """``options["start_step"]``: one int for every env or ``n_envs`` ints in [0, limit)."""
    value = None if options is None else options.get("start_step")
    if value is None:
        return None
    steps = (
        np.broadcast_to(np.asarray(value), (n_envs,)) if np.ndim(value) == 0 else np.asarray(value)
    )
    ok = (
        steps.shape == (n_envs,)
        and steps.dtype.kind in "iu"
        and bool(np.all((steps >= 0) & (steps < limit)))
    )
    if not ok:
        raise ValueError(
            f"options['start_step'] = {value!r} is not allowed: must be an integer "
            f"or a list of num_envs = {n_envs} integers in [0, "
            f"max_episode_steps = {limit})"
        )
    return steps.astype(np.int64)


def _reset_references(
    core: TaskCore, options, n_envs: int | None
) -> list[ReferenceSpec | None] | None:
    """The per-env references of ``reset(options=...)`` (None: every env's own spec).

    ``n_envs`` None: the single env (one reference); else the vector env's rules.
    """
    if options is None:
        return None
    allowed = list(RESET_OPTIONS if n_envs is None else VECTOR_RESET_OPTIONS)
    if not isinstance(options, Mapping):
        raise ValueError(
            f"options = {options!r} is not allowed: must be None or a dict with keys from {allowed}"
        )
    for key in options:
        if key not in allowed:
            raise ValueError(f"options key = {key!r} is not allowed: must be one of {allowed}")
    value = options.get("reference")
    if value is None:
        return None
    field = "options['reference']"
    if n_envs is None or isinstance(value, (ReferenceSpec, Mapping)):
        spec = core.episode_reference(value, field)
        return [spec] * (n_envs or 1)
    rows: Sequence[Any] | np.ndarray | None = None
    if isinstance(value, np.ndarray):
        rows = value if value.ndim == 2 else None
    elif isinstance(value, Sequence) and not isinstance(value, str):
        rows = value
    if rows is None or len(rows) != n_envs:
        given = (
            f"shape {value.shape}"
            if isinstance(value, np.ndarray)
            else f"{len(rows)} entries"
            if rows is not None
            else type(value).__name__
        )
        raise ValueError(
            f"{field} ({given}) is not allowed: must be one reference spec "
            f"for all envs, a list of num_envs = {n_envs} entries (a spec, a 1-D "
            f"sample array or None for the env's own) or a 2-D array "
            f"({n_envs}, n_samples)"
        )
    return [
        None if row is None else core.episode_reference(row, f"{field}[{i}]")
        for i, row in enumerate(rows)
    ]


class _TaskProperties:
    """Read-only views of the task an env runs (shared by the single and the vector env)."""

    core: TaskCore

    @property
    def task(self) -> TaskSpec:
        """The task (what is tracked, the default reference, the rod modes)."""
        return self.core.task

    @property
    def base_params(self) -> Mapping[str, float]:
        """The model parameters (``load_parameters`` names, SI units), read-only: what a
        controller may know (the ``plant`` option and ``domain_randomization`` change the
        simulated plant, not these)."""
        return MappingProxyType(self.core.base_params)

    @property
    def control_dt_s(self) -> float:
        """The control period (s): one ``step``."""
        return float(self.core.dt)

    @property
    def coil_current_max_a(self) -> float:
        """The action bound (A)."""
        return float(self.core.i_max)

    @property
    def force_scale_n(self) -> float:
        """(P_s - P_a) min(A1, A2) (N): divides the force when normalised."""
        return float(self.core.force_scale)

    @property
    def reference_scale(self) -> float:
        """The tracked channel's unit: the force scale (N) or the half stroke (m); divides
        the error in the reward and the reference when normalised."""
        return float(self.core.scale)

    @property
    def preview_steps(self) -> int:
        """Reference samples ahead in the observation."""
        return int(self.core.options.preview_steps)

    @property
    def normalize_observation(self) -> bool:
        return bool(self.core.options.normalize_observation)

    @property
    def observation_columns(self) -> list[str]:
        """The name of each observation entry: the base layout, then the features
        (``envs.features.observation_columns``)."""
        core = self.core
        return observation_columns(
            core.options.preview_steps, core.feature_config if core.features else None
        )

    @property
    def observation_scales(self) -> ObservationScales:
        """What ``normalize_observation`` divides by (``envs.observation``)."""
        return self.core.observation_scales

    @property
    def reference_spec(self) -> ReferenceSpec:
        """The env's own reference spec (SI), used unless ``reset`` is given one."""
        return self.core.reference_spec


def _read_only(array: np.ndarray) -> np.ndarray:
    view = array.view()
    view.flags.writeable = False
    return view


class PneumaticTrackingEnv(_TaskProperties, gym.Env[NDArray[np.float32], NDArray[np.float32]]):
    """A pneumatic cylinder driven by a proportional valve tracks a force or a position.

    ## Description

    The actuator of Richer & Hurmuzlu (2000), Part I: a 4-way proportional spool valve
    (Eqs. 38-46) feeds the two chambers of a double-acting cylinder (Eq. 14) through tubes
    with delay and attenuation (Eqs. 30-35); the piston (Eq. 1, stick-slip friction, end
    stops) is clamped to a load cell (``ForceTrack``: track a force) or free
    (``PositionTrack``: track a piston position). Each control period (1 ms) the agent sets
    the coil current, held while the model advances by RK4 substeps. The registered ids are
    ``pneumatic_env/{task}-{cylinder}-{tube}m-v0`` (``pneumatic_env.registered_ids()``),
    e.g. ``pneumatic_env/ForceTrack-Numatics-2m-v0``: cylinders Numatics (0750D02-03A) and
    Airpel (E16D3.0N), tubes 0.5, 1, 2 and 3 m long.

    ## Action Space

    ``Box(-i_max, i_max, (1,), float32)``: the valve's coil current (A), ``i_max =
    coil_current_max_a`` (2 A for both cylinders). Values outside are clipped and
    ``info["action_clipped"]`` says so; NaN, inf or a wrong shape raise ``ValueError``.

    ## Observation Space

    ``Box(-inf, inf, (5 + preview_steps,), float32)``, unbounded (sensor noise may put a
    channel anywhere). With ``normalize_observation=True`` each entry is mapped as in the
    last column (``observation_scales``, module ``pneumatic_env.envs.observation``):

    | index | observation                        | unit  | normalised              |
    |-------|------------------------------------|-------|-------------------------|
    | 0     | p1, cap-end chamber (absolute)     | Pa    | (p1 - P_a) / (P_s - P_a)|
    | 1     | p2, rod-end chamber (absolute)     | Pa    | (p2 - P_a) / (P_s - P_a)|
    | 2     | x, piston position (0 mid-stroke)  | m     | x / (L/2)               |
    | 3     | f, load-cell force                 | N     | f / force_scale_n       |
    | 4     | ref(k), the reference now          | N, m  | ref / reference_scale   |
    | 5..   | ref(k+1) .. ref(k+H), the preview  | N, m  | ref / reference_scale   |

    p1, p2, x and f are measured (``sensor_noise``, ``sensor_lag_s``). The reference is the
    tracked channel's: a force (N) for ``ForceTrack``, a position (m) for
    ``PositionTrack``; ``H = preview_steps``. ``force_scale_n = (P_s - P_a) min(A1, A2)``
    is the force the cylinder holds both ways (about 139 N for the Numatics);
    ``reference_scale`` is that force (ForceTrack) or the half stroke L/2 (PositionTrack).

    Features for a delayed plant (all off by default; module ``pneumatic_env.envs.features``,
    which names every column) follow the table, in this order, always dimensionless:
    ``action_history = K``: the last K applied currents (A); ``measurement_history = M``:
    ``10 (c_n(k) - c_n(k-j))``, j = 1..M, for p1, p2, x, f normalised as in the table;
    ``tracking_error``: ``e_n = y_n - r_n(k)`` (``y`` the tracked channel, ``_n``: divided
    by ``reference_scale``) and 10 x its integral ``I += dt/tau (e_n - I)`` (leaky, tau =
    ``error_integral_tau_s``, 0.2 s) or ``I += dt/tau e_n`` (``error_integral_leaky=False``);
    ``relative_preview``: ``r_n(k+j) - y_n(k)``, j = 0..H. The shape grows by
    ``K + 4 M + 2 + H + 1`` for all of them.

    ## Rewards

    ``r = -min(|e| / reference_scale, 1) - effort_weight (i / i_max)^2
    - chatter_weight ((i - i_prev) / (2 i_max))^2``, with ``e`` the tracked output (true
    force or position, not the measured one) minus the reference after the step and ``i``
    the applied (clipped) current; ``r`` lies in ``[-1 - effort_weight - chatter_weight,
    0]``. ``info`` holds ``tracking_error`` (``e``), ``reference``, ``coil_current_a``
    (``i``), ``action_clipped`` and ``exhaust_mass_kg`` (air let out since reset).

    ## Starting State

    Both chambers at ambient pressure, spool centred, piston at rest (at the clamp
    position ``fixed_position_m`` = 0, mid-stroke, when clamped); the tube delay lines
    hold that state. Drawn per episode from the env's seeded generator, in this order: the
    ``domain_randomization`` values, the reference (by default the task's random mixture
    of steps and multisines), the first sensor noise.

    ## Episode End

    ``terminated`` is always False: tracking has no failure state. Episodes are truncated
    after ``max_episode_steps`` (registered: 2000 steps, 2 s) by Gymnasium's ``TimeLimit``.

    ## Arguments

    Keyword arguments of ``gym.make(id, ...)``, checked on construction; a bad value raises
    an error naming the field, the value and what is allowed:

    * ``task`` (``"ForceTrack"`` or ``"PositionTrack"``), ``cylinder`` (name, alias or
      config id) and ``tube_length_m`` (m): set by the registered id.
    * ``params``: a parameter YAML file (written by ``identify`` or
      ``params.save_parameters``) or mapping. Any physical parameter by its name in
      ``configs/``, in SI units (``supply_pressure_pa=5e5``; ``piston_mode`` among the
      task's rod modes; ``fixed_position_m``, the clamp position, 0 m).
    * ``max_episode_steps`` (control steps; registered: 2000, ``ids.EPISODE_STEPS``).
    * ``reference_steps`` (control steps, 2000): length of the generated reference, held at
      its last value.
    * ``preview_steps`` (control steps, 10, ``ids.ENV_PREVIEW_STEPS``): reference samples
      ahead, H.
    * ``reference``: every episode's reference spec, in the tracked channel's SI unit
      (``{"kind": "sine", "amplitude": 40, "frequency_hz": 10}``; kinds step, sine, chirp,
      multisine, random_step, array, mixture: ``pneumatic_env.references``).
    * ``normalize_observation`` (False): the last column of the table above.
    * ``effort_weight`` and ``chatter_weight`` (dimensionless, 0): the reward's weights.
    * ``action_history`` (K, 0), ``measurement_history`` (M, 0), ``tracking_error``
      (False), ``error_integral_tau_s`` (tau, s, 0.2), ``error_integral_leaky`` (True),
      ``relative_preview`` (False): the observation features above.
    * ``domain_randomization``: ``{name: (low, high)}`` in the parameter's SI unit or
      ``{name: relative_half_width}`` (a fraction in [0, 1)), uniform per episode (around
      the plant's values); ``"one_of": [{"probability": p, "ranges": {...}}, ...]`` adds
      alternatives, one drawn per episode (a switch such as ``tube_waves`` on in a share of
      the episodes; ``envs.randomization``).
    * ``plant``: ``{name: value}`` (SI), a model mismatch: the simulated plant takes these
      parameters while the task, the reference scale, the observation scales and
      ``base_params`` (what a controller may know) keep the model's; for robustness
      studies (``agents/robustness.py``).
    * ``sensor_noise``: ``{channel: std}`` for p1, p2 (Pa), x (m), f (N), Gaussian per
      step; ``sensor_lag_s`` (s, 0): the time constant of a first-order sensor lag.
    * ``control_dt_s`` (s) and ``substeps``: the control period and RK4 substeps per
      period (default 1 ms and 5, configs/numerics.yaml).
    * ``render_mode``: ``"rgb_array"`` or None.

    ``reset(seed=None, options=None)`` accepts ``options={"reference": r}``: this episode's
    reference, either a spec (``ReferenceSpec`` or dict, in the tracked channel's SI unit)
    drawn from the env's generator where the default would be (the episode is that of
    ``gym.make(id, reference=r)`` with the same seed), or a 1-D array of samples one control
    period apart from step 0, held at its end. It applies to that episode only; a later
    ``reset`` without it uses the env's own reference. Other keys are refused.

    ## Version History

    * v0: the initial version.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 50}

    def __init__(
        self,
        task: str = ids.FORCE_TRACK,
        cylinder: str = ids.DEFAULT_CYLINDER,
        tube_length_m: float | None = None,
        params=None,
        render_mode: str | None = None,
        **kwargs,
    ):
        options, overrides = _split_kwargs(kwargs)
        _check_render_mode(render_mode)
        self.core = TaskCore(_task(task), 1, cylinder, tube_length_m, params, options, **overrides)
        self.render_mode = render_mode
        i_max = np.float32(self.core.i_max)
        self.action_space = gym.spaces.Box(-i_max, i_max, shape=(1,), dtype=np.float32)
        low, high = self.core.observation_bounds()
        self.observation_space = gym.spaces.Box(low, high, dtype=np.float32)
        self.metadata = {**self.metadata, "render_fps": int(round(1 / self.core.dt / 20))}
        self._trace: Trace | None = None

    @property
    def references(self) -> np.ndarray:
        """This episode's reference samples (read-only view, length ``reference_steps +
        preview_steps + 1``); ``info["reference"]`` of step k is sample k."""
        return _read_only(self.core.references[0])

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[NDArray[np.float32], dict[str, Any]]:
        references = _reset_references(self.core, options, None)
        super().reset(seed=seed)
        self._rngs = [self.np_random]
        self.core.reset_envs(np.array([0]), self._rngs, references)
        if self.render_mode is not None:
            from .render import Trace

            self._trace = Trace()
            self._trace.record(self.core, 0)
        return self.core.observation()[0], {}

    def step(
        self, action: NDArray[np.float32]
    ) -> tuple[NDArray[np.float32], SupportsFloat, bool, bool, dict[str, Any]]:
        current = self.core.check_action(action)
        obs, reward = self.core.step(current, self._rngs)
        if self._trace is not None:
            self._trace.record(self.core, 0)
        return obs[0], float(reward[0]), False, False, self.core.info(0)

    def render(self):
        if self.render_mode is None:
            gym.logger.warn("render() called without render_mode='rgb_array'")
            return None
        from .render import render_rgb

        return render_rgb(self.core, 0, self._trace)


class PneumaticTrackingVectorEnv(
    _TaskProperties, VectorEnv[NDArray[np.float32], NDArray[np.float32], NDArray[Any]]
):
    """``num_envs`` :class:`PneumaticTrackingEnv` advanced in one jitted call per step
    (``gym.make_vec(id, num_envs=n)``).

    ## Description

    A batch of the single env's actuators and task: env ``i`` seeded with ``seed + i`` (or
    ``seed[i]``) reproduces the single env seeded alike, bit for bit. Batches of
    ``simulator.PARALLEL_MIN_ENVS`` envs or more run on Numba's threads.

    ## Action Space

    ``Box(-i_max, i_max, (num_envs, 1), float32)``: one coil current (A) per env, as the
    single env's (``single_action_space``).

    ## Observation Space

    ``Box(-inf, inf, (num_envs, 5 + preview_steps), float32)``: one row per env, laid out
    and normalised as the single env's (its table and features; ``single_observation_space``).

    ## Rewards

    The single env's, per env: arrays of shape ``(num_envs,)``; ``info`` is a dict of such
    arrays (``tracking_error``, ``reference``, ``coil_current_a``, ``action_clipped``,
    ``exhaust_mass_kg``).

    ## Starting State

    The single env's, per env, from env i's own generator.

    ## Episode End

    ``terminated`` is always False. Episodes are truncated after ``max_episode_steps``
    (default 2000) inside the env and reset in the same step
    (``AutoresetMode.SAME_STEP``): the returned observation is the new episode's first, the
    last one is in ``info["final_obs"]`` (``info["_final_obs"]`` marks the envs).

    ## Arguments

    ``num_envs`` (1), ``max_episode_steps`` (2000) and every keyword argument of
    :class:`PneumaticTrackingEnv` (``render_mode`` draws env 0).

    ``reset(seed=None, options=None)``: ``seed`` an int (env i gets ``seed + i``) or a list
    of ``num_envs`` ints. ``options={"reference": r}`` sets this episode's references: one
    spec (``ReferenceSpec`` or dict, SI) for every env, a list of ``num_envs`` entries (a
    spec, a 1-D sample array or None for the env's own), or a 2-D array ``(num_envs,
    n_samples)``; each as in the single env. It applies to that episode only: autoresets
    use the env's own reference. ``options={"start_step": s}`` (an int, or ``num_envs``
    ints in ``[0, max_episode_steps)``) starts env i's episode at step ``s[i]``: its
    reference is read from sample ``s[i]`` on and it is truncated ``s[i]`` steps early;
    it desynchronises a batch's episodes for training. Later autoresets start at 0.

    ## Version History

    * v0: the initial version.
    """

    metadata = {"render_modes": ["rgb_array"], "autoreset_mode": AutoresetMode.SAME_STEP}

    def __init__(
        self,
        num_envs: int = 1,
        task: str = ids.FORCE_TRACK,
        cylinder: str = ids.DEFAULT_CYLINDER,
        tube_length_m: float | None = None,
        params=None,
        max_episode_steps: int | None = None,
        render_mode: str | None = None,
        **kwargs,
    ):
        if int(num_envs) != num_envs or num_envs < 1:
            raise ValueError(f"num_envs = {num_envs!r} is not allowed: must be an integer >= 1")
        options, overrides = _split_kwargs(kwargs)
        _check_render_mode(render_mode)
        self.num_envs = int(num_envs)
        self.core = TaskCore(
            _task(task), self.num_envs, cylinder, tube_length_m, params, options, **overrides
        )
        if max_episode_steps is None:
            max_episode_steps = ids.EPISODE_STEPS
        if int(max_episode_steps) != max_episode_steps or max_episode_steps < 1:
            raise ValueError(
                f"max_episode_steps = {max_episode_steps!r} is not allowed: must be an integer >= 1"
            )
        self.max_episode_steps = int(max_episode_steps)
        self.render_mode = render_mode
        i_max = np.float32(self.core.i_max)
        self.single_action_space = gym.spaces.Box(-i_max, i_max, shape=(1,), dtype=np.float32)
        low, high = self.core.observation_bounds()
        self.single_observation_space = gym.spaces.Box(low, high, dtype=np.float32)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self._rngs = [np.random.default_rng() for _ in range(self.num_envs)]

    @property
    def references(self) -> np.ndarray:
        """The episodes' reference samples, (num_envs, reference_steps + preview_steps + 1),
        read-only view; ``info["reference"][i]`` of step k is ``references[i, k]``."""
        return _read_only(self.core.references)

    def reset(
        self, *, seed: int | Sequence[int] | None = None, options: dict[str, Any] | None = None
    ) -> tuple[NDArray[np.float32], dict[str, Any]]:
        if seed is not None:
            seeds = (
                [seed + i for i in range(self.num_envs)] if isinstance(seed, int) else list(seed)
            )
            if len(seeds) != self.num_envs:
                raise ValueError(f"seed has {len(seeds)} entries, expected {self.num_envs}")
        references = _reset_references(self.core, options, self.num_envs)
        start_steps = _start_steps(options, self.num_envs, self.max_episode_steps)
        if seed is not None:
            self._rngs = [gym.utils.seeding.np_random(s)[0] for s in seeds]
        self.core.reset_envs(np.arange(self.num_envs), self._rngs, references, start_steps)
        return self.core.observation(), {}

    def step(
        self, actions: NDArray[np.float32]
    ) -> tuple[
        NDArray[np.float32],
        NDArray[np.float64],
        NDArray[np.bool_],
        NDArray[np.bool_],
        dict[str, Any],
    ]:
        current = self.core.check_action(actions)
        obs, reward = self.core.step(current, self._rngs)
        reward = reward.copy()
        info = self.core.info()
        terminated = np.zeros(self.num_envs, dtype=bool)
        truncated = self.core.step_count >= self.max_episode_steps
        if truncated.any():
            done = np.flatnonzero(truncated)
            final_obs = np.full(self.num_envs, None, dtype=object)
            for env in done:
                final_obs[env] = obs[env].copy()
            info["final_obs"] = final_obs
            info["_final_obs"] = truncated.copy()
            self.core.reset_envs(done, self._rngs)
            obs = self.core.observation()
        return obs, reward, terminated, truncated, info

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        from .render import render_rgb

        return render_rgb(self.core, 0, None)
