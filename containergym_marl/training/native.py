"""The interface of the package's own trainers, as ``train`` (and so ``compare`` and the sweep) runs them.

A native algorithm's registry entry (:class:`~containergym_marl.algorithms.AlgorithmSpec`) names its
trainer as ``"module:NAME"``, an object with the methods of :class:`NativeTrainer`, imported when a
run needs it. ``train`` does the rest the same way for every trainer: the run directory, its lock
and ``args.json``, resuming from the newest intact checkpoint, the progress bar, ``run.json`` and
the final model's place. Adding a native algorithm is its trainer's module, its registry line and,
to show it in the results, its line in :mod:`containergym_marl.methods`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Protocol


@dataclass(frozen=True)
class MemoryShapes:
    """The sizes a trainer's memory estimate is made of (float32 throughout): F observation features
    (``obs``), A actions, S slots (samples per vector step: simulations, or agents of all of them),
    the plant's n containers and m PUs."""

    obs: int
    actions: int
    slots: int
    n_containers: int
    n_pus: int

    def networks(self, hidden: tuple[int, ...] | list[int], critic_hidden=None) -> int:
        """A policy and a value network of ``hidden`` units (the critic's own when given): parameters
        × 6 (weights, gradients, Adam's two moments, the saved copies)."""
        from containergym_marl.policies.actor_critic import mlp_parameters

        nets = (list(hidden), list(hidden if critic_hidden is None else critic_hidden))
        return sum(mlp_parameters([self.obs, *widths, out]) for widths, out in zip(nets, (self.actions, 1))) * 4 * 6

    def rollout(self, n_steps: int, per_sample: int, copies: int = 1) -> int:
        """``n_steps`` × S samples of ``per_sample`` floats, ``copies`` times."""
        return n_steps * self.slots * per_sample * 4 * copies

    def minibatch(self, size: int, hidden_units: int, n_steps: int) -> int:
        """A minibatch's inputs and activations, forward and backward."""
        return min(size, n_steps * self.slots) * (self.obs + 4 * hidden_units + self.actions) * 4 * 2


class NativeTrainer(Protocol):
    """What ``train`` calls on a native trainer. ``settings`` is the object :meth:`settings` returns;
    ``state`` whatever the trainer keeps between calls (its model, optimiser, generator, samples
    so far: ``state.num_timesteps``)."""

    def settings(self, hyperparams: dict[str, Any]) -> Any:
        """The settings with ``hyperparams`` (``--hp``, the method's settings file) applied; a
        ValueError naming an unknown key or a bad value, before anything is written."""

    def default_sims(self, settings: Any, agents_per_sim: int) -> int:
        """Simulations a run steps when the caller gives none and the registry entry names no
        ``default_n_envs`` (``agents_per_sim``: 1 for a centralised controller, n for the container
        agents)."""

    def memory(self, settings: Any, shapes: MemoryShapes) -> dict[str, int]:
        """Bytes the run needs beyond its simulations, one entry per setting that sizes them
        (``"n_steps=64"``), what a refusal names."""

    def env_options(self, settings: Any) -> dict[str, Any]:
        """Optional: keyword arguments of the run's vectorised env that the settings choose (DAgger's
        ``observation``, the container agents' observation variant); a trainer without this method
        trains on the env's defaults (:func:`env_options`)."""

    def new_state(self, env, settings: Any, view: str, seed: int, meta: dict[str, Any]) -> Any:
        """A fresh state for ``env`` from ``seed``; ``meta`` goes into the model's header."""

    def load_checkpoint(self, path: Path, settings: Any) -> Any:
        """The state saved at ``path`` (tensors only); a ValueError when it is broken."""

    def learn(self, run: Path, state: Any, env, budget: int, gamma: float, settings: Any, progress,
              interval: int, seed: int, on_samples: Callable | None) -> Any:
        """Train from ``state`` to ``budget`` samples in ``run`` (metrics rows, the best model,
        checkpoints every ``interval`` samples); returns the final state."""

    def save_final(self, state: Any, path: Path) -> None:
        """The final model, at ``path``."""

    def run_summary(self, run: Path) -> dict[str, Any]:
        """Entries ``run.json`` adds for this trainer (``{}``: none)."""


def env_options(trainer: NativeTrainer, settings: Any) -> dict[str, Any]:
    """The env keyword arguments ``trainer``'s ``settings`` choose: its ``env_options``, or ``{}``
    for a trainer without that optional method."""
    method = getattr(trainer, "env_options", None)
    return {} if method is None else dict(method(settings))


__all__ = ["MemoryShapes", "NativeTrainer", "env_options"]
