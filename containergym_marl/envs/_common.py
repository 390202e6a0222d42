"""Helpers shared by the environment views: action checking and text rendering."""

from __future__ import annotations

import numbers

import numpy as np

from containergym_marl.core.simulator import PlantSimulator


def discrete_action(action, n_actions: int, who: str) -> int:
    """``action`` as a Python int in ``[0, n_actions)``; a clear error for anything else.

    Accepts Python and numpy integers and integer arrays holding one value (shape ``()`` as SB3's
    ``predict`` returns for one observation, or ``(1,)``). Floats and bools are rejected rather
    than silently truncated or cast.
    """
    value = action
    if isinstance(value, np.ndarray):
        if value.shape not in ((), (1,)):
            raise ValueError(f"{who}: expected a single integer action, got an array of shape {value.shape}")
        value = value.reshape(()).item() if np.issubdtype(value.dtype, np.integer) else value
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral):
        raise TypeError(f"{who}: expected an integer action in [0, {n_actions - 1}], got {action!r} "
                        f"({type(action).__name__})")
    value = int(value)
    if not 0 <= value < n_actions:
        raise ValueError(f"{who}: action {value} out of range [0, {n_actions - 1}]")
    return value


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
