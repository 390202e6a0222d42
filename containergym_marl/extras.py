"""Optional dependencies: which extra installs what, and the one error that names it.

The core (physics, both views, the Gymnasium vector env) needs numpy, numba, Gymnasium and
PettingZoo only. Everything else comes with an extra of the package, and code that needs a missing
one raises :class:`MissingExtraError` saying which extra to install, never a bare
``ModuleNotFoundError``.
"""

from __future__ import annotations

#: extra -> the command that installs it
INSTALL = {
    "train": "pip install 'containergym-marl[train]'",  # torch, SB3, sb3-contrib, SuperSuit
    "sweep": "pip install 'containergym-marl[train,sweep]'",  # Ray, for compare's sweeps
    "clients": "pip install 'containergym-marl[clients]'",  # TorchRL, BenchMARL, Tianshou, RLlib
    "notebook": "pip install 'containergym-marl[notebook]'",  # ipywidgets, for progress rows in Jupyter
    "offline": "pip install 'containergym-marl[offline]'",  # Minari (with h5py and jax), for the demonstrations
}


class MissingExtraError(ImportError):
    """An optional dependency is not installed; the message names the extra that installs it."""


def missing_extra(what: str, extra: str, error: ImportError) -> MissingExtraError:
    """The error for ``what`` (e.g. "ContainerAgentsVecEnv is a stable-baselines3 VecEnv and")
    failing to import its dependency with ``error``; raise it ``from error``."""
    missing = getattr(error, "name", None) or "a dependency"
    return MissingExtraError(f"{what} needs {missing}, which is not installed ({error}); "
                             f"install the {extra} extra: {INSTALL[extra]}")
