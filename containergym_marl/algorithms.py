"""The training algorithms: one registry entry per algorithm, read by training, evaluation and the CLI.

Each :class:`AlgorithmSpec` says which SB3 / sb3-contrib class trains it (imported only when
needed), which view of the plant it acts on, how many simulations it steps by default, whether it
learns from rollouts (``n_steps`` samples per update) or from a replay buffer, and which policy
adapter evaluates its models. Adding an algorithm = one entry in :data:`REGISTRY`.

``fast_ppo`` and ``fast_shared_ppo`` are the package's own PPO (:mod:`containergym_marl.training.fast_ppo`:
SB3's network and loss, a wider batch), with tensor-only model files (``.pt``); ``dagger_agents`` and
``dagger_ppo_agents`` train ``fast_shared_ppo``'s network by imitating the rollout planner
(:mod:`containergym_marl.training.dagger`), the second then fine-tuning it with the native PPO. An entry with neither
is trained by a script of its own (``trainer``) and only evaluated here: ``mappo`` (BenchMARL's
MAPPO, ``baselines/train_mappo.py``), whose run directories ``containergym-marl evaluate`` reads like
any other. :data:`ALGORITHMS` lists the ones that ``containergym-marl train`` and ``compare`` train.

The methods a comparison holds (these algorithms with their reward modes, the rules and the
planners) are :mod:`containergym_marl.methods`'.
"""

from __future__ import annotations

import importlib
import math
from dataclasses import dataclass
from typing import Any

from containergym_marl.envs.edge import REWARD_MODES
from containergym_marl.extras import missing_extra
from containergym_marl.policies import CentralisedModelPolicy, SharedModelPolicy
from containergym_marl.policies.actor_critic import CentralisedActorCriticPolicy, SharedActorCriticPolicy
from containergym_marl.policies.shared_actor import SharedActorPolicy

#: Samples per policy update of the rollout algorithms (the paper's n_steps with one environment).
ROLLOUT_SAMPLES = 6144


def paper_budget(n_containers: int) -> int:
    """The paper's training budget: 2M samples for n = 5, 5M for n = 11 (section 6.1)."""
    return 2_000_000 if n_containers <= 5 else 5_000_000


def rollout_steps(num_slots: int, minibatch: int = 64, samples: int = ROLLOUT_SAMPLES) -> int:
    """``n_steps`` of a rollout algorithm: about ``samples`` (6144) samples per update, spread over
    ``num_slots`` vectorised slots, with a rollout buffer (``n_steps × num_slots``) that the
    minibatch divides.

    The buffer is divisible by the minibatch exactly when ``n_steps`` is a multiple of
    ``k = minibatch / gcd(num_slots, minibatch)``; of those multiples the one nearest to
    ``samples / num_slots`` is taken (the lower one on a tie, at least ``k`` and at least 2). For
    the centralised algorithms with 8 simulations this is 6144 / 8 = 768, the paper's 6144 samples
    exactly; shared PPO with 8 simulations of n = 5 containers (40 slots) gets 152 (6080 samples
    per update) and of n = 11 (88 slots) 72 (6336), instead of a buffer that SB3 warns about
    (153 × 40 = 6120) and whose last, short minibatch it would train on.
    """
    if num_slots < 1 or minibatch < 1:
        raise ValueError(f"rollout_steps: num_slots and minibatch must be >= 1, got {num_slots}, {minibatch}")
    k = minibatch // math.gcd(num_slots, minibatch)
    target = samples / num_slots
    below = int(target // k) * k
    above = below + k
    n_steps = below if target - below <= above - target else above
    return max(n_steps, k, 2)


@dataclass(frozen=True)
class AlgorithmSpec:
    """One training algorithm.

    Attributes:
        name: the registry key (CLI ``--algo``, run directory names, table rows).
        class_path: ``"module:Class"`` of the SB3 / sb3-contrib algorithm (imported by :meth:`load_class`),
            or None for an algorithm trained outside SB3 (``native``, or by ``trainer``).
        native: ``"module:NAME"`` of the package's own trainer that trains it (a
            :class:`~containergym_marl.training.native.NativeTrainer`, imported by :meth:`trainer`),
            or None.
        policy_adapter: the class that evaluates its models; its ``view`` ("centralised" or
            "decentralised") is the algorithm's view. For a non-SB3 algorithm it also loads them
            (``policy_adapter.load_model(path)``).
        description: one line for help texts and the baseline script.
        default_n_envs: simulations stepped together when the caller gives none; None for a native
            algorithm, whose trainer says how many (the native PPO: as many as give its
            ``rollout_samples`` per update, :meth:`default_sims`).
        rollout: True for on-policy algorithms (``n_steps`` samples per update, see
            :func:`rollout_steps`); False for a replay buffer, which checkpoints then also save.
        minibatch: the minibatch size of a rollout algorithm (passed as ``batch_size``), or None.
        adam_eps: Adam's eps restated in ``optimizer_kwargs`` (SB3's actor-critic policies use 1e-5
            only when given no optimizer arguments); None keeps torch's default.
        reward_modes: the agent reward modes (of :data:`~containergym_marl.envs.edge.REWARD_MODES`) a
            decentralised algorithm can train with (the first is the default); () for centralised
            ones, which train on the plant reward.
        extra_modules: modules it needs beyond torch and stable_baselines3 (for error messages).
        trainer_name: what trains it: ``containergym-marl train`` for the SB3 and native algorithms, a
            script otherwise.
        model_suffix: the suffix of its model files in a run directory (``best_model<suffix>``,
            ``final_model<suffix>``): SB3's ``.zip``, or a torch file (``.pt``).
    """

    name: str
    class_path: str | None
    policy_adapter: type
    description: str
    native: str | None = None
    default_n_envs: int | None = 8
    rollout: bool = True
    minibatch: int | None = 64
    adam_eps: float | None = 1e-5
    reward_modes: tuple[str, ...] = ()
    extra_modules: tuple[str, ...] = ()
    trainer_name: str = "containergym-marl train"
    model_suffix: str = ".zip"

    @property
    def view(self) -> str:
        return self.policy_adapter.view

    @property
    def sb3(self) -> bool:
        """Trained by Stable-Baselines3."""
        return self.class_path is not None

    @property
    def trained_here(self) -> bool:
        """Trained by ``containergym-marl train`` (and ``compare``, the sweep): SB3 or native."""
        return self.sb3 or self.native

    def model_file(self, which: str) -> str:
        """The file name of a run's ``which`` ("best" or "final") model."""
        return f"{which}_model{self.model_suffix}"

    @property
    def default_reward_mode(self) -> str:
        """The agent reward mode it trains with unless told: its first; the environments' default
        (``individual``) for a centralised algorithm, which trains on the plant reward anyway."""
        return self.reward_modes[0] if self.reward_modes else REWARD_MODES[0]

    def method_name(self, reward_mode: str | None = None) -> str:
        """The name of this algorithm trained with ``reward_mode``: its own name for the default mode
        (or none), ``<name>_<mode>`` for another (compare's ``shared_ppo_team``)."""
        if not self.reward_modes or reward_mode in (None, self.default_reward_mode):
            return self.name  # a centralised algorithm trains on the plant reward, whatever the mode says
        return f"{self.name}_{reward_mode}"

    @property
    def replay_buffer(self) -> bool:
        return not self.rollout

    def load_class(self):
        """The SB3 algorithm class, with an error naming the ``train`` extra when it is missing."""
        if not self.sb3:
            raise ValueError(f"{self.name} is not a Stable-Baselines3 algorithm: it is trained by {self.trainer_name}")
        require_training_extra(("stable_baselines3", *self.extra_modules))
        module, cls = self.class_path.split(":")
        return getattr(importlib.import_module(module), cls)

    def trainer(self):
        """The native trainer (:attr:`native`), with an error naming the ``train`` extra when torch
        is missing."""
        if not self.native:
            raise ValueError(f"{self.name} is not trained by a native trainer: it is trained by {self.trainer_name}")
        require_training_extra(())
        module, name = self.native.split(":")
        return getattr(importlib.import_module(module), name)

    def default_sims(self, n_containers: int, hyperparams: dict[str, Any] | None = None, settings=None) -> int:
        """Simulations a run steps when the caller gives none: ``default_n_envs``, or what a native
        trainer asks for with these settings on a plant of ``n_containers`` (the native PPO: as many
        as make about its ``rollout_samples`` per update, fewer for more container agents).
        ``settings``: the trainer's settings when parsed already, else parsed from ``hyperparams``."""
        if self.default_n_envs is not None:
            return self.default_n_envs
        trainer = self.trainer()
        if settings is None:
            settings = trainer.settings(hyperparams or {})
        return trainer.default_sims(settings, self.num_slots(n_containers, 1))

    @property
    def default_sims_text(self) -> str:
        """``default_sims`` in words, for help texts."""
        return str(self.default_n_envs) if self.default_n_envs is not None else "its trainer's"

    def num_slots(self, n_containers: int, num_sims: int) -> int:
        """Vectorised slots (samples per vector step): one per simulation, or one per container
        agent of every simulation for a decentralised algorithm."""
        return num_sims * (n_containers if self.view == "decentralised" else 1)

    def kwargs(self, num_slots: int, gamma: float = 0.99, hyperparams: dict[str, Any] | None = None) -> dict[str, Any]:
        """Keyword arguments of the SB3 class: the paper's settings, then ``hyperparams`` (which win;
        ``policy_kwargs`` key by key)."""
        hyperparams = dict(hyperparams or {})
        kwargs: dict[str, Any] = {"gamma": gamma}
        if self.rollout:
            minibatch = int(hyperparams.get("batch_size", self.minibatch or 64))
            kwargs["n_steps"] = rollout_steps(num_slots, minibatch)
            if self.minibatch is not None:
                kwargs["batch_size"] = self.minibatch
        # Adam's fused CPU kernel: the same update rule as SB3's default Adam, one kernel per step
        # instead of a dozen small ops per parameter tensor; with these small MLPs that makes a
        # PPO run ~25 % faster. (Rounding differs in the last bits, as between any two Adam kernels.)
        optimizer_kwargs: dict[str, Any] = {"fused": True}
        if self.adam_eps is not None:
            optimizer_kwargs["eps"] = self.adam_eps
        kwargs["policy_kwargs"] = {"optimizer_kwargs": optimizer_kwargs}
        for key, value in hyperparams.items():
            if key == "policy_kwargs":
                kwargs["policy_kwargs"] = {**kwargs["policy_kwargs"], **value}
            else:
                kwargs[key] = value
        return kwargs

    def policy(self, model: Any, name: str, deterministic: bool = True):
        """The evaluation policy of one of its models."""
        return self.policy_adapter(model, name=name, deterministic=deterministic)


_PPO = "containergym_marl.training.fast_ppo:TRAINER"
#: what every native entry shares: tensor-only model files, the trainer's own simulations and minibatches
_NATIVE = {"default_n_envs": None, "minibatch": None, "adam_eps": None, "model_suffix": ".pt"}

REGISTRY: dict[str, AlgorithmSpec] = {
    spec.name: spec
    for spec in (
        AlgorithmSpec("ppo", "stable_baselines3:PPO", CentralisedModelPolicy,
                      "centralised PPO: one controller picks which container to empty"),
        AlgorithmSpec("trpo", "sb3_contrib:TRPO", CentralisedModelPolicy,
                      "centralised TRPO (sb3-contrib)", minibatch=128, extra_modules=("sb3_contrib",)),
        AlgorithmSpec("dqn", "stable_baselines3:DQN", CentralisedModelPolicy,
                      "centralised DQN with SB3's defaults (one environment, replay buffer of 1M)",
                      default_n_envs=1, rollout=False, minibatch=None, adam_eps=None),
        AlgorithmSpec("maskable_ppo", "sb3_contrib:MaskablePPO", CentralisedModelPolicy,
                      "centralised PPO that never empties while no PU is free (action masks)",
                      extra_modules=("sb3_contrib",)),
        AlgorithmSpec("shared_ppo", "stable_baselines3:PPO", SharedModelPolicy,
                      "decentralised PPO: one policy shared by every container agent",
                      reward_modes=REWARD_MODES),
        AlgorithmSpec("fast_ppo", None, CentralisedActorCriticPolicy,
                      "centralised PPO, native trainer: SB3's network and loss, about 4096 samples per update "
                      "in minibatches of 1024", native=_PPO, **_NATIVE),
        AlgorithmSpec("fast_shared_ppo", None, SharedActorCriticPolicy,
                      "decentralised PPO, native trainer: one policy shared by every container agent, "
                      "about 4096 samples per update whatever the plant's size, minibatches of 1024", native=_PPO,
                      reward_modes=REWARD_MODES, **_NATIVE),
        AlgorithmSpec("fast_shared_ppo_checked", None, SharedActorCriticPolicy,
                      "fast_shared_ppo with the agents' own check, a rule in the policy: an agent's request is "
                      "made wherever its own observation says its container may overflow within two fills",
                      native="containergym_marl.training.fast_ppo:CHECKED_TRAINER", reward_modes=REWARD_MODES,
                      **_NATIVE),
        AlgorithmSpec("dagger_agents", None, SharedActorCriticPolicy,
                      "decentralised imitation of planner_agents (DAgger): fast_shared_ppo's shared policy, "
                      "trained on the planner's decisions in the states it visits itself",
                      native="containergym_marl.training.dagger:IMITATION", **{**_NATIVE, "default_n_envs": 64}),
        AlgorithmSpec("dagger_response_agents", None, SharedActorCriticPolicy,
                      "dagger_agents labelled by each agent's best response to the others' requests as the "
                      "policy made them (the planner's look-ahead, the arbitration counted)",
                      native="containergym_marl.training.dagger:RESPONSE_IMITATION",
                      **{**_NATIVE, "default_n_envs": 64}),
        AlgorithmSpec("dagger_contended_agents", None, SharedActorCriticPolicy,
                      "dagger_agents with the contended states oversampled: half of every minibatch from "
                      "the states where more containers are due than PUs are free",
                      native="containergym_marl.training.dagger:CONTENDED_IMITATION",
                      **{**_NATIVE, "default_n_envs": 64}),
        AlgorithmSpec("dagger_checked_agents", None, SharedActorCriticPolicy,
                      "dagger_agents on the labels of planner_agents_shielded (the reference), with the agents' "
                      "own check, a rule in the policy: an agent's request is made wherever its own observation "
                      "says its container may overflow within two fills, or its request probability is above 0.3",
                      native="containergym_marl.training.dagger:CHECKED_IMITATION",
                      **{**_NATIVE, "default_n_envs": 64}),
        AlgorithmSpec("dagger_messaging_agents", None, SharedActorCriticPolicy,
                      "dagger_checked_agents whose agents send one message each a step (the container's volume, "
                      "the log-odds of requesting) and apply one shared rule to all: requests the arbitration would "
                      "deny are withdrawn, unsafe emptyings replaced by the safe set the policy prefers",
                      native="containergym_marl.training.dagger:MESSAGING_IMITATION",
                      **{**_NATIVE, "default_n_envs": 64}),
        # the fine-tuning's default reward is the plant's, the objective the planner it imitates plans for
        AlgorithmSpec("dagger_ppo_agents", None, SharedActorCriticPolicy,
                      "dagger_agents for half the budget, then fast_shared_ppo from the imitated policy, "
                      "every agent rewarded with the plant's reward",
                      native="containergym_marl.training.dagger:IMITATION_THEN_PPO",
                      reward_modes=("team", "individual"), **{**_NATIVE, "default_n_envs": 64}),
        AlgorithmSpec("dagger_dapg_agents", None, SharedActorCriticPolicy,
                      "dagger_ppo_agents whose fine-tuning keeps a decaying behaviour-cloning term on the "
                      "imitation's data set beside PPO's loss (DAPG)",
                      native="containergym_marl.training.dagger:IMITATION_THEN_DAPG",
                      reward_modes=("team", "individual"), **{**_NATIVE, "default_n_envs": 64}),
        AlgorithmSpec("mappo", None, SharedActorPolicy,
                      "MAPPO (BenchMARL, CTDE): one actor shared by the container agents, a critic on the "
                      "global state; team reward (its settings are BenchMARL's, in the script)",
                      reward_modes=("team",), extra_modules=("benchmarl",), trainer_name="baselines/train_mappo.py",
                      model_suffix=".pt"),
    )
}
#: The names of the algorithms that ``containergym-marl train --algo`` and ``compare`` train (SB3 and
#: native), in registry order. The other entries (mappo) are trained by their own script.
ALGORITHMS: tuple[str, ...] = tuple(name for name, spec in REGISTRY.items() if spec.trained_here)


def get_algorithm(name: str) -> AlgorithmSpec:
    """The registry entry of ``name``; a ValueError naming the choices for an unknown one."""
    try:
        return REGISTRY[name]
    except (KeyError, TypeError):
        raise ValueError(f"algo: unknown algorithm {name!r}; choose one of {tuple(REGISTRY)}") from None


def require_training_extra(modules: tuple[str, ...] = ("stable_baselines3",)) -> None:
    """Import torch and ``modules``; a :class:`MissingExtraError` naming the ``train`` extra when one
    is missing."""
    for module in ("torch", *modules):
        try:
            importlib.import_module(module)
        except ImportError as exc:
            raise missing_extra("training and evaluating trained models", "train", exc) from exc
