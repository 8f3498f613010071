"""``render_mode="rgb_array"``: the cylinder's state and recent traces, drawn with Matplotlib."""

from __future__ import annotations

from collections import deque

import numpy as np

TRACE_STEPS = 500


class Trace:
    """The last ``TRACE_STEPS`` samples of one environment, for rendering."""

    def __init__(self):
        self.rows = deque(maxlen=TRACE_STEPS)

    def record(self, core, env: int) -> None:
        k = min(core.step_count[env], core.references.shape[1] - 1)
        p1, p2, x, f = core.measured[env]
        self.rows.append((core.step_count[env] * core.dt, f, core.references[env, k], p1, p2, x))


def render_rgb(core, env: int, trace: Trace | None) -> np.ndarray:
    """An RGB image (H, W, 3) uint8: the cylinder (piston position, pressures) and traces."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6.4, 4.8), dpi=80)
    canvas = FigureCanvasAgg(fig)
    ax_cyl, ax_f, ax_p = (fig.add_subplot(3, 1, k) for k in (1, 2, 3))
    p1, p2, x, f = core.measured[env]
    half = core.half_stroke
    span = core.ps - core.pa
    shade = lambda p: str(float(np.clip(1 - (p - core.pa) / span, 0.1, 1.0)))  # noqa: E731
    ax_cyl.add_patch(matplotlib.patches.Rectangle((-half, 0), x + half, 1, color=shade(p1)))
    ax_cyl.add_patch(matplotlib.patches.Rectangle((x, 0), half - x, 1, color=shade(p2)))
    ax_cyl.plot([x, x], [0, 1], "k", lw=4)
    ax_cyl.plot([x, half * 1.6], [0.5, 0.5], "k", lw=3)
    ax_cyl.set_xlim(-half * 1.1, half * 1.7)
    ax_cyl.set_ylim(-0.1, 1.1)
    ax_cyl.set_yticks([])
    ax_cyl.set_title(
        f"p1 {p1 / 1e3:.0f} kPa  p2 {p2 / 1e3:.0f} kPa  x {x * 1e3:.1f} mm  f {f:.1f} N", fontsize=9
    )
    if trace is not None and trace.rows:
        t, fs, ref, p1s, p2s, _ = np.array(trace.rows).T
        tracked = fs if core.task.tracked == "f" else np.array(trace.rows)[:, 5]
        ax_f.plot(t, tracked, label=core.task.tracked)
        ax_f.plot(t, ref, "--", label="reference")
        ax_f.legend(fontsize=7, loc="upper left")
        ax_p.plot(t, p1s / 1e3, label="p1")
        ax_p.plot(t, p2s / 1e3, label="p2")
        ax_p.set_ylabel("kPa", fontsize=8)
        ax_p.legend(fontsize=7, loc="upper left")
    ax_p.set_xlabel("t (s)", fontsize=8)
    fig.tight_layout()
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[:, :, :3].copy()
