"""DAgger: the shared container-agent policy imitates the rollout planner in the states it visits
itself (Ross, Gordon & Bagnell, 2011), then, for ``dagger_ppo_agents``, the native PPO fine-tunes it.

Five registry entries train with it (``containergym-marl train --algo ...``, ``compare``, the sweep):

* ``dagger_agents``: DAgger for the whole budget;
* ``dagger_response_agents``: ``dagger_agents`` with ``labels=response`` (below);
* ``dagger_contended_agents``: ``dagger_agents`` with ``contended_share`` 0.5 (below);
* ``dagger_dapg_agents``: ``dagger_ppo_agents`` whose fine-tuning keeps a behaviour-cloning term on
  the imitation's data set beside PPO's loss (DAPG, Rajeswaran et al., 2018), ``bc_coef`` × the
  cross-entropy, its weight halving every ``bc_half_life`` of the fine-tuning's samples, so that PPO
  starts from the imitation without leaving it at its first updates and ends on its own objective;
* ``dagger_ppo_agents``: DAgger for ``imitation_share`` of the budget (default 0.5), then
  ``fast_shared_ppo``'s trainer (:mod:`~containergym_marl.training.fast_ppo`) from the imitated
  policy for the rest, in the same run and budget, every agent rewarded with the plant's reward
  (``--reward-mode team``, its default; ``individual`` as for ``fast_shared_ppo``). Both defaults
  were chosen on validation episodes (``studies/dagger_tuning.py``, the ``ppo_*`` variants): with
  each container's own reward the fine-tuning overflowed about three times as often on n16_m2, and
  with a fifth of the budget imitated it fell below the imitation on n11_m11_dt60.

The policy is ``fast_shared_ppo``'s :class:`~containergym_marl.policies.actor_critic.ActorCritic`:
one network shared by every container agent, acting on the agent's own observation (the
decentralised view's, ``Discrete(2)``), so it is evaluated by the same adapter and decides by one
forward of a [64, 64] MLP for all agents. Only the labels come from the global state.

**What the student sees** (``observation``, :data:`~containergym_marl.core.observations.OBSERVATIONS`):
the container agents' observation variant its env builds, ``"local"`` (the view's usual
observation) unless set, e.g. ``--hp observation=global``: the global state besides (an oracle),
``history4`` (the last 4 observations stacked), ``broadcast`` (last step's requests and grants of
every container). The model records it, and its evaluation builds the same observation
(``studies/coordination_ablation.py`` compares them).

**One iteration** (:func:`learn`):

1. *act*: ``n_steps`` steps of every simulation. The container agents act with the shared policy
   (its most likely action, as the paper's test protocol and every evaluation act, or with
   ``request_threshold`` τ a request wherever its probability is above τ, the model's rule in every
   evaluation too; ``greedy=false`` for a sample from it, as PPO's rollouts); in the first
   ``expert_iterations`` the planner acts instead: β = 1, then β = 0, the schedule Ross et al. use
   in practice, so the first data set is behaviour cloning on the expert's own states.
2. *label*: in every visited state ``planner_agents`` (:class:`~containergym_marl.policies.planner.PlannerAgents`
   with its defaults, the reference the method is measured against) decides for all agents from the
   global state; agent i's label is 1 where the planner would have container i request. One planner
   per simulation, reset with the simulation's seed, as an evaluation resets it: the labels are
   what ``planner_agents`` decides in the same states. With ``labels=response``
   (``dagger_response_agents``), where the learner acts agent i's label is instead its best
   response to the other agents' requests as the learner made them: whether the planner's
   look-ahead values those requests higher with i's request on or off, the plant's arbitration
   deciding which are granted (:meth:`~containergym_marl.policies.planner.PlannerAgents.respond`).
   The planner's own decision never has more requests than free PUs, so its labels cannot teach an
   agent what its request does when the others' requests already take every free PU, which is
   where the imitation's overflows on the contended plants begin (a denied request).
3. *aggregate*: the (observation, label) pairs join the data set, each flagged where its state was
   contended (:meth:`~containergym_marl.policies.planner.PlannerAgents.contended`: a PU free and more
   containers due than free PUs); the latest ``dataset_size`` are kept (DAgger keeps all;
   the cap bounds memory and the checkpoint).
4. *train*: ``n_epochs`` × new samples / ``minibatch_size`` Adam steps, each on a minibatch drawn
   from the whole data set (with ``contended_share``, ``dagger_contended_agents``, that share of it
   from the contended samples): the cross-entropy of the policy's logits against the labels (requests
   weighted by ``request_weight``; the step size annealed to 0 with ``anneal_lr``). The value
   network regresses on the λ-returns of this iteration's rollout at the same time (the agents'
   rewards, time-limit cuts bootstrapped as PPO does), so a PPO fine-tuning starts from a critic of
   the imitated policy: a random critic's advantages would drive its first updates away from it.

**Budget and cost.** Samples are agent steps, as for ``fast_shared_ppo`` (a simulation step of an
n-container plant is n samples), whoever acted. Labelling costs the planner's decision per
simulation step (about 1–2 ms of CPU where it plans; nothing when no PU is free or no container is
eligible); its CPU seconds are recorded in ``imitation.json`` (per iteration) and in run.json's
``"imitation"``, so the training cost per seed can be reported with and without them.

**Best model.** The 100-episode training return of episodes the learner played from start to end
(episodes in which the planner acted are not the policy's and are neither counted nor windowed), as
for the native PPO; after the fine-tuning starts, PPO's training episodes continue the same window.

**Run directory and resume** as the native PPO's: tensor-only ``best_model.pt`` / ``final_model.pt``
(``ActorCritic``) and checkpoints ``checkpoints/ckpt_<S>_steps.pt`` (model, optimiser, generator,
iteration, the per-iteration record) every checkpoint interval. The data set of the newest
checkpoint is kept beside it (``ckpt_dataset_<S>_steps.pt``; older ones are removed, and the last
when imitation ends: it is the size of a replay buffer); a resume from a checkpoint without one
continues with an empty data set, with a warning. A checkpoint of the fine-tuning phase is the native PPO's. All randomness comes from the
run's seed: the simulations (``seed + b``, ``seed + samples`` after a resume or the switch to PPO),
the planners (seeded like their simulations) and one ``torch.Generator`` (initialisation, action
samples, minibatches).
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from containergym_marl.config.bounds import (
    MAX_DATASET_SIZE,
    MAX_EPOCHS,
    MAX_MINIBATCH,
    MAX_N_STEPS,
    MAX_PLANNER_FUTURES,
    MAX_PLANNER_HORIZON,
    check_count,
)
from containergym_marl.core.observations import DEFAULT_OBSERVATION, check_observation, check_same_observation
from containergym_marl.files import atomic_write_text
from containergym_marl.policies.actor_critic import ActorCritic, check_request_threshold, load_tensors, save_tensors
from containergym_marl.policies.planner import SHIELD, PlannerAgents, decide_all, respond_all
from containergym_marl.policies.safety import own_check_setting, own_deadline_due
from containergym_marl.policies.shared_check import SHARED_CHECK, SharedCheck, shared_check_setting
from containergym_marl.rundir import RunError, RunWarning
from containergym_marl.training import fast_ppo
from containergym_marl.training.checkpoints import SegmentClock, TrainingProgress, save_checkpoint
from containergym_marl.training.native import MemoryShapes

CHECKPOINT_FORMAT = "containergym-marl dagger checkpoint"
DATASET_FORMAT = "containergym-marl dagger dataset"
CHECKPOINT_VERSION = 1
#: The share of the budget that ``dagger_ppo_agents`` imitates before PPO takes over, unless ``imitation_share``.
FINE_TUNE_IMITATION_SHARE = 0.5
#: DAgger's settings of the fine-tuning, refused where there is none.
FINE_TUNE_SETTINGS = ("imitation_share", "bc_coef", "bc_half_life")
#: The imitation's data set, kept for the fine-tuning's behaviour-cloning term (``bc_coef``), in ``checkpoints/``.
BC_DATASET = "bc_dataset.pt"
#: PPO settings a fine-tuning takes from the imitated model, not from ``ppo_<key>``.
MODEL_SETTINGS = ("hidden", "action_mask", "own_check_risk", "own_check_lead_steps")
#: The record of the imitation phase in the run directory, rewritten after every iteration.
RECORD = "imitation.json"
#: What an agent's label is: the planner's decision for all agents (``planner``), or the agent's best
#: response to the others' requests as the learner made them (``response``: the arbitration counted).
LABELS = ("planner", "response")


@dataclass(frozen=True)
class DAggerArgs:
    """DAgger's settings (``--hp KEY=VALUE``); ``dagger_ppo_agents`` also takes ``imitation_share``
    and the native PPO's settings as ``ppo_<field>`` (e.g. ``ppo_learning_rate=1e-4``)."""

    n_steps: int = 64  # steps of every simulation per iteration: n_envs × n × n_steps new samples
    n_epochs: int = 4  # Adam steps per iteration = n_epochs × new samples / minibatch_size
    minibatch_size: int = 1024  # samples per Adam step, drawn from the whole data set
    learning_rate: float = 1e-3  # Adam's step size (constant unless anneal_lr)
    anneal_lr: bool = False  # the step size decays linearly to 0 over the imitation budget
    # weight of the request class (label 1) in the cross-entropy: the planner requests in only 1-2 % of
    # agent steps, and a missed request under contention is what overflows
    request_weight: float = 1.0
    adam_eps: float = 1e-5  # Adam's eps (the native PPO's)
    max_grad_norm: float = 0.5  # gradient norm clip (the native PPO's)
    vf_coef: float = 0.5  # weight of the value loss (λ-returns of the acting policy)
    gae_lambda: float = 0.95  # λ of the value targets
    expert_iterations: int = 1  # first iterations in which the planner acts (β = 1), the learner after them (β = 0)
    # the learner acts by its most likely action, as it is evaluated (false: by a sample, as PPO's rollouts),
    # so the data set holds the states the deployed policy meets (DAgger's rule); over 5 seeds on validation
    # episodes it scored as sampling on n11_m2_dt60 and higher on n11_m2_dt120 (studies/dagger_tuning.py)
    greedy: bool = True
    dataset_size: int = 1_000_000  # most recent labelled samples kept (each F float32 + 2 bytes)
    hidden: tuple[int, ...] = (64, 64)  # hidden units of the policy and value networks (fast_shared_ppo's)
    futures: int = 16  # K of the labelling planner (planner_agents' default)
    horizon: int = 8  # H of the labelling planner (planner_agents' default)
    # the labelling planner's deadline check (PlannerAgents' safety_risk, ε): 0 is off, planner_agents' labels;
    # 1e-6 labels with the reference, planner_agents_shielded (policies.planner.SHIELD), whose decisions near an
    # overflow empty the containers that could not otherwise be emptied in time
    safety_risk: float = 0.0
    # the student's own deadline check (policies.safety.own_deadline_due), part of the trained policy wherever it
    # acts: an agent whose own observation says its container would overflow within own_check_lead_steps + 1 fills
    # with probability above own_check_risk asks for a free PU; 0 is no check. The imitation alone (no fine-tuning)
    own_check_risk: float = 0.0
    own_check_lead_steps: int = 1
    # the student's greedy decision rule, part of the trained policy wherever it acts greedily (ActorCritic.greedy):
    # an agent requests where its probability of requesting is above this, 0.5 being the most likely action. The
    # labels of similar-looking agent states differ (the planner sees the whole plant), so the network learns the
    # share in which the planner requests. The imitation alone, acting greedily
    request_threshold: float = 0.5
    # the agents' shared check (policies.shared_check): one message per agent and step (its container's volume and
    # its log-odds of requesting) and one rule all apply to them, part of the trained policy wherever it acts:
    # denied requests withdrawn, unsafe emptyings (the deadline check at this risk, over this window) replaced by
    # the safe set the policy prefers (shared_check_prefer); 0 is no check. The imitation alone
    shared_check_risk: float = 0.0
    shared_check_window_steps: int = 24
    shared_check_prefer: str = "policy"
    imitation_share: float = 1.0  # share of the budget DAgger trains; dagger_ppo_agents: 0.5, PPO the rest
    # the fine-tuning's behaviour-cloning term (DAPG): bc_coef × the cross-entropy on the imitation's data set beside
    # PPO's loss, its weight halving every bc_half_life of the fine-tuning's samples; 0: PPO alone
    bc_coef: float = 0.0
    bc_half_life: float = 0.1
    # what every container agent sees (core.observations.OBSERVATIONS): the view's usual observation, or it with
    # the global state (an oracle), the last 4 observations stacked, or last step's requests and grants of all
    observation: str = DEFAULT_OBSERVATION
    # each agent's label (LABELS): the planner's decision for all agents, or, where the learner acts, its best
    # response by the planner's look-ahead to the other agents' requests as the learner made them
    labels: str = "planner"
    # share of every minibatch drawn from the data set's contended samples (PlannerAgents.contended: a PU is free
    # and more containers are due than PUs are free), the rest uniformly from all; 0: uniform
    # (DAgger's rule). The contended states are few, and which agent asks there is what the contended plants need
    contended_share: float = 0.0
    ppo: fast_ppo.PPOArgs | None = None  # the fine-tuning's settings (``ppo_<field>``); None: no fine-tuning

    @classmethod
    def from_hyperparams(cls, hyperparams: dict[str, Any], fine_tune: bool = False) -> "DAggerArgs":
        """The settings with ``hyperparams`` applied (``fine_tune``: with a PPO phase); a ValueError
        naming an unknown key or a bad value."""
        own = {f.name: f for f in dataclasses.fields(cls) if f.name != "ppo"}
        if not fine_tune:
            for key in FINE_TUNE_SETTINGS:
                own.pop(key)
        ppo_fields = {f"ppo_{f.name}" for f in dataclasses.fields(fast_ppo.PPOArgs)} if fine_tune else set()
        taken = sorted(k for k in hyperparams if k in ppo_fields and k[4:] in MODEL_SETTINGS)
        if taken:
            raise ValueError(f"hp: {taken} cannot be set: the fine-tuning keeps the imitated model (its network "
                             f"and its own check)")
        unknown = sorted(k for k in hyperparams if k not in own and k not in ppo_fields)
        if unknown:
            choices = sorted(own) + sorted(ppo_fields - {f"ppo_{k}" for k in MODEL_SETTINGS})
            raise ValueError(f"hp: unknown DAgger setting(s) {unknown}; choose from {choices}")
        ppo_keys = {k[4:]: v for k, v in hyperparams.items() if k in ppo_fields}
        values: dict[str, Any] = {"imitation_share": FINE_TUNE_IMITATION_SHARE} if fine_tune else {}
        for key, value in hyperparams.items():
            if key in own:
                values[key] = fast_ppo.coerce_setting(key, value, getattr(cls, key) if key != "hidden" else cls.hidden)
        if fine_tune:
            try:
                values["ppo"] = fast_ppo.PPOArgs.from_hyperparams(ppo_keys)
            except ValueError as exc:  # name the key as it was given
                raise ValueError(str(exc).replace("hp: ", "hp: ppo_", 1)) from None
        args = cls(**values)
        args.validate()
        return args

    def validate(self) -> None:
        """Every setting within its bounds (:mod:`containergym_marl.config.bounds`), checked before
        anything is allocated or written; a ValueError naming it otherwise."""
        for name, hi in (("n_steps", MAX_N_STEPS), ("n_epochs", MAX_EPOCHS), ("minibatch_size", MAX_MINIBATCH),
                         ("dataset_size", MAX_DATASET_SIZE), ("futures", MAX_PLANNER_FUTURES),
                         ("horizon", MAX_PLANNER_HORIZON)):
            check_count(getattr(self, name), 1, hi, f"hp: {name}")
        if self.expert_iterations < 0:
            raise ValueError(f"hp: expert_iterations must be >= 0, got {self.expert_iterations}")
        for name in ("learning_rate", "adam_eps", "max_grad_norm"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"hp: {name} must be a finite number > 0, got {value}")
        if not (math.isfinite(self.request_weight) and self.request_weight > 0):
            raise ValueError(f"hp: request_weight must be a finite number > 0, got {self.request_weight}")
        if not (math.isfinite(self.vf_coef) and self.vf_coef >= 0):
            raise ValueError(f"hp: vf_coef must be a finite number >= 0, got {self.vf_coef}")
        if not 0 <= self.gae_lambda <= 1:
            raise ValueError(f"hp: gae_lambda must be in [0, 1], got {self.gae_lambda}")
        if not 0 <= self.contended_share < 1:
            raise ValueError(f"hp: contended_share must be in [0, 1), got {self.contended_share}")
        if self.ppo is not None and not 0 < self.imitation_share < 1:
            raise ValueError(f"hp: imitation_share must be in (0, 1), got {self.imitation_share}")
        if not (math.isfinite(self.bc_coef) and self.bc_coef >= 0):
            raise ValueError(f"hp: bc_coef must be a finite number >= 0, got {self.bc_coef}")
        if not (math.isfinite(self.bc_half_life) and self.bc_half_life > 0):
            raise ValueError(f"hp: bc_half_life must be a finite number > 0, got {self.bc_half_life}")
        fast_ppo.check_hidden(self.hidden)
        check_observation(self.observation, "hp: observation")
        if self.labels not in LABELS:
            raise ValueError(f"hp: labels must be one of {LABELS}, got {self.labels!r}")
        if not (math.isfinite(self.safety_risk) and 0 <= self.safety_risk < 1):
            raise ValueError(f"hp: safety_risk must be a probability in [0, 1) (0: no deadline check), "
                             f"got {self.safety_risk}")
        self.own_check()  # its two settings within their ranges
        check_request_threshold(self.request_threshold, "hp: request_threshold")
        if self.request_threshold != 0.5 and (self.ppo is not None or not self.greedy):
            raise ValueError("hp: request_threshold is the imitation's greedy decision rule: it takes greedy=true and "
                             "no fine-tuning (PPO's updates learn from sampled actions)")
        self.shared_check()  # its three settings within their ranges
        if self.shared_check_risk > 0 and self.ppo is not None:
            raise ValueError("hp: shared_check_risk applies to the imitation alone: a rule that overrides the sampled "
                             "actions would make PPO's fine-tuning learn from actions its policy did not take")
        if self.own_check_risk > 0 and self.ppo is not None:
            raise ValueError("hp: own_check_risk applies to the imitation alone: a check that overrides the sampled "
                             "actions would make PPO's fine-tuning learn from actions its policy did not take")
        if self.safety_risk > 0 and self.labels != "planner":
            raise ValueError(f"hp: safety_risk applies to the planner's own decisions (labels='planner'); "
                             f"labels={self.labels!r} takes its best responses, which the check does not shield")

    def own_check(self) -> dict[str, Any] | None:
        """The model's own check (:func:`~containergym_marl.policies.safety.check_own_check`), or None."""
        return own_check_setting(self.own_check_risk, self.own_check_lead_steps)

    def shared_check(self) -> dict[str, Any] | None:
        """The model's shared check (:func:`~containergym_marl.policies.shared_check.check_shared_check`), or None."""
        return shared_check_setting(self.shared_check_risk, self.shared_check_window_steps, self.shared_check_prefer)

    def model_threshold(self) -> float | None:
        """The model's request threshold, None where it is 0.5 (the most likely action, as a model without one)."""
        return None if self.request_threshold == 0.5 else self.request_threshold

    def learning_rate_at(self, samples: int, budget: int) -> float:
        """Adam's step size after ``samples`` of an imitation budget of ``budget`` samples."""
        return self.learning_rate * max(1.0 - samples / budget, 0.0) if self.anneal_lr else self.learning_rate

    def imitation_budget(self, budget: int) -> int:
        """The samples DAgger trains of a run's ``budget`` (all of it without fine-tuning)."""
        return budget if self.ppo is None else max(int(round(self.imitation_share * budget)), 1)


# ---- the expert ---------------------------------------------------------------------------------------
class Labeller:
    """``planner_agents`` for every simulation of a vectorised env: planner b is reset with seed
    ``seed + b``, the seed simulation b starts from (later episodes: the planner's own rule, a seed
    from the episode's initial state), as an evaluation of ``planner_agents`` seeds it. Counts the
    CPU seconds it spends."""

    def __init__(self, num_sims: int, hp: DAggerArgs, seed: int):
        shield = {"safety_risk": hp.safety_risk, "safety_horizon_steps": SHIELD["safety_horizon_steps"]} \
            if hp.safety_risk > 0 else {}
        self.planners = [PlannerAgents(futures=hp.futures, horizon=hp.horizon, **shield) for _ in range(num_sims)]
        for b, planner in enumerate(self.planners):
            planner.reset(seed + b)
        self.cpu_s = 0.0

    def label(self, simulator, requests: np.ndarray | None = None) -> np.ndarray:
        """(B, n) bool, in each simulation's current state: the containers the planner has request, or,
        given the agents' ``requests`` ((B, n) bool), each agent's best response to the others'
        (:meth:`~containergym_marl.policies.planner.PlannerAgents.respond`)."""
        t0 = time.process_time()
        state, params = simulator.state, simulator.params
        # every simulation's look-ahead in one batch: the labels each planner alone gives, at a fraction of the cost
        out = (decide_all(self.planners, state, params) if requests is None
               else respond_all(self.planners, state, params, requests))
        self.cpu_s += time.process_time() - t0
        return out

    def contended(self, simulator) -> np.ndarray:
        """(B,) bool: the simulations whose free PUs are contested now (:meth:`PlannerAgents.contended`)."""
        return self.planners[0].contended(simulator.state, simulator.params)

    @property
    def planned(self) -> int:
        """Decisions that needed a look-ahead (the others cost nothing)."""
        return sum(p.planned for p in self.planners)


# ---- the data set and the training state ----------------------------------------------------------------
class Dataset:
    """The aggregated (observation, label, contended) triples: a ring of ``capacity`` samples, the
    oldest replaced first. The storage is reserved, not touched, until filled."""

    def __init__(self, capacity: int, obs_size: int):
        self.obs = torch.empty((capacity, obs_size))
        self.labels = torch.empty(capacity, dtype=torch.uint8)
        self.contended = torch.empty(capacity, dtype=torch.bool)  # the sample's state had contested PUs
        self.size = self.next = 0

    def add(self, obs: torch.Tensor, labels: torch.Tensor, contended: torch.Tensor | None = None) -> None:
        """Append [N, F] observations, [N] labels and [N] contended flags (None: none contended)."""
        capacity = self.labels.shape[0]
        if contended is None:
            contended = torch.zeros(labels.shape[0], dtype=torch.bool)
        obs, labels, contended = obs[-capacity:], labels[-capacity:], contended[-capacity:]
        idx = (self.next + torch.arange(labels.shape[0])) % capacity
        self.obs[idx], self.labels[idx], self.contended[idx] = obs, labels.to(torch.uint8), contended
        self.next = int(idx[-1] + 1) % capacity
        self.size = min(self.size + labels.shape[0], capacity)

    def to_dict(self) -> dict[str, Any]:
        return {"format": DATASET_FORMAT, "version": CHECKPOINT_VERSION, "obs": self.obs[:self.size].clone(),
                "labels": self.labels[:self.size].clone(), "contended": self.contended[:self.size].clone(),
                "next": self.next}

    def load(self, data: Any, source: str) -> None:
        """Fill from :meth:`to_dict`'s output: float32 observations [N, F] of this data set's F, labels
        [N] of 0 and 1 (the two actions), contended flags [N] (bool; a data set saved without them has
        none contended), the ring's next slot in [0, N]; a ValueError naming ``source`` and the field
        when it does not fit (checked before anything is copied)."""
        try:
            if data.get("format") != DATASET_FORMAT or data.get("version") != CHECKPOINT_VERSION:
                raise ValueError("not a DAgger data set of this version")
            obs, labels, next_slot = data["obs"], data["labels"], data["next"]
            if not (torch.is_tensor(obs) and obs.dtype == torch.float32 and obs.dim() == 2
                    and obs.shape[1] == self.obs.shape[1]):
                got = (obs.dtype, tuple(obs.shape)) if torch.is_tensor(obs) else type(obs).__name__
                raise ValueError(f"its observations are {got}, expected float32 (*, {self.obs.shape[1]})")
            if not (torch.is_tensor(labels) and labels.dim() == 1 and labels.shape[0] == obs.shape[0]
                    and not labels.is_floating_point() and not labels.is_complex()):
                got = (labels.dtype, tuple(labels.shape)) if torch.is_tensor(labels) else type(labels).__name__
                raise ValueError(f"its labels are {got}, expected integers ({obs.shape[0]},)")
            if labels.numel() and not (int(labels.min()) >= 0 and int(labels.max()) <= 1):
                raise ValueError(f"its labels must be 0 or 1 (the two actions), got {int(labels.min())} to "
                                 f"{int(labels.max())}")
            if not torch.isfinite(obs).all():
                raise ValueError("its observations are not all finite")
            if type(next_slot) is not int or not 0 <= next_slot <= obs.shape[0]:
                raise ValueError(f"its next slot must be an integer in [0, {obs.shape[0]}], got {next_slot!r}")
            contended = data.get("contended", torch.zeros(obs.shape[0], dtype=torch.bool))
            if not (torch.is_tensor(contended) and contended.dtype == torch.bool
                    and tuple(contended.shape) == (obs.shape[0],)):
                got = (contended.dtype, tuple(contended.shape)) if torch.is_tensor(contended) else type(contended).__name__
                raise ValueError(f"its contended flags are {got}, expected bool ({obs.shape[0]},)")
        except (AttributeError, KeyError, TypeError, ValueError, RuntimeError) as exc:
            raise ValueError(f"{source}: {exc}") from exc
        capacity = self.labels.shape[0]
        kept = min(obs.shape[0], capacity)
        self.obs[:kept], self.labels[:kept], self.contended[:kept] = obs[:kept], labels[:kept], contended[:kept]
        self.size = kept
        self.next = next_slot % capacity if kept == capacity else kept  # the oldest sample, when full


@dataclass
class DAggerState:
    """Everything a resumed run needs besides the run directory's progress files and the data set
    (saved beside the checkpoint). ``save(f)`` writes a tensor-only checkpoint."""

    model: ActorCritic
    optimizer: Any
    generator: torch.Generator
    dataset: Dataset
    num_timesteps: int = 0
    iteration: int = 0
    history: list[dict[str, Any]] = field(default_factory=list)  # one row per iteration (imitation.json)
    hyperparams: dict[str, Any] = field(default_factory=dict)

    def save(self, f) -> None:
        torch.save({"format": CHECKPOINT_FORMAT, "version": CHECKPOINT_VERSION, "model": self.model.to_dict(),
                    "optimizer": self.optimizer.state_dict(), "generator": self.generator.get_state(),
                    "num_timesteps": int(self.num_timesteps), "iteration": int(self.iteration),
                    "history": self.history, "hyperparams": self.hyperparams}, f)


def _optimizer(model: ActorCritic, hp: DAggerArgs):
    return torch.optim.Adam(model.net.parameters(), lr=hp.learning_rate, eps=hp.adam_eps, fused=True)


def new_state(env, hp: DAggerArgs, seed: int, meta: dict[str, Any]) -> DAggerState:
    """A fresh shared policy (initialised from ``seed``), its optimiser and an empty data set."""
    generator = torch.Generator().manual_seed(int(seed))
    obs_size = env.observation_space.shape[0]
    check_same_observation(hp.observation, getattr(env, "observation", DEFAULT_OBSERVATION), "the new DAgger model")
    model = ActorCritic("decentralised", obs_size, int(env.action_space.n), hp.hidden,
                        meta={**meta, "expert": "planner_agents"}, generator=generator, observation=hp.observation,
                        own_check=hp.own_check(), request_threshold=hp.model_threshold(),
                        shared_check=hp.shared_check())
    return DAggerState(model, _optimizer(model, hp), generator, Dataset(hp.dataset_size, obs_size),
                       hyperparams=_jsonable(hp))


def _jsonable(hp: DAggerArgs) -> dict[str, Any]:
    return json.loads(json.dumps(dataclasses.asdict(hp)))


def dataset_file(run: Path, steps: int) -> Path:
    return Path(run) / "checkpoints" / f"ckpt_dataset_{steps}_steps.pt"


def _check_resumed_observation(model: ActorCritic, hp: DAggerArgs, source: str) -> None:
    """A RunError (not the ValueError of a broken checkpoint, which a resume sets aside and passes over)
    when the checkpoint's model was trained on another observation than ``hp`` asks for."""
    try:
        check_same_observation(model.observation, hp.observation, f"the model of {source}")
    except ValueError as exc:
        raise RunError(f"{exc} (hp: observation)") from None


def load_checkpoint(path: str | Path, hp: DAggerArgs):
    """The training state saved at ``path`` (tensors only): a :class:`DAggerState` (its data set
    from beside it, or empty with a warning), or, in the fine-tuning phase, the native PPO's; a
    ValueError when it is broken or neither."""
    path = Path(path)
    data = load_tensors(path)
    source = f"checkpoint {str(path)!r}"
    if isinstance(data, dict) and data.get("format") == fast_ppo.CHECKPOINT_FORMAT and hp.ppo is not None:
        state = fast_ppo.load_checkpoint(path, hp.ppo)
        _check_resumed_observation(state.model, hp, source)
        return state
    if not isinstance(data, dict) or data.get("format") != CHECKPOINT_FORMAT:
        raise ValueError(f"{source} is not a DAgger checkpoint (format {CHECKPOINT_FORMAT!r})")
    if data.get("version") != CHECKPOINT_VERSION:
        raise ValueError(f"{source}: version {data.get('version')!r}; this package reads {CHECKPOINT_VERSION}")
    model = ActorCritic.from_dict(data.get("model"), source)
    _check_resumed_observation(model, hp, source)
    optimizer, generator = _optimizer(model, hp), torch.Generator()
    try:
        optimizer.load_state_dict(data["optimizer"])
        generator.set_state(data["generator"])
        steps, iteration, history = int(data["num_timesteps"]), int(data["iteration"]), list(data["history"])
    except (KeyError, TypeError, ValueError, RuntimeError) as exc:
        raise ValueError(f"{source}: its optimiser or generator state is unreadable ({exc})") from exc
    dataset = read_dataset(dataset_file(path.parent.parent, steps), hp.dataset_size, model.observation_size,
                           f"no data set saved with {path.name}", "DAgger continues with an empty one")
    return DAggerState(model, optimizer, generator, dataset or Dataset(hp.dataset_size, model.observation_size),
                       steps, iteration, history, _jsonable(hp))


def read_dataset(path: Path, capacity: int, obs_size: int, missing: str, instead: str) -> Dataset | None:
    """The data set saved at ``path`` (:meth:`Dataset.to_dict`), or None with a warning that says why
    (``missing`` where there is no file) and what training does ``instead``."""
    dataset = Dataset(capacity, obs_size)
    try:
        dataset.load(load_tensors(path, "not a data set"), f"data set {str(path)!r}")
    except (ValueError, FileNotFoundError) as exc:
        warnings.warn(f"{exc if path.is_file() else missing}; {instead}", RunWarning, stacklevel=3)
        return None
    return dataset


# ---- one iteration ----------------------------------------------------------------------------------------
@dataclass
class Rollout:
    """One iteration's data, [T, S] for T steps of S = B × n agent slots (slot b·n + i: agent i of simulation b)."""

    obs: torch.Tensor  # [T, S, F] what each agent saw
    labels: torch.Tensor  # [T, S] its label (1: request): the planner's decision, or the agent's best response
    actions: torch.Tensor  # [T, S] what it did (the learner's action, or the label where the planner acted)
    contended: torch.Tensor  # [T, S] bool: its simulation's free PUs were contested (Labeller.contended)
    rewards: torch.Tensor  # [T, S] its reward, time-limit cuts bootstrapped
    values: torch.Tensor  # [T, S] the critic's value of its observation
    starts: torch.Tensor  # [T, S] 1 where the observation starts an episode
    last_value: torch.Tensor  # [S] after the last step
    last_start: torch.Tensor  # [S]


class Episodes:
    """Training episodes of B simulations: their plant return and length, and whether the planner
    acted in them (then they are not the learner's and are left out of ``progress``)."""

    def __init__(self, num_sims: int, progress: TrainingProgress):
        self.progress = progress
        self.ret, self.length = np.zeros(num_sims), np.zeros(num_sims, dtype=np.int64)
        self.expert = np.zeros(num_sims, dtype=bool)

    def step(self, plant_reward: np.ndarray, done: np.ndarray, truncated: np.ndarray, expert_acted: bool) -> None:
        self.ret += plant_reward
        self.length += 1
        self.expert |= expert_acted
        for b in np.flatnonzero(done).tolist():
            if not self.expert[b]:
                self.progress.add_episode(float(self.ret[b]), int(self.length[b]), bool(truncated[b]))
            self.ret[b], self.length[b], self.expert[b] = 0.0, 0, False


def collect(model: ActorCritic, env, obs: torch.Tensor, episode_start: torch.Tensor, labeller: Labeller,
            n_steps: int, gamma: float, generator: torch.Generator, expert_acts: bool, greedy: bool,
            episodes: Episodes, labels: str = "planner") -> tuple[Rollout, torch.Tensor, torch.Tensor]:
    """``n_steps`` steps of every simulation of ``env`` from observations ``obs``, the planner
    labelling every agent's decision (``labels``, :data:`LABELS`: its own decision, or where the
    learner acts each agent's best response to the learner's other requests); the planner acts where
    ``expert_acts``, the learner otherwise. Returns the rollout, the next observations and their
    episode-start flags."""
    slots = env.num_envs
    buf = {k: torch.zeros((n_steps, slots)) for k in ("rewards", "values", "starts")}
    obs_buf = torch.zeros((n_steps, slots, obs.shape[-1]))
    label_buf = torch.zeros((n_steps, slots), dtype=torch.long)
    act_buf = torch.zeros((n_steps, slots), dtype=torch.long)
    contended_buf = torch.zeros((n_steps, slots), dtype=torch.bool)
    agents = slots // env.num_sims
    shared = None if model.shared_check is None else SharedCheck(
        model.shared_check, env.simulator.params, model.observation, env.simulator.arbitration)
    with torch.no_grad():
        for t in range(n_steps):
            if expert_acts:
                actions = step_labels = torch.from_numpy(labeller.label(env.simulator).reshape(-1).astype(np.int64))
            else:
                logits = model.logits(obs)
                if greedy:
                    actions = model.greedy(logits)
                else:  # Gumbel-max: a sample, from the run's generator
                    actions = (logits - torch.log(-torch.log(torch.rand(logits.shape, generator=generator)))).argmax(-1)
                if model.own_check is not None:  # the check is part of the policy: it acts as deployed
                    actions = torch.where(torch.from_numpy(own_deadline_due(obs.numpy(), **model.own_check)), 1, actions)
                if shared is not None:  # so is the shared check, after it (as the policy adapter applies them)
                    actions = torch.from_numpy(shared.requests_after(obs.numpy(), actions.numpy(), logits))
                requests = None if labels == "planner" else actions.numpy().reshape(env.num_sims, -1).astype(bool)
                made = labeller.label(env.simulator, requests)
                step_labels = torch.from_numpy(made.reshape(-1).astype(np.int64))
            obs_buf[t], label_buf[t], act_buf[t] = obs, step_labels, actions
            contended_buf[t] = torch.from_numpy(np.repeat(labeller.contended(env.simulator), agents))
            buf["values"][t], buf["starts"][t] = model.value(obs), episode_start
            next_obs, rewards, dones, infos = env.step(actions.numpy())
            rewards = torch.from_numpy(rewards)
            if dones.any():  # a time-limit cut is not terminal: bootstrap (as the native PPO)
                cut = [k for k in np.flatnonzero(dones).tolist() if infos[k].get("TimeLimit.truncated")]
                if cut:
                    last = torch.from_numpy(np.stack([infos[k]["terminal_observation"] for k in cut]))
                    rewards[cut] += gamma * model.value(last)
            buf["rewards"][t] = rewards
            episode_start = torch.from_numpy(dones.astype(np.float32))
            obs = torch.from_numpy(next_obs)
            episodes.step(*env.last_plant_step(), env.simulator.last_outcome.truncated, expert_acts)
        last_value = model.value(obs)
    rollout = Rollout(obs_buf, label_buf, act_buf, contended_buf, buf["rewards"], buf["values"], buf["starts"], last_value,
                      episode_start)
    return rollout, obs, episode_start


class MinibatchDraw:
    """Minibatches of ``batch`` indices into ``dataset``, with replacement: ``contended_share`` of
    them (rounded) uniformly from its contended samples, while it has any, the rest uniformly from
    all of it (so a contended sample's share of a minibatch is the share plus the rest's natural
    rate). At ``contended_share`` 0 a draw is ``torch.randint(size, (batch,))``: DAgger's own."""

    def __init__(self, dataset: Dataset, batch: int, contended_share: float):
        self.size, self.batch = dataset.size, batch
        self.contended = torch.nonzero(dataset.contended[:dataset.size]).squeeze(1) if contended_share else None
        has = self.contended is not None and self.contended.numel() > 0
        self.from_contended = round(contended_share * batch) if has else 0

    def __call__(self, generator: torch.Generator) -> torch.Tensor:
        idx = torch.randint(self.size, (self.batch - self.from_contended,), generator=generator)
        if not self.from_contended:
            return idx
        picked = torch.randint(self.contended.numel(), (self.from_contended,), generator=generator)
        return torch.cat([self.contended[picked], idx])


def update(model: ActorCritic, optimizer, hp: DAggerArgs, generator: torch.Generator, dataset: Dataset,
           obs: torch.Tensor, returns: torch.Tensor) -> float:
    """The supervised step of an iteration: ``n_epochs`` × len(obs) / ``minibatch_size`` Adam steps
    on the cross-entropy of minibatches drawn from the whole ``dataset`` (``contended_share`` of each
    from its contended samples, while it has any) plus ``vf_coef`` × the value MSE on minibatches of
    this rollout's (``obs``, ``returns``). Returns the mean cross-entropy."""
    new = obs.shape[0]
    steps = max(hp.n_epochs * new // hp.minibatch_size, 1)
    weight = None if hp.request_weight == 1.0 else torch.tensor([1.0, hp.request_weight])
    draw = MinibatchDraw(dataset, min(hp.minibatch_size, dataset.size), hp.contended_share)
    total = 0.0
    for _ in range(steps):
        idx = draw(generator)
        cross_entropy = torch.nn.functional.cross_entropy(model.logits(dataset.obs[idx]), dataset.labels[idx].long(),
                                                          weight=weight)
        j = torch.randint(new, (min(hp.minibatch_size, new),), generator=generator)
        value_loss = torch.nn.functional.mse_loss(model.value(obs[j]), returns[j])
        loss = cross_entropy + hp.vf_coef * value_loss
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.net.parameters(), hp.max_grad_norm)
        optimizer.step()
        total += cross_entropy.detach().item()
    return total / steps


# ---- the trainer ----------------------------------------------------------------------------------------
def learn(run: Path, state: DAggerState, env, budget: int, gamma: float, hp: DAggerArgs,
          progress: TrainingProgress, interval: int, seed: int, checkpoint_before: int, on_samples=None) -> None:
    """DAgger iterations on ``env`` (a :class:`~containergym_marl.envs.vector.ContainerAgentsVecEnv`)
    until ``budget`` samples; planners seeded from ``seed`` (the simulations' seed). After every
    iteration: a metrics row (and the best model when the training return improved), the record;
    a checkpoint after every iteration that crosses ``interval`` samples, below ``checkpoint_before``."""
    model, optimizer, generator = state.model, state.optimizer, state.generator
    labeller = Labeller(env.num_sims, hp, seed)
    episodes = Episodes(env.num_sims, progress)
    obs, episode_start = torch.from_numpy(env.reset()), torch.ones(env.num_envs)
    clock = SegmentClock(progress)
    cpu0 = state.history[-1]["label_cpu_s"] if state.history else 0.0
    planned0 = state.history[-1]["planned_decisions"] if state.history else 0
    last_checkpoint = state.num_timesteps
    while state.num_timesteps < budget:
        expert_acts = state.iteration < hp.expert_iterations
        rollout, obs, episode_start = collect(model, env, obs, episode_start, labeller, hp.n_steps, gamma, generator,
                                              expert_acts, hp.greedy, episodes, hp.labels)
        returns = fast_ppo.compute_gae(rollout.rewards, rollout.values, rollout.starts, rollout.last_value,
                                       rollout.last_start, gamma, hp.gae_lambda) + rollout.values
        flat_obs, flat_labels = rollout.obs.view(-1, rollout.obs.shape[-1]), rollout.labels.view(-1)
        flat_contended = rollout.contended.view(-1)
        state.num_timesteps += flat_labels.shape[0]
        steps = state.num_timesteps
        with torch.no_grad():  # how far the policy that acted is from the planner, on its own states
            greedy = model.logits(flat_obs).argmax(-1)
        requests = flat_labels == 1
        wall = clock.wall()
        saved_best = fast_ppo.save_if_best(run / "best_model.pt", model, progress, steps)
        fast_ppo.log_rollout(run, progress, steps, wall, saved_best)
        if on_samples is not None:
            on_samples(steps, progress)

        state.dataset.add(flat_obs, flat_labels, flat_contended)
        learning_rate = hp.learning_rate_at(steps - flat_labels.shape[0], budget)
        for group in optimizer.param_groups:
            group["lr"] = learning_rate
        cross_entropy = update(model, optimizer, hp, generator, state.dataset, flat_obs, returns.view(-1))
        state.iteration += 1
        state.history.append({
            "iteration": state.iteration, "timesteps": steps, "expert_acted": expert_acts,
            "dataset_samples": state.dataset.size,
            "agreement": float((greedy == flat_labels).float().mean()),
            "request_share": float(requests.float().mean()),
            "contended_share": float(flat_contended.float().mean()),  # of this rollout's samples
            "request_recall": float((greedy[requests] == 1).float().mean()) if requests.any() else None,
            "cross_entropy": cross_entropy, "learning_rate": learning_rate,
            "label_cpu_s": round(cpu0 + labeller.cpu_s, 3), "planned_decisions": planned0 + labeller.planned,
            "wall_time_s": clock.wall()})
        write_record(run, state, hp)
        clock.update()
        if steps - last_checkpoint >= interval and steps < checkpoint_before:
            save_tensors(dataset_file(run, steps), state.dataset.to_dict())
            last_checkpoint = save_checkpoint(run, state, progress, suffix=".pt")
            for old in (run / "checkpoints").glob("ckpt_dataset_*_steps.pt"):
                if old.name != dataset_file(run, steps).name:  # one data set on disk: the newest checkpoint's
                    old.unlink()
    clock.update()


def write_record(run: Path, state: DAggerState, hp: DAggerArgs) -> None:
    """``imitation.json``: the expert, the totals so far and one row per iteration."""
    last = state.history[-1] if state.history else {}
    atomic_write_text(Path(run) / RECORD, json.dumps({
        # the reference's name where its check is the reference's; another ε is planner_agents with that check
        "expert": "planner_agents_shielded" if hp.safety_risk == SHIELD["safety_risk"] else "planner_agents",
        "futures": hp.futures,
        "horizon": hp.horizon, "safety_risk": hp.safety_risk,
        "samples": state.num_timesteps,
        "label_cpu_s": last.get("label_cpu_s", 0.0), "planned_decisions": last.get("planned_decisions", 0),
        "iterations": state.history}, indent=1))


def summary(run: Path) -> dict[str, Any] | None:
    """What run.json says of the imitation phase: its samples and the planner's labelling cost."""
    path = Path(run) / RECORD
    if not path.is_file():
        return None
    record = json.loads(path.read_text())
    return {k: record[k] for k in ("expert", "samples", "label_cpu_s", "planned_decisions")}


def train(run: Path, state, env, budget: int, gamma: float, hp: DAggerArgs, progress: TrainingProgress,
          interval: int, seed: int, on_samples=None):
    """The run's phases from ``state`` (a :class:`DAggerState`, or a PPO state of a resumed
    fine-tuning) to ``budget`` samples: DAgger to ``hp.imitation_budget(budget)``, then, with
    ``hp.ppo``, the native PPO from the imitated policy. The simulations (and planners) of each
    phase start from ``seed + samples``. Returns the final state."""
    if isinstance(state, DAggerState):
        imitation = hp.imitation_budget(budget)
        if state.num_timesteps < imitation:
            env.seed(seed + state.num_timesteps)
            learn(run, state, env, imitation, gamma, hp, progress, interval, seed + state.num_timesteps, budget,
                  on_samples)
        if hp.ppo is not None and hp.bc_coef > 0:  # before the imitation's checkpointed data sets go
            save_tensors(run / "checkpoints" / BC_DATASET, state.dataset.to_dict())
        for done_with in (run / "checkpoints").glob("ckpt_dataset_*_steps.pt"):
            done_with.unlink()  # imitation is over: a resume from here on needs no data set
        if hp.ppo is None:
            return state
        state = fast_ppo.state_from_model(state.model, hp.ppo, state.generator, state.num_timesteps)
    env.seed(seed + state.num_timesteps)
    fast_ppo.learn(run, state, env, budget, gamma, hp.ppo, progress, interval, on_samples,
                   behaviour_cloning(run, hp, budget, state.model.observation_size))
    return state


def behaviour_cloning(run: Path, hp: DAggerArgs, budget: int, obs_size: int) -> fast_ppo.BehaviourCloning | None:
    """The fine-tuning's behaviour-cloning term on the imitation's data set (saved in the run's
    checkpoints when imitation ended), or None without ``bc_coef``; a warning, and None, when that data
    set is missing or broken (the fine-tuning then continues as PPO alone)."""
    if hp.ppo is None or hp.bc_coef == 0:
        return None
    path = run / "checkpoints" / BC_DATASET
    dataset = read_dataset(path, hp.dataset_size, obs_size, f"no data set {str(path)!r}",
                           "the fine-tuning continues without its behaviour-cloning term")
    if dataset is None:
        return None
    imitation = hp.imitation_budget(budget)
    return fast_ppo.BehaviourCloning(dataset.obs[:dataset.size].clone(), dataset.labels[:dataset.size].long(),
                                     hp.bc_coef, hp.bc_half_life * (budget - imitation), imitation)


class DAggerTrainer:
    """DAgger, and with ``fine_tune`` the native PPO after it, as ``train`` runs them
    (:class:`~containergym_marl.training.native.NativeTrainer`); ``defaults``: the method's own
    settings (``--hp`` overrides them)."""

    def __init__(self, fine_tune: bool, defaults: dict[str, Any] | None = None):
        self.fine_tune, self.defaults = fine_tune, dict(defaults or {})

    def settings(self, hyperparams: dict[str, Any]) -> DAggerArgs:
        return DAggerArgs.from_hyperparams({**self.defaults, **hyperparams}, fine_tune=self.fine_tune)

    def memory(self, settings: DAggerArgs, shapes: MemoryShapes) -> dict[str, int]:
        """The data set (F float32 + 2 bytes a sample), the labelling planner's futures (K × H
        look-ahead of n + 1 candidates), the networks, a rollout and a minibatch; the fine-tuning's
        rollout and minibatch."""
        hp, n, m = settings, shapes.n_containers, shapes.n_pus
        estimate = {f"dataset_size={hp.dataset_size}": hp.dataset_size * (shapes.obs * 4 + 2),
                    f"futures={hp.futures}, horizon={hp.horizon}": hp.futures * (n + 1) * (n + m + hp.horizon) * 8 * 8,
                    f"hidden={list(hp.hidden)}": shapes.networks(hp.hidden),
                    f"n_steps={hp.n_steps}": shapes.rollout(hp.n_steps, shapes.obs + 8, copies=2),
                    f"minibatch_size={hp.minibatch_size}": shapes.minibatch(hp.minibatch_size, 2 * sum(hp.hidden),
                                                                             hp.n_steps)}
        if hp.ppo is not None:  # the fine-tuning keeps the imitated network
            estimate.update(fast_ppo.batch_memory(dataclasses.replace(hp.ppo, hidden=hp.hidden), shapes, "ppo_"))
        return estimate

    def env_options(self, settings: DAggerArgs) -> dict[str, Any]:
        return {"observation": settings.observation}

    def new_state(self, env, settings: DAggerArgs, view: str, seed: int, meta: dict[str, Any]) -> DAggerState:
        return new_state(env, settings, seed, meta)

    def load_checkpoint(self, path: Path, settings: DAggerArgs):
        return load_checkpoint(path, settings)

    def learn(self, run: Path, state, env, budget: int, gamma: float, settings: DAggerArgs,
              progress: TrainingProgress, interval: int, seed: int, on_samples=None):
        return train(run, state, env, budget, gamma, settings, progress, interval, seed, on_samples)

    def save_final(self, state, path: Path) -> None:
        fast_ppo.save_final(state, path)

    def run_summary(self, run: Path) -> dict[str, Any]:
        return {"imitation": summary(run)}


#: The share of each minibatch ``dagger_contended_agents`` draws from the contended samples: half, so
#: that they weigh as much as all the others (a setting to tune on validation episodes, as every other).
CONTENDED_SHARE = 0.5
#: The registry's trainers: ``dagger_agents`` (DAgger alone), ``dagger_ppo_agents`` (then PPO),
#: ``dagger_response_agents`` (DAgger on each agent's best response to the others' requests) and
#: ``dagger_contended_agents`` (DAgger with the contended states oversampled) and ``dagger_dapg_agents``
#: (``dagger_ppo_agents`` with a decaying behaviour-cloning term in the fine-tuning).
IMITATION = DAggerTrainer(fine_tune=False)
IMITATION_THEN_PPO = DAggerTrainer(fine_tune=True)
RESPONSE_IMITATION = DAggerTrainer(fine_tune=False, defaults={"labels": "response"})
CONTENDED_IMITATION = DAggerTrainer(fine_tune=False, defaults={"contended_share": CONTENDED_SHARE})
#: ``dagger_dapg_agents``' behaviour-cloning term: half PPO's weight at first, halving every fifth of the
#: fine-tuning (a 30th of it at the end; settings to tune on validation episodes, as every other).
DAPG_SETTINGS = {"bc_coef": 0.5, "bc_half_life": 0.2}
IMITATION_THEN_DAPG = DAggerTrainer(fine_tune=True, defaults=DAPG_SETTINGS)
#: ``dagger_checked_agents``: DAgger on the reference's labels (planner_agents_shielded's deadline check,
#: policies.planner.SHIELD) with the student's own deadline check and a request threshold of 0.3 in collection
#: and in the trained policy (fast_shared_ppo_checked's check, policies.safety): dagger_tuning's
#: ``greedy_shielded_own_1_threshold_0.3``, which on validation episodes overflowed in none of 90 on n16_m2_dt120
#: where ``greedy_shielded_own_1`` overflowed in 20 of 60 (best models); the threshold by
#: studies/request_threshold.py (the highest sum of the published imitation's shares over the contended rows).
CHECKED_REQUEST_THRESHOLD = 0.3
CHECKED_SETTINGS = {"safety_risk": SHIELD["safety_risk"], **fast_ppo.OWN_CHECK_SETTINGS,
                    "request_threshold": CHECKED_REQUEST_THRESHOLD}
CHECKED_IMITATION = DAggerTrainer(fine_tune=False, defaults=CHECKED_SETTINGS)
#: ``dagger_messaging_agents``: ``dagger_checked_agents`` with the agents' shared check (policies.shared_check) in
#: collection and in the trained policy, at the setting studies/shared_check_screen.py chose on validation episodes
#: for dagger_checked_agents' published networks (SHARED_CHECK).
MESSAGING_SETTINGS = {**CHECKED_SETTINGS, **{f"shared_check_{key}": value for key, value in SHARED_CHECK.items()}}
MESSAGING_IMITATION = DAggerTrainer(fine_tune=False, defaults=MESSAGING_SETTINGS)

__all__ = ["BC_DATASET", "CHECKED_IMITATION", "CHECKED_SETTINGS", "CONTENDED_IMITATION", "CONTENDED_SHARE", "DAPG_SETTINGS", "DAggerArgs", "DAggerState", "DAggerTrainer", "IMITATION", "IMITATION_THEN_DAPG", "IMITATION_THEN_PPO", "LABELS",
           "MESSAGING_IMITATION", "MESSAGING_SETTINGS",
           "RESPONSE_IMITATION", "Dataset", "Episodes",
           "Labeller", "MinibatchDraw", "Rollout", "collect", "learn",
           "load_checkpoint", "new_state", "summary", "train", "update"]
