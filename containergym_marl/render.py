"""Rendering of one plant simulation, shared by the centralised and the decentralised view.

Three render modes, read off a :class:`~containergym_marl.core.simulator.PlantSimulator` (its
``state``, ``last_outcome``, ``config`` and ``params``), so both views draw the same picture:

* ``"ansi"``: :func:`render_ansi`, a text snapshot (volumes to two decimals, PU timers, last step).
* ``"rgb_array"``: :meth:`PlantRenderer.rgb_array`, a ``(H, W, 3)`` uint8 frame of a diagram:
  containers as bars (fill level, v_max, the global optimum and the local optima), the last step's
  emptyings (dashed outline at the emptied volume) and denied requests (red cross), each with its
  reward, and the PUs with their remaining busy time and the container they serve.
* ``"human"``: :meth:`PlantRenderer.human` shows that diagram in a matplotlib window when a display
  and an interactive backend are available. Without one (a headless test run, CI) it draws the
  frame off-screen with Agg and returns ``None``: it never blocks and never opens a window.

matplotlib is imported only when a diagram is first drawn, so importing the environments stays
cheap. One :class:`~matplotlib.figure.Figure` is made per renderer and its artists are updated in
place for every frame.
"""

from __future__ import annotations

import os
import sys
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.figure import Figure

    from containergym_marl.core.simulator import PlantSimulator

__all__ = [
    "EnvRenderer",
    "RENDER_MODES",
    "RENDER_FPS",
    "PlantRenderer",
    "container_colors",
    "display_available",
    "render_ansi",
]

#: The render modes of both views, in the order of their ``metadata["render_modes"]``.
RENDER_MODES = ("human", "rgb_array", "ansi")
#: Frames per second of "human" rendering (both views' ``metadata["render_fps"]``).
RENDER_FPS = 4

_NON_INTERACTIVE_BACKENDS = {"agg", "cairo", "pdf", "pgf", "ps", "svg", "template"}


# ---- text ------------------------------------------------------------------------------------
def render_ansi(sim: PlantSimulator, index: int = 0) -> str:
    """A text snapshot of simulation ``index``: volumes against targets and v_max, PU timers."""
    cfg, params = sim.config, sim.params
    v = sim.state.volumes[index]
    p = sim.state.pu_timers_s[index]
    lines = [f"{cfg.name}  step {int(sim.state.step_count[index])}/{params.episode_length_steps}"
             f"  (δ = {params.timestep_s:g} s)"]
    width = 30
    for i, name in enumerate(cfg.container_names):
        vmax = params.max_volume[i]
        filled = int(round(width * min(v[i], vmax) / vmax))
        target_col = int(round(width * params.target_volume[i] / vmax))
        bar = ["#" if k < filled else "." for k in range(width)]
        if 0 <= target_col < width:
            bar[target_col] = "|"
        lines.append(f"{name:>8} [{''.join(bar)}] {v[i]:6.2f} / {vmax:g}  target {params.target_volume[i]:g}")
    lines.append("PUs: " + "  ".join(
        f"PU{j}: {'free' if t == 0 else f'busy {t:.0f} s'}" for j, t in enumerate(p)))
    out = sim.last_outcome
    if out is not None and int(sim.state.step_count[index]) > 0:
        names = cfg.container_names
        granted = [names[i] for i in np.flatnonzero(out.granted[index])]
        denied = [names[i] for i in np.flatnonzero(out.denied[index])]
        lines.append(f"last step: emptied {granted or '-'}, denied {denied or '-'}, "
                     f"plant reward {out.plant_reward[index]:+.3f}")
    return "\n".join(lines) + "\n"


# ---- helpers shared with the figures ---------------------------------------------------------
def container_colors(n: int) -> list[tuple[float, float, float, float]]:
    """One distinct RGBA colour per container (tab10 up to 10 containers, tab20 beyond)."""
    from matplotlib import colormaps

    cmap = colormaps["tab10" if n <= 10 else "tab20"]
    return [cmap(i % cmap.N) for i in range(n)]


def display_available() -> bool:
    """Whether "human" frames can be shown: an interactive matplotlib backend and, on Linux and
    other X11/Wayland systems, a ``DISPLAY`` or ``WAYLAND_DISPLAY``."""
    if sys.platform not in ("darwin", "win32") and not (
        os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
    ):
        return False
    import matplotlib

    backend = matplotlib.get_backend().lower()
    return backend not in _NON_INTERACTIVE_BACKENDS and not backend.startswith("module://")


# ---- what the views hold ----------------------------------------------------------------------
class EnvRenderer:
    """The rendering of one environment view: dispatches its ``render_mode``.

    ``render()`` returns the ansi text, the rgb_array frame, or ``None`` (``"human"`` and no
    mode). The diagram's figure is made on the first frame and released by :meth:`close`. In
    ``"human"`` mode the window is used only if :func:`display_available` says so at the first
    frame; otherwise frames are drawn off-screen (Agg), which never blocks.
    """

    def __init__(self, sim: PlantSimulator, render_mode: str | None, *, view: str, index: int = 0):
        if render_mode is not None and render_mode not in RENDER_MODES:
            raise ValueError(f"render_mode: {render_mode!r} not supported; choose from {list(RENDER_MODES)}")
        self.sim, self.render_mode, self.view, self.index = sim, render_mode, view, int(index)
        self._diagram: PlantRenderer | None = None

    @property
    def diagram(self) -> PlantRenderer:
        if self._diagram is None:
            window = self.render_mode == "human" and display_available()
            self._diagram = PlantRenderer(self.sim, index=self.index, view=self.view, window=window)
        return self._diagram

    def render(self):
        if self.render_mode == "ansi":
            return render_ansi(self.sim, self.index)
        if self.render_mode == "rgb_array":
            return self.diagram.rgb_array()
        if self.render_mode == "human":
            return self.diagram.human()
        return None

    def close(self) -> None:
        if self._diagram is not None:
            self._diagram.close()
            self._diagram = None


# ---- diagram ---------------------------------------------------------------------------------
class PlantRenderer:
    """Draws simulation ``index`` of a simulator; one figure, reused for every frame.

    Args:
        sim: the simulator to read (never stepped by the renderer).
        index: which simulation of the batch to draw.
        view: shown in the title (``"centralised"`` or ``"decentralised"``).
        window: ``True`` to draw into a pyplot-managed window (used by "human" when
            :func:`display_available`); ``False`` (default) for an off-screen Agg canvas.
        dpi: resolution; the frame is ``(5.2·dpi, 9·dpi, 3)`` pixels (520 × 900 at 100 dpi).
        fps: frame rate of the window (seconds per frame = 1 / fps).

    The PU panel names the container a PU serves when the renderer saw the step that assigned it
    (it draws every step in "human" mode; in "rgb_array" mode when called after every step);
    otherwise it shows only the remaining time.
    """

    FIGSIZE_IN = (9.0, 5.2)

    def __init__(self, sim: PlantSimulator, *, index: int = 0, view: str = "",
                 window: bool = False, dpi: float = 100, fps: float = RENDER_FPS):
        self.sim, self.index, self.view = sim, int(index), view
        self.window, self.dpi, self.fps = bool(window), float(dpi), float(fps)
        self.fig: Figure | None = None
        self._serving = np.full(sim.params.n_pus, -1)  # container each PU serves, -1 = unknown
        self._seen_step: int | None = None
        self._seen_outcome = None
        self._dynamic: list = []  # artists redrawn every frame (over a cached background)
        self._background = None
        self._shown = False

    # ---- public API --------------------------------------------------------------------------
    def rgb_array(self) -> np.ndarray:
        """The current frame as a new ``(H, W, 3)`` uint8 array."""
        self._draw()
        buf = np.asarray(self.fig.canvas.buffer_rgba())
        return np.ascontiguousarray(buf[..., :3])

    def human(self) -> None:
        """Show the current frame in the window if there is one, else draw it off-screen."""
        self._draw()
        if self.window:
            if not self._shown:
                self.fig.show()
                self._shown = True
            # Runs the window's event loop for one frame period, then returns: never blocks.
            self.fig.canvas.flush_events()
            self.fig.canvas.start_event_loop(1.0 / self.fps)
        return None

    def close(self) -> None:
        """Release the figure (and close its window, if any)."""
        if self.fig is not None:
            if self.window:
                import matplotlib.pyplot as plt

                plt.close(self.fig)
            self.fig = None
            self._background = None
            self._shown = False

    # ---- drawing -----------------------------------------------------------------------------
    def _dyn(self, artist):
        """Register an artist that changes between frames (drawn over the cached background)."""
        self._dynamic.append(artist)
        if not self.window:
            artist.set_animated(True)
        return artist

    def _make_figure(self) -> None:
        from matplotlib.collections import LineCollection
        from matplotlib.lines import Line2D
        from matplotlib.patches import Patch

        if self.window:
            import matplotlib.pyplot as plt

            fig = plt.figure(figsize=self.FIGSIZE_IN, dpi=self.dpi)
        else:
            from matplotlib.backends.backend_agg import FigureCanvasAgg
            from matplotlib.figure import Figure

            fig = Figure(figsize=self.FIGSIZE_IN, dpi=self.dpi)
            FigureCanvasAgg(fig)
        self.fig = fig
        self._dynamic = []
        self._background = None
        cfg, params = self.sim.config, self.sim.params
        n, m = params.n_containers, params.n_pus
        x = np.arange(n)
        small = 8 if n <= 11 else 6.5
        dyn = self._dyn

        self._title = dyn(fig.text(0.01, 0.975, "", fontsize=11, weight="bold", va="top"))
        self._subtitle = dyn(fig.text(0.01, 0.925, "", fontsize=9, va="top"))

        # Containers: bars, then v_max / optimum lines over them, then markers and texts.
        ax = fig.add_axes((0.075, 0.40, 0.70, 0.46))
        self._top = top = 1.12 * float(params.max_volume.max())
        ax.set_xlim(-0.6, n - 0.4)
        ax.set_ylim(0, top)
        ax.set_ylabel("volume (volume units)")
        ax.set_xticks(x, list(cfg.container_names), fontsize=small)
        ax.tick_params(axis="x", length=0)
        half = 0.36
        self._ghosts = ax.bar(x, np.zeros(n), width=2 * half, fill=False, edgecolor="tab:green",
                              linestyle="--", linewidth=1.5, zorder=2)
        self._bars = ax.bar(x, np.zeros(n), width=2 * half, color="tab:blue", zorder=3)
        for rect in (*self._ghosts, *self._bars):
            dyn(rect)
        vmax_lines = [((i - half, params.max_volume[i]), (i + half, params.max_volume[i])) for i in x]
        target_lines = [((i - half, params.target_volume[i]), (i + half, params.target_volume[i]))
                        for i in x]
        local = [((i - 0.7 * half, peak), (i + 0.7 * half, peak))
                 for i, c in enumerate(cfg.containers) for peak in c.reward_peaks
                 if peak != c.target_volume]
        dyn(ax.add_collection(LineCollection(vmax_lines, colors="tab:red", linewidths=2.0, zorder=4)))
        dyn(ax.add_collection(LineCollection(target_lines, colors="tab:green", linewidths=2.0,
                                             linestyles="--", zorder=4)))
        dyn(ax.add_collection(LineCollection(local, colors="0.45", linewidths=1.0, linestyles=":",
                                             zorder=4)))
        self._denied = dyn(ax.scatter(np.zeros(0), np.zeros(0), marker="X", s=90, color="tab:red",
                                      edgecolor="white", linewidth=0.8, zorder=6))
        self._reward_texts = [dyn(ax.text(i, 0, "", ha="center", va="bottom", fontsize=small,
                                          weight="bold", zorder=7)) for i in x]
        # Volumes under the names (x in data, y in axes coordinates).
        self._volume_texts = [dyn(ax.text(i, -0.075, "", ha="center", va="top", fontsize=small,
                                          transform=ax.get_xaxis_transform(), clip_on=False))
                              for i in x]
        self._container_ax = ax

        handles = [
            Patch(color="tab:blue", label="fill level"),
            Patch(color="tab:orange", label="past global optimum"),
            Patch(color="tab:red", label="overflow (≥ v_max)"),
            Line2D([], [], color="tab:red", lw=2, label="v_max"),
            Line2D([], [], color="tab:green", lw=2, ls="--", label="global optimum v*"),
            Line2D([], [], color="0.45", lw=1, ls=":", label="local optima"),
            Patch(fill=False, edgecolor="tab:green", ls="--",
                  label="emptied last step\n(volume, reward)"),
            Line2D([], [], color="tab:red", marker="X", ls="", ms=9,
                   label="request denied\n(no free PU)"),
        ]
        fig.legend(handles=handles, loc="upper left", bbox_to_anchor=(0.79, 0.86), fontsize=8,
                   frameon=False)

        # Processing units.
        pax = fig.add_axes((0.075, 0.09, 0.70, 0.17))
        self._pu_max = max(float(params.max_pu_time_s), float(params.timestep_s))
        pax.set_xlim(0, self._pu_max)
        pax.set_ylim(-0.6, m - 0.4)
        pax.invert_yaxis()
        pax.set_yticks(np.arange(m), [f"PU{j}" for j in range(m)], fontsize=small)
        pax.set_xlabel("remaining busy time (s)")
        pax.grid(axis="x", alpha=0.3)
        self._pu_bars = pax.barh(np.arange(m), np.zeros(m), height=0.6, color="0.55", zorder=3)
        for rect in self._pu_bars:
            dyn(rect)
        self._pu_texts = [dyn(pax.text(0, j, "", va="center", fontsize=small, zorder=4))
                          for j in range(m)]
        self._pu_ax = pax
        self._dynamic.sort(key=lambda a: a.get_zorder())

    def _update_assignments(self) -> None:
        """Track which container each PU serves from the outcomes seen step by step."""
        sim, b = self.sim, self.index
        step = int(sim.state.step_count[b])
        out = sim.last_outcome
        if step == 0:
            self._serving[:] = -1
        elif out is not None and out is not self._seen_outcome:
            if self._seen_step != step - 1:  # steps were missed: earlier assignments unknown
                self._serving[:] = -1
            for i in np.flatnonzero(out.granted[b]):
                self._serving[out.pu_index[b, i]] = i
        self._serving[sim.state.pu_timers_s[b] == 0] = -1
        self._seen_step, self._seen_outcome = step, out

    def _update_artists(self) -> None:
        sim, b = self.sim, self.index
        cfg, params = sim.config, sim.params
        names = cfg.container_names
        v = sim.state.volumes[b]
        timers = sim.state.pu_timers_s[b]
        step = int(sim.state.step_count[b])
        out = sim.last_outcome if step > 0 else None
        top = self._top

        view = f" ({self.view} view)" if self.view else ""
        self._title.set_text(f"{cfg.name}{view}   step {step}/{params.episode_length_steps}"
                             f"   t = {step * params.timestep_s / 3600:.2f} h   δ = {params.timestep_s:g} s")
        for i, (bar, ghost) in enumerate(zip(self._bars, self._ghosts)):
            bar.set_height(min(v[i], top))
            if v[i] >= params.max_volume[i]:
                bar.set_facecolor("tab:red")
            elif v[i] > params.target_volume[i]:
                bar.set_facecolor("tab:orange")
            else:
                bar.set_facecolor("tab:blue")
            ghost.set_height(0.0)
            self._reward_texts[i].set_text("")
            self._volume_texts[i].set_text(f"{v[i]:.2f}")

        denied_xy = np.zeros((0, 2))
        if out is None:
            self._subtitle.set_text("last step: -")
        else:
            granted = np.flatnonzero(out.granted[b])
            denied = np.flatnonzero(out.denied[b])
            for i in granted:
                self._ghosts[i].set_height(min(out.emptied_volume[b, i], top))
            if denied.size:
                denied_xy = np.column_stack([denied, np.minimum(v[denied], top)])
            for i in np.flatnonzero(out.requested[b]):
                height = out.emptied_volume[b, i] if out.granted[b, i] else v[i]
                r = out.container_reward[b, i]
                text = self._reward_texts[i]
                text.set_position((i, min(height, top) + 0.02 * top))
                text.set_text(f"{r:+.2f}")
                text.set_color("tab:green" if r > 0 else "tab:red")
            parts = [
                f"free PUs {int(out.free_pus_before[b])}/{params.n_pus}",
                "emptied " + (", ".join(f"{names[i]} at {out.emptied_volume[b, i]:.2f}" for i in granted)
                              or "-"),
                "denied " + (", ".join(names[i] for i in denied) or "-"),
                f"plant reward {out.plant_reward[b]:+.3f}",
            ]
            overflowed = np.flatnonzero(out.overflowed[b])
            if overflowed.size:
                parts.append("OVERFLOW " + ", ".join(names[i] for i in overflowed))
            self._subtitle.set_text("last step: " + ";  ".join(parts))
        self._denied.set_offsets(denied_xy)

        for j, (bar, text) in enumerate(zip(self._pu_bars, self._pu_texts)):
            t = float(timers[j])
            width = min(t, self._pu_max)
            bar.set_width(width)
            serving = int(self._serving[j])
            label = "free" if t == 0 else f"{t:.0f} s" + (f" ({names[serving]})" if serving >= 0 else "")
            text.set_text(label)
            inside = width > 0.7 * self._pu_max  # a long bar: write the label inside it
            text.set_x(width - 0.01 * self._pu_max if inside else width + 0.01 * self._pu_max)
            text.set_horizontalalignment("right" if inside else "left")
            text.set_color("white" if inside else "black")

    def _draw(self) -> None:
        if self.fig is None:
            self._make_figure()
        self._update_assignments()
        self._update_artists()
        canvas = self.fig.canvas
        if self.window:
            canvas.draw()
            return
        if self._background is None:
            canvas.draw()  # the static parts: axes, ticks, labels, legend
            self._background = canvas.copy_from_bbox(self.fig.bbox)
        else:
            canvas.restore_region(self._background)
        for artist in self._dynamic:
            self.fig.draw_artist(artist)
