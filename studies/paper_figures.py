"""The figures of ``pneumatic-env paper`` (needs the ``plots`` extra): one PNG per
experiment of :mod:`pneumatic_env.studies.paper`, with the paper's figure numbers."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pneumatic_env.physics.flow import flow_constants

from .paper import (
    COUPLINGS,
    CYLINDERS,
    DOWNSTREAM_CURRENTS_A,
    SINE_AMPLITUDE_A,
    SINE_FREQUENCY_HZ,
    STEP_TUBES_M,
    TUBE_FLOW_FREQUENCY_HZ,
    TUBE_LENGTH_M,
    valve_flow_vs_current,
    valve_flow_vs_downstream,
    valve_numbers,
)


def write_figures(
    params: dict, step_runs: dict, sine_runs: dict, tube: dict, out: Path
) -> list[Path]:
    """Write the figures of (a)-(d) to ``out``; the paths written."""
    plt = pyplot()
    return (
        figure_valve(plt, params, out)
        + figure_step(plt, step_runs, out)
        + figure_sine(plt, sine_runs, out)
        + figure_tube(plt, tube, out)
    )


def pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def figure_valve(plt, params, out: Path) -> list[Path]:
    flows = valve_flow_vs_current(params)
    numbers = valve_numbers(params)
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    ax.plot(flows["current_a"], 1e3 * flows["chamber1_kg_s"], label="supply -> chamber 1 (A_in)")
    ax.plot(
        flows["current_a"], 1e3 * flows["chamber2_kg_s"], "--", label="supply -> chamber 2 (A_ex)"
    )
    ax.axhline(
        1e3 * numbers["choked_flow_full_open_kg_s"],
        color="k",
        lw=0.6,
        ls=":",
        label="choked flow, fully open",
    )
    ax.set(
        xlabel="coil current i_c [A]",
        ylabel="mass flow [g/s]",
        title="Valve flow vs coil current, chamber at ambient (cf. Fig. 7)",
    )
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    paths = [out / "valve_flow_vs_current.png"]
    fig.tight_layout()
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    downstream = np.linspace(params["ambient_pressure_pa"], params["supply_pressure_pa"], 400)
    for i in DOWNSTREAM_CURRENTS_A:
        ax.plot(
            1e-5 * downstream,
            1e3 * valve_flow_vs_downstream(params, i, downstream),
            label=f"i_c = {i:g} A",
        )
    p_cr = flow_constants(params["heat_capacity_ratio"], params["gas_constant_j_per_kg_k"])[2]
    ax.axvline(
        1e-5 * p_cr * params["supply_pressure_pa"],
        color="k",
        lw=0.6,
        ls=":",
        label="P_cr P_s (choked below)",
    )
    ax.set(
        xlabel="downstream pressure [bar abs]",
        ylabel="mass flow [g/s]",
        title=f"Valve flow vs downstream pressure, upstream "
        f"{1e-5 * params['supply_pressure_pa']:g} bar (cf. Fig. 9)",
    )
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    paths.append(out / "valve_flow_vs_downstream.png")
    fig.tight_layout()
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)
    return paths


def figure_step(plt, runs, out: Path) -> list[Path]:
    fig, axes = plt.subplots(2, 2, figsize=(10, 6.5), sharex=True)
    styles = {"command": "-", "literal": "--"}
    for col, L in enumerate(STEP_TUBES_M):
        for coupling in COUPLINGS:
            r = runs[(coupling, L)]
            t_ms = 1e3 * r["t"]
            ls = styles[coupling]
            axes[0, col].plot(t_ms, 1e-5 * r["p1"], ls, color="C0", label=f"p1, {coupling}")
            axes[0, col].plot(t_ms, 1e-5 * r["p2"], ls, color="C1", label=f"p2, {coupling}")
            axes[1, col].plot(t_ms, r["f"], ls, color="C2", label=f"force, {coupling}")
        axes[0, col].set(title=f"{L:g} m tubes", ylabel="pressure [bar abs]")
        axes[1, col].set(xlabel="time after the 0.5 A step [ms]", ylabel="force [N]")
        for ax in axes[:, col]:
            ax.grid(alpha=0.3)
            ax.legend(fontsize=7)
    fig.suptitle(
        "Clamped rod at mid-stroke, 0.5 A coil step (cf. Figs. 15-16); "
        "solid: command coupling (default), dashed: literal Eq. 55"
    )
    fig.tight_layout()
    path = out / "clamped_step.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return [path]


def figure_sine(plt, runs, out: Path) -> list[Path]:
    fig, axes = plt.subplots(len(CYLINDERS), 1, figsize=(8, 6), sharex=True)
    for ax, cylinder in zip(axes, CYLINDERS):
        r = runs[cylinder]
        ax.plot(r["t"], 1e3 * r["x"], color="C0", label="piston position x")
        ax.set(ylabel="x [mm]", title=cylinder)
        ax.grid(alpha=0.3)
        twin = ax.twinx()
        twin.step(r["t"], r["i_c"], where="post", color="C3", lw=0.8, label="coil current")
        twin.set_ylabel("i_c [A]", color="C3")
        ax.legend(loc="upper left", fontsize=8)
    axes[-1].set_xlabel("time [s]")
    fig.suptitle(
        f"Free rod, no load, {SINE_AMPLITUDE_A:g} A {SINE_FREQUENCY_HZ:g} Hz "
        "sinusoidal coil current (cf. Figs. 17-18)"
    )
    fig.tight_layout()
    path = out / "free_sine.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return [path]


def figure_tube(plt, tube, out: Path) -> list[Path]:
    fig, ax = plt.subplots(figsize=(8, 4.2))
    t_ms = 1e3 * tube["t"]
    ax.plot(t_ms, 1e3 * tube["inlet_kg_s"], color="k", lw=0.8, label="inlet flow")
    ax.plot(
        t_ms,
        1e3 * tube["outlet_eq31_kg_s"],
        color="C0",
        label="outlet, Eq. 31 (R_t by Reynolds number)",
    )
    ax.plot(
        t_ms,
        1e3 * tube["outlet_eq31_laminar_kg_s"],
        ":",
        color="C0",
        label="outlet, Eq. 31 with laminar R_t (Eq. 33)",
    )
    ax.plot(
        t_ms,
        1e3 * tube["outlet_wave_kg_s"],
        "--",
        color="C3",
        label="outlet, Eqs. 19-20 (characteristics, R_t by Reynolds number)",
    )
    ax.set(
        xlabel="time [ms]",
        ylabel="mass flow [g/s]",
        title=f"{TUBE_LENGTH_M:g} m x 3.2 mm tube, {TUBE_FLOW_FREQUENCY_HZ:g} Hz inlet flow, "
        f"P = {1e-5 * tube['mean_pressure_pa']:g} bar (cf. Fig. 3)",
    )
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=2)
    fig.tight_layout()
    path = out / "tube_outlet_flow.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return [path]
