"""ContainerGym as a BenchMARL task: BenchMARL's algorithms (MAPPO, IPPO, QMIX, …) on the batched
TorchRL environment (:class:`~containergym_marl.envs.torchrl_env.ContainerAgentsTorchRLEnv`).

One task per built-in plant config, named as the config (``ContainerGymTask.N5_M2_DT120`` is
``"n5_m2_dt120"``)::

    from benchmarl.algorithms import MappoConfig
    from benchmarl.experiment import Experiment, ExperimentConfig
    from benchmarl.models.mlp import MlpConfig
    from containergym_marl.training.benchmarl_task import ContainerGymTask

    task = ContainerGymTask.N5_M2_DT120.get_task()  # or get_task(config={"reward_mode": ..., ...})
    experiment = Experiment(task=task, algorithm_config=MappoConfig.get_from_yaml(),
                            model_config=MlpConfig.get_from_yaml(),
                            critic_model_config=MlpConfig.get_from_yaml(),
                            seed=0, config=ExperimentConfig.get_from_yaml())
    experiment.run()

The task config (:data:`DEFAULT_TASK_CONFIG`, a dict BenchMARL stores with the experiment) is
passed to the environment: ``reward_mode`` (default ``"team"``: every agent gets the plant reward,
so the per-agent episode return that BenchMARL logs, ``collection/container/reward/episode_reward_mean``,
is the plant return), ``arbitration``, ``protocol`` and any plant override of
:func:`~containergym_marl.config.load_config` (e.g. ``episode_length_steps``).

What BenchMARL gets (see the env's module docstring for the keys): one agent group
``"container"`` (parameters shared within it when ``share_policy_params`` is on, BenchMARL's
default), the agents' observations, the action masks (MAPPO/IPPO sample from a masked
categorical; QMIX masks its Q-values), the normalised global ``"state"`` (MAPPO's critic and
QMIX's mixer read it), and the per-agent infos, which BenchMARL logs as
``collection/container/info/*``. The environment is already batched, so BenchMARL's
``on_policy_n_envs_per_worker`` / ``off_policy_n_envs_per_worker`` are its number of simulations
and its ``evaluation_episodes`` run as one batch.

Hydra's command line (``benchmarl/run.py task=...``) only knows BenchMARL's own tasks; with the
Python API above nothing needs registering. A trained policy is evaluated under the paper's test
protocol with :class:`containergym_marl.policies.torchrl_policy.TorchRLAgentsPolicy`.

Needs benchmarl (the ``clients`` extra; checked with BenchMARL 1.5.2, torchrl 0.11.1).
"""

from __future__ import annotations

import copy
from typing import Any, Callable, Dict, List, Optional

try:  # benchmarl is an optional dependency (the clients extra)
    from benchmarl.environments.common import Task, TaskClass
    from benchmarl.utils import _read_yaml_config
    from torchrl.data import Composite
    from torchrl.envs import EnvBase
except ImportError as error:  # a clear message instead of a bare ModuleNotFoundError
    from containergym_marl.extras import missing_extra

    raise missing_extra("containergym_marl.training.benchmarl_task", "clients", error) from error

from containergym_marl.config import list_configs
from containergym_marl.core.dynamics import DEFAULT_ARBITRATION
from containergym_marl.envs.torchrl_env import GROUP, ContainerAgentsTorchRLEnv

#: The environment name of these tasks (BenchMARL's ``env_name``; logs and run names carry it).
ENV_NAME = "containergym"
#: Used when a task is made without a config (``get_task()``).
DEFAULT_TASK_CONFIG: Dict[str, Any] = {"reward_mode": "team", "arbitration": DEFAULT_ARBITRATION}


class ContainerGymTaskClass(TaskClass):
    """How BenchMARL builds and reads a ContainerGym task (BenchMARL's ``TaskClass`` API)."""

    def get_env_fun(self, num_envs: int, continuous_actions: bool, seed: Optional[int],
                    device: Any) -> Callable[[], EnvBase]:
        if continuous_actions:
            raise ValueError("ContainerGym has discrete actions only (0 wait, 1 request emptying)")
        config = copy.deepcopy(self.config)
        plant = self.name.lower()
        return lambda: ContainerAgentsTorchRLEnv(plant, num_envs=num_envs, seed=seed, device=device,
                                                 categorical_actions=True, **config)

    def supports_continuous_actions(self) -> bool:
        return False

    def supports_discrete_actions(self) -> bool:
        return True

    def has_render(self, env: EnvBase) -> bool:
        return False

    def max_steps(self, env: EnvBase) -> int:
        return env.config.episode_length_steps

    def group_map(self, env: EnvBase) -> Dict[str, List[str]]:
        return env.group_map

    def _group_entries(self, env: EnvBase, keep: set[str]) -> Composite:
        spec = env.full_observation_spec_unbatched.clone()
        for key in list(spec[GROUP].keys()):
            if key not in keep:
                del spec[(GROUP, key)]
        del spec["state"]
        return spec

    def observation_spec(self, env: EnvBase) -> Composite:
        return self._group_entries(env, {"observation"})

    def action_mask_spec(self, env: EnvBase) -> Optional[Composite]:
        return self._group_entries(env, {"action_mask"})

    def info_spec(self, env: EnvBase) -> Optional[Composite]:
        return self._group_entries(env, {"info"})

    def state_spec(self, env: EnvBase) -> Optional[Composite]:
        return Composite({"state": env.full_observation_spec_unbatched["state"].clone()})

    def action_spec(self, env: EnvBase) -> Composite:
        return env.full_action_spec_unbatched

    @staticmethod
    def env_name() -> str:
        return ENV_NAME


class _ContainerGymTasks(Task):
    """The ContainerGym tasks, one per built-in plant config (``containergym_marl.list_configs()``)."""

    @staticmethod
    def associated_class():
        return ContainerGymTaskClass

    def get_from_yaml(self, path: Optional[str] = None) -> TaskClass:
        """The task with the config in the YAML file at ``path``, or :data:`DEFAULT_TASK_CONFIG`
        (these tasks have no file in BenchMARL's ``conf/task`` folder)."""
        config = dict(DEFAULT_TASK_CONFIG) if path is None else _read_yaml_config(path)
        return self.get_task(config=config)


#: One member per built-in plant config, named as the config in upper case, generated from
#: ``list_configs()`` so that a plant added to the package is a task without an edit here.
ContainerGymTask = _ContainerGymTasks("ContainerGymTask", [name.upper() for name in list_configs()],
                                      module=__name__, qualname="ContainerGymTask")
