"""Learned controllers from the sensor observation alone, in numpy (no torch at run time).

An actor exported by ``pneumatic-env train --algo ppo_fast`` (``agents/ppo.py``) is an
``.npz`` with the MLP of :class:`pneumatic_env.agents.policy.NumpyPolicy`, the observation
normaliser (``obs_mean``, ``obs_std``) and, in its ``meta``, everything needed to rebuild
its input from the base observation ``[p1, p2, x, f, ref(k), preview...]``: the env
options it was trained with (preview, normalisation, ``envs.features`` options), the
residual configuration (``agents.residual``) if it corrects a classical controller, and
the names of its input columns (``envs.features.observation_columns`` plus
``base_current``, ``base_error``). :class:`LearnedController` keeps the feature
histories, the error integral and the classical controller inside, so it runs through
the :class:`~pneumatic_env.agents.base.Controller` interface like the classical ones.

Shipped policies live in ``agents/policies/<name>-<variant>.npz`` (``<variant>`` as in the
controller configs, e.g. ``numatics-2m``; ``all`` for a generalist that runs on every
variant) and run by name:
``pneumatic-env bench --controller <name> --variants <variant>``.

    python -m pneumatic_env.agents.learned convert runs/res-c-s0/actor_best.npz OUT.npz
        # an actor of the issue-19 prototype (format issue19-ppo-actor-v1) to this format

Format versions (``meta["format"]``): ``pneumatic_env-learned-v1``, the trainer's export,
takes the model parameters from the env it runs in and a residual actor's base controller
from the benchmark's gains of the variant; ``pneumatic_env-learned-v2`` is self-contained
(:func:`write_self_contained`, ``pneumatic-env train --rig``): its ``meta["model"]`` holds
the model it was trained for (parameters, scales, control period) and
``meta["base_controller"]`` the base controller's kind and gains, so it runs on any env of
its observation layout with no config. Another version is refused by name.
"""

from __future__ import annotations

import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

from pneumatic_env.envs.features import (
    FeatureConfig,
    FeatureState,
    normalize_base_observation,
    observation_columns,
)
from pneumatic_env.envs.tasks import TASKS
from pneumatic_env.ids import parse_env_id

from .base import Controller, ControllerContext, valve_currents
from .generalist import PARAM_PREFIX, param_values
from .policy import NumpyPolicy
from .residual import RESIDUAL_COLUMNS, ResidualConfig, ResidualCore

__all__ = [
    "zero_the_residual",
    "scale_the_residual",
    "trained_correction_fraction",
    "FORMAT",
    "FORMAT_SELF_CONTAINED",
    "FORMATS",
    "write_self_contained",
    "LearnedActor",
    "LearnedController",
    "pure_current",
    "is_learned",
    "policy_dir",
    "shipped_policies",
    "shipped_policy_path",
    "convert_prototype_actor",
]

FORMAT = "pneumatic_env-learned-v1"
FORMAT_SELF_CONTAINED = "pneumatic_env-learned-v2"
FORMATS = (FORMAT, FORMAT_SELF_CONTAINED)
_FORMAT_PREFIX = "pneumatic_env-learned-"


def pure_current(action, action_scale_a: float, deadband_a, smoothing: float, i_max_a: float):
    """A pure policy's coil current (A) for actions in [-1, 1]:
    ``clip(action_scale_a a + deadband_a tanh(a / smoothing), -i_max, i_max)``.

    The tanh term (on when ``smoothing > 0``) steps over the valve's dead band
    (``deadband_a``, the current where the supply path opens, Eqs. 43-46;
    ``agents.base.valve_currents``) within a few hundredths of the action, so a small
    action moves air and zero holds it; without it a smooth policy rests inside the dead
    band, where the chambers are sealed and a force error stays (measured: a -3.6 % offset
    on Numatics-0.5m). An actuator map from the nominal valve, not a controller."""
    u = action_scale_a * np.asarray(action, dtype=np.float64)
    if smoothing > 0:
        u = u + deadband_a * np.tanh(np.asarray(action) / smoothing)
    return np.clip(u, -i_max_a, i_max_a)


def is_learned(path: str | Path) -> bool:
    """Whether ``path`` is an ``.npz`` of this format, any version (else e.g. an SB3
    export); :class:`LearnedActor` refuses a version it does not read."""
    with np.load(path, allow_pickle=False) as data:
        if "meta" not in data:
            return False
        return str(json.loads(str(data["meta"])).get("format", "")).startswith(_FORMAT_PREFIX)


class LearnedActor(NumpyPolicy):
    """The exported MLP with its observation normaliser: ``action(x)`` in [-1, 1] for input
    rows ``x`` (the columns ``meta["inputs"]``), ``(x - mean) / std`` clipped first."""

    def __init__(self, path: str | Path):
        super().__init__(path)
        if self.meta.get("format") not in FORMATS:
            raise ValueError(
                f"{path}: format = {self.meta.get('format')!r} is not allowed: this "
                f"package reads {list(FORMATS)} (agents/ppo.py export, train --rig)"
            )
        with np.load(self.path, allow_pickle=False) as data:
            self.obs_mean, self.obs_std = data["obs_mean"], data["obs_std"]
        self.clip_obs = float(self.meta["clip_obs"])
        if len(self.meta["inputs"]) != self.obs_dim or self.obs_mean.shape != (self.obs_dim,):
            raise ValueError(
                f"{path}: {len(self.meta['inputs'])} input names and a normaliser "
                f"of shape {self.obs_mean.shape} for {self.obs_dim} inputs"
            )

    def action(self, x) -> np.ndarray:
        # C order: BLAS sums a product of a Fortran-ordered array in another order
        x = np.clip(
            (np.ascontiguousarray(x, dtype=np.float64) - self.obs_mean) / self.obs_std,
            -self.clip_obs,
            self.clip_obs,
        )
        return self.normalized_action(x)[:, 0]

    @property
    def feature_config(self) -> FeatureConfig:
        opts = self.meta["env_options"]
        return FeatureConfig(
            **{k: opts[k] for k in FeatureConfig.__dataclass_fields__ if k in opts}
        )

    @property
    def residual_config(self) -> ResidualConfig | None:
        r = self.meta.get("residual")
        return None if r is None else ResidualConfig(**r)

    @property
    def base_controller(self) -> tuple[str, dict] | None:
        """(kind, gains) of the base controller a self-contained file holds, else None."""
        b = self.meta.get("base_controller")
        return None if b is None else (b["kind"], dict(b["gains"]))

    def model_context(self, context: ControllerContext) -> ControllerContext:
        """``context`` with the model a self-contained file holds (parameters, scales);
        ``context`` itself for a v1 file. The control period must be the file's."""
        model = self.meta.get("model")
        if model is None:
            return context
        if not np.isclose(context.dt_s, model["dt_s"], rtol=1e-9, atol=0.0):
            raise ValueError(
                f"{self.path}: trained at a control period of {model['dt_s']} s, "
                f"the env steps {context.dt_s} s"
            )
        return dataclasses.replace(
            context,
            base_params={k: float(v) for k, v in model["base_params"].items()},
            scale_n=float(model["scale_n"]),
            force_scale_n=model["force_scale_n"],
        )


class LearnedController(Controller):
    """A :class:`LearnedActor` as a benchmark controller: base observation in, current out.

    ``base``: the classical controller a residual actor corrects, built for ``context``
    (``agents.registry.make_base_controller``; the benchmark's gains of the variant it
    runs); None for a pure actor. The controller's env must give ``preview_steps`` of the
    actor.
    """

    name = "learned"

    def __init__(
        self, context: ControllerContext, actor: LearnedActor, base: Controller | None = None
    ):
        super().__init__(context)
        opts = actor.meta["env_options"]
        if context.preview_steps != int(opts["preview_steps"]):
            raise ValueError(
                f"{actor.path}: trained with preview_steps = "
                f"{opts['preview_steps']}, the env gives {context.preview_steps}"
            )
        rc = actor.residual_config
        if (rc is None) != (base is None):
            raise ValueError(
                f"{actor.path}: a {'pure' if rc is None else 'residual'} actor "
                f"{'takes no' if rc is None else 'needs a'} base controller"
            )
        self.actor = actor
        self.name = actor.meta.get("name", actor.path.stem)
        self.features_config = actor.feature_config
        self.normalize = bool(opts["normalize_observation"])
        self.residual = None if rc is None or base is None else ResidualCore(base, rc)
        columns = observation_columns(context.preview_steps, self.features_config)
        columns += list(RESIDUAL_COLUMNS) if rc is not None else []
        # a generalist's plant columns (agents.generalist): nominal parameters it may know
        plant = [c for c in actor.meta["inputs"] if c.startswith(PARAM_PREFIX)]
        self.plant_values = param_values(context.base_params, plant).astype(np.float32)
        columns += plant
        missing = [c for c in actor.meta["inputs"] if c not in columns]
        if missing:
            raise ValueError(
                f"{actor.path}: input column(s) {missing} are not built by its "
                f"options (columns: {columns})"
            )
        self.index = np.array([columns.index(c) for c in actor.meta["inputs"]])
        self.action_scale_a = float(actor.meta["action_scale_a"])
        self.deadband_smoothing = float(actor.meta.get("deadband_smoothing") or 0.0)
        self.deadband_a = valve_currents(context.base_params)[0]
        self.tracked = TASKS[parse_env_id(actor.meta["env_id"]).task].tracked  # "f" or "x"

    def _allocate(self, n):
        ctx = self.context
        self.features = FeatureState(
            self.features_config,
            n,
            ctx.preview_steps,
            ctx.observation_scales,
            ctx.dt_s,
            self.tracked,
        )
        self.fresh = np.ones(n, dtype=bool)
        self.last_current = np.zeros(n)
        if self.residual is not None:
            self.residual.reset()

    def _reset_rows(self, rows):
        self.fresh[rows] = True
        if self.residual is not None:
            self.residual.reset(rows)

    def inputs(self, obs_si) -> np.ndarray:
        """The env-layout observation this controller rebuilds (all columns, float32) for SI
        rows ``obs_si``; updates the feature state (call once per step). ``act`` keeps the
        last one in ``last_inputs``."""
        parts = [
            (
                normalize_base_observation(obs_si, self.context.observation_scales)
                if self.normalize
                else obs_si
            ).astype(np.float32)
        ]
        if self.fresh.all():
            self.features.reset(np.arange(obs_si.shape[0]), obs_si)
        else:
            self.features.update(obs_si, self.last_current)
            rows = np.flatnonzero(self.fresh)
            self.features.reset(rows, obs_si[rows])
        self.fresh[:] = False
        parts.append(self.features.values)
        if self.residual is not None:
            parts.append(self.residual.observe(obs_si))
        parts.append(np.broadcast_to(self.plant_values, (obs_si.shape[0], self.plant_values.size)))
        return np.concatenate(parts, axis=1)

    def _act(self, obs):
        self.last_inputs = self.inputs(obs)
        a = self.actor.action(self.last_inputs[:, self.index])
        if self.residual is not None:
            u = self.residual.current(a)
            self.residual.applied(u)
        else:
            i_max = self.context.i_max_a
            u = pure_current(
                a, self.action_scale_a, self.deadband_a, self.deadband_smoothing, i_max
            )
        self.last_current = u
        return u


def write_self_contained(
    src: str | Path,
    dst: str | Path,
    context: ControllerContext,
    base: tuple[str, dict] | None,
    **meta,
) -> Path:
    """Rewrite the v1 actor ``src`` as a self-contained v2 file ``dst``: the model of
    ``context`` (the env it was trained for) and the base controller ``(kind, gains)`` go
    into its meta, with any other ``meta`` keys (e.g. a ``source``)."""
    with np.load(src, allow_pickle=False) as data:
        arrays = {k: data[k] for k in data.files if k != "meta"}
        old = json.loads(str(data["meta"]))
    if old.get("format") != FORMAT:
        raise ValueError(f"{src}: format = {old.get('format')!r}, expected {FORMAT!r}")
    if (old.get("residual") is None) != (base is None):
        raise ValueError(f"{src}: a residual actor needs a base controller, a pure one none")
    if base is not None and base[0] != old["residual"]["base"]:
        raise ValueError(f"{src}: trained on base {old['residual']['base']!r}, not {base[0]!r}")
    new = {
        **old,
        **meta,
        "format": FORMAT_SELF_CONTAINED,
        "model": {
            "base_params": {k: float(v) for k, v in context.base_params.items()},
            "dt_s": float(context.dt_s),
            "scale_n": float(context.scale_n),
            "force_scale_n": None
            if context.force_scale_n is None
            else float(context.force_scale_n),
        },
        "base_controller": None
        if base is None
        else {"kind": base[0], "gains": {k: _plain_gain(v) for k, v in base[1].items()}},
    }
    dst = Path(dst)
    np.savez(dst, meta=np.array(json.dumps(new)), **arrays)
    return dst


def zero_the_residual(path: str | Path, reason: str) -> Path:
    """Rewrite the residual actor file ``path`` with its output layer zeroed: its action is
    0 for every input, so the controller is its base controller bit for bit
    (``agents.residual``); ``reason`` goes into its meta (``residual_zeroed``)."""
    path = Path(path)
    with np.load(path, allow_pickle=False) as data:
        arrays = {k: data[k] for k in data.files if k != "meta"}
        meta = json.loads(str(data["meta"]))
    if meta.get("residual") is None:
        raise ValueError(f"{path}: a pure actor has no base to fall back on")
    last = len(meta["activations"]) - 1
    arrays[f"w{last}"] = np.zeros_like(arrays[f"w{last}"])
    arrays[f"b{last}"] = np.zeros_like(arrays[f"b{last}"])
    np.savez(path, meta=np.array(json.dumps({**meta, "residual_zeroed": reason})), **arrays)
    return path


def trained_correction_fraction(meta: dict) -> float:
    """The correction bound a residual actor's ``meta`` was trained with (before any
    ``scale_the_residual``)."""
    scaled = meta.get("residual_gain", {}).get("trained_correction_fraction")
    return float(scaled if scaled is not None else meta["residual"]["correction_fraction"])


def scale_the_residual(src: str | Path, dst: str | Path, gain: float, source: str) -> Path:
    """Write the residual actor ``src`` to ``dst`` with the bound of its correction (the
    residual's ``correction_fraction``) at ``gain`` times the trained one: 1 runs it as
    trained, 0 runs its base controller alone. The trained bound, the gain and ``source``
    go into its meta (``residual_gain``); a file already scaled is scaled from its trained
    bound, not compounded."""
    if not (np.isfinite(gain) and gain >= 0):
        raise ValueError(f"gain = {gain!r} is not allowed: must be a finite number >= 0")
    with np.load(src, allow_pickle=False) as data:
        arrays = {k: data[k] for k in data.files if k != "meta"}
        meta = json.loads(str(data["meta"]))
    residual = meta.get("residual")
    if residual is None:
        raise ValueError(f"{src}: a pure actor has no residual to scale")
    trained = trained_correction_fraction(meta)
    meta["residual"] = {**residual, "correction_fraction": trained * float(gain)}
    meta["residual_gain"] = {
        "gain": float(gain),
        "trained_correction_fraction": trained,
        "source": source,
    }
    np.savez(dst, meta=np.array(json.dumps(meta)), **arrays)
    return Path(dst)


def _plain_gain(value):
    """A gain as a JSON value (bool, int, float or list of floats)."""
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    arr = np.asarray(value, dtype=np.float64)
    return float(arr) if arr.ndim == 0 else arr.tolist()


# --------------------------------------------------------------------------- shipped policies


def policy_dir() -> Path:
    """``agents/policies``: the shipped actors."""
    return Path(__file__).resolve().parent / "policies"


def shipped_policies() -> dict[str, list[str]]:
    """Shipped policy name -> the variant keys it has an actor for."""
    out: dict[str, list[str]] = {}
    for path in sorted(policy_dir().glob("*.npz")):
        name, _, rest = path.stem.partition("-")
        out.setdefault(name, []).append(rest)
    return out


def shipped_policy_path(name: str, variant: str) -> Path:
    """``agents/policies/<name>-<variant>.npz``; a clear error if that variant has none."""
    available = shipped_policies().get(name)
    if available is None:
        raise ValueError(
            f"controller = {name!r} is not a shipped policy: use one of "
            f"{sorted(shipped_policies())}"
        )
    key = variant.lower()
    if key not in available and "all" in available:  # a generalist: one actor for all
        key = "all"
    if key not in available:
        raise ValueError(
            f"controller = {name!r} has no actor for variant = {variant!r}: "
            f"it has {available} (pass --variants)"
        )
    return policy_dir() / f"{name}-{key}.npz"


# --------------------------------------------------------------------------- prototype actors


# The prototype's input order (agents/rl_features.FeatureBuilder of the issue-19 worktree),
# as columns of this package's env layout.
def _prototype_inputs(k: int, m: int, h: int, residual: bool) -> list[str]:
    cols = ["f", "p1", "p2", "ref+0"] + [f"rel_ref+{j}" for j in range(h + 1)]
    for ch in ("f", "p1", "p2"):
        cols += [f"d{ch}-{j}" for j in range(1, m + 1)]
    cols += [f"u-{j}" for j in range(1, k + 1)] + ["e_int"]
    return cols + (list(RESIDUAL_COLUMNS) if residual else [])


def convert_prototype_actor(src: str | Path, dst: str | Path, name: str | None = None) -> Path:
    """Rewrite an actor of the issue-19 prototype (``issue19-ppo-actor-v1``) in this format.

    The weights and the normaliser are copied unchanged; the prototype's features map to
    env columns one to one (its measured f, p1, p2 and r(k) are the normalised base
    columns, its action history, measured differences x10, leaky integral x10 and
    relative preview are the ``envs.features`` blocks), so the controller rebuilds the
    same input. The prototype's correction ``corr_scale_a`` (A) becomes
    ``correction_fraction = corr_scale_a / 2 A`` (the coil limit of both cylinders).
    """
    with np.load(src, allow_pickle=False) as data:
        meta = json.loads(str(data["meta"]))
        if meta.get("format") != "issue19-ppo-actor-v1":
            raise ValueError(
                f"{src}: format = {meta.get('format')!r} is not allowed: expected "
                "'issue19-ppo-actor-v1'"
            )
        n = int(meta["n_layers"])
        arrays = {f"{c}{i}": data[f"{c}{i}"] for i in range(n) for c in "wb"}
        mean, std = data["obs_mean"], data["obs_std"]
    if int(meta.get("repeat", 1)) != 1:
        raise ValueError(
            f"{src}: repeat = {meta['repeat']!r} is not allowed: action repeat "
            "is not ported (1 only)"
        )
    f = meta["features"]
    residual = bool(meta["residual"])
    i_max = 2.0  # coil_current_max_a of both cylinders (configs/cylinders)
    out = {
        "format": FORMAT,
        "algo": "ppo_fast",
        "name": name or Path(src).parent.name,
        "env_id": meta["env"],
        "variant": meta["variant"],
        "preview_steps": f["preview"],
        "normalize_observation": True,
        "output": "clip",
        "clip_obs": meta["clip_obs"],
        "action_scale_a": meta["action_scale_a"],
        "activations": ["Tanh"] * (n - 1) + ["Identity"],
        "env_options": {
            "preview_steps": f["preview"],
            "normalize_observation": True,
            "action_history": f["k_actions"],
            "measurement_history": f["m_hist"],
            "tracking_error": True,
            "error_integral_tau_s": f["tau_i"],
            "error_integral_leaky": True,
            "relative_preview": True,
        },
        "residual": None
        if not residual
        else {
            "base": "sliding_mode",
            "correction_fraction": meta["corr_scale_a"] / i_max,
            "gate_floor": meta.get("gate_c0", 1.0),
            "gate_scale": meta.get("gate_scale", 0.3),
            "gate_steps": 20,
            "consistent_predictor": bool(meta.get("consistent_predictor", False)),
        },
        "inputs": _prototype_inputs(f["k_actions"], f["m_hist"], f["preview"], residual),
        "source": f"converted from the issue-19 prototype actor {src}",
    }
    out["obs_dim"] = len(out["inputs"])
    if arrays["w0"].shape[1] != out["obs_dim"]:
        raise ValueError(
            f"{src}: the actor takes {arrays['w0'].shape[1]} inputs, the "
            f"prototype layout has {out['obs_dim']}"
        )
    dst = Path(dst)
    np.savez(dst, meta=np.array(json.dumps(out)), obs_mean=mean, obs_std=std, **arrays)
    return dst


if __name__ == "__main__":
    if len(sys.argv) not in (4, 5) or sys.argv[1] != "convert":
        sys.exit("usage: python -m pneumatic_env.agents.learned convert SRC.npz DST.npz [NAME]")
    print(convert_prototype_actor(*sys.argv[2:]))
