"""An adapter that lets :func:`~containergym_marl.evaluation.evaluate` run a TorchRL policy trained on
:class:`~containergym_marl.envs.torchrl_env.ContainerAgentsTorchRLEnv` (BenchMARL's MAPPO, IPPO,
QMIX, … or any TensorDict module reading the env's keys) under the paper's test protocol::

    from benchmarl.experiment import Experiment
    from containergym_marl.evaluation import evaluate
    from containergym_marl.policies.torchrl_policy import TorchRLAgentsPolicy

    experiment = Experiment.reload_from_file("…/checkpoints/checkpoint_<frames>.pt")
    result = evaluate(TorchRLAgentsPolicy(experiment.policy, name="mappo"), "n5_m2_dt120")

Each step, the agents' observations from the decentralised view are stacked into the TorchRL env's
layout, a batch of one simulation: ``("container", "observation")`` [1, n, F],
``("container", "action_mask")`` [1, n, 2] and the normalised ``"state"`` [1, n + m], computed
from the same functions the batched env uses, so the policy sees what it saw in training. Actions
are the mode of the policy's distribution (``deterministic=True``, TorchRL's
``ExplorationType.DETERMINISTIC``, as the paper's test protocol asks) or samples from it.

Needs torch and torchrl (the ``clients`` extra).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from containergym_marl.envs.edge import NormalisedState
from containergym_marl.envs.torchrl_env import GROUP
from containergym_marl.extras import missing_extra


class TorchRLAgentsPolicy:
    """A TensorDict policy acting for all container agents at once (one shared call per step).

    Args:
        policy: a callable on a TensorDict that writes ``(group, "action")`` (categorical [1, n]
            or one-hot [1, n, 2]), such as BenchMARL's ``experiment.policy``.
        name: the policy's name in evaluation results.
        group: the agent group the policy was trained for (the env's ``"container"``).
        deterministic: act with the distribution's mode (the test protocol) or sample.
    """

    view = "decentralised"

    def __init__(self, policy: Any, name: str = "torchrl_policy", group: str = GROUP,
                 deterministic: bool = True):
        try:
            import torch
            from tensordict import TensorDict
            from torchrl.envs.utils import ExplorationType, set_exploration_type
        except ImportError as error:
            raise missing_extra("TorchRLAgentsPolicy", "clients", error) from error
        self.policy, self.name, self.group, self.deterministic = policy, name, group, deterministic
        self._torch, self._TensorDict = torch, TensorDict
        mode = ExplorationType.DETERMINISTIC if deterministic else ExplorationType.RANDOM
        self._exploration = lambda: set_exploration_type(mode)
        self._normalise_for: tuple[Any, NormalisedState] | None = None

    def _normalise(self, params) -> NormalisedState:
        if self._normalise_for is None or self._normalise_for[0] is not params:
            self._normalise_for = (params, NormalisedState(params))
        return self._normalise_for[1]

    def inputs(self, observations: dict[str, Any], env: Any):
        """The TensorDict the policy gets for the decentralised view's ``observations``."""
        torch, sim = self._torch, env.simulator
        obs = np.stack([o["observation"] if isinstance(o, dict) else o for o in observations.values()])
        n = obs.shape[0]
        mask = np.ones((1, n, 2), dtype=bool)
        mask[0, :, 1] = bool(sim.free_pu_count()[0] > 0)
        state = self._normalise(sim.params)(sim.global_state())
        group = self._TensorDict({"observation": torch.from_numpy(np.ascontiguousarray(obs, np.float32))[None],
                                  "action_mask": torch.from_numpy(mask)}, batch_size=(1, n))
        return self._TensorDict({self.group: group, "state": torch.from_numpy(state)}, batch_size=(1,))

    def act(self, observations: dict[str, Any], env: Any) -> dict[str, int]:
        td = self.inputs(observations, env)
        with self._torch.no_grad(), self._exploration():
            td = self.policy(td)
        action = td.get((self.group, "action"))[0]
        if action.ndim == 2:  # one-hot
            action = action.to(self._torch.uint8).argmax(-1)
        return {a: int(x) for a, x in zip(observations, action.tolist())}
