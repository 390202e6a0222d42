"""Native PPO: Stable-Baselines3's PPO (network, loss, defaults) on the package's batched simulations,
with a batch shape that keeps the CPU busy with samples rather than with tiny gradient steps.

Two registry entries train with it (``containergym-marl train --algo ...``, ``compare``, the sweep):

* ``fast_ppo``: the centralised controller, ``Discrete(n + 1)``, on the global state;
* ``fast_shared_ppo``: one policy shared by every container agent (``Discrete(2)`` on the agent's own
  observation), with ``--reward-mode individual`` (method ``fast_shared_ppo``) or ``team``
  (``fast_shared_ppo_team``).

What is SB3's, unchanged: separate [64, 64] tanh policy and value networks with orthogonal
initialisation; the clipped surrogate (0.2) plus 0.5 × the value MSE, no entropy bonus; advantages
normalised per minibatch; GAE (λ 0.95, γ 0.99); Adam (3e-4, eps 1e-5) with the gradient norm
clipped at 0.5; 10 epochs per rollout; a time-limit cut bootstrapped with the value of the last
observation (``TimeLimit.truncated``), an overflow not. What differs is the batch shape
(:class:`PPOArgs`): SB3's paper runs step 8 simulations for about 6144 samples per rollout and take
minibatches of 64; here a rollout is 64 steps of as many simulations as make about
``rollout_samples`` (4096) samples, whatever the plant's size (64 simulations for the controller; 13,
6 and 4 for the container agents of 5, 11 and 16 containers, one sample per agent), and minibatches
of 1024 take 16× fewer gradient steps per sample, each on a batch wide enough for the CPU's vector
units. A shape that grew with n (64 simulations for every plant) gave the shared policy 3-7× fewer
updates than SB3's on the same budget, and its policy collapsed before it had learned.
``--n-envs 8 --hp n_steps=768 minibatch_size=64`` is SB3's centralised shape exactly
(``studies/fast_ppo_validation.py paper-shape`` runs it). ``studies/native_ppo_tuning.py``
searches the settings on validation episodes (``results/ppo_tuning/``).

The update is one compiled call (:mod:`~containergym_marl.training.ppo_kernel`: the loss's gradient
in closed form, the networks' backward layer by layer into one flat buffer, the clip and Adam), the
same as autograd's to float rounding; the rollout's policy step is another.

After every update, the run's metrics.csv row carries the update's diagnostics, as SB3 logs them:
entropy, approx-KL, clip fraction, the critic's explained variance, and the share of the last 100
training episodes that reached the time limit rather than overflowing.

Optional: ``--hp action_mask=true`` masks the emptying actions while no PU is free (in training and
in evaluation, the model file records it); ``--hp observation=portable`` (``fast_shared_ppo``) trains
the container agents on another observation variant (:data:`~containergym_marl.core.observations.OBSERVATIONS`:
``portable`` has the same size on every plant, so the policy can act on a plant it was not trained on).

The run directory is the SB3 runs' (:mod:`containergym_marl.rundir`), with tensor-only model
files: ``best_model.pt`` / ``final_model.pt`` (:class:`~containergym_marl.policies.actor_critic.ActorCritic`,
loaded with ``weights_only=True``) and checkpoints ``checkpoints/ckpt_<S>_steps.pt`` that add the
optimiser's state and the sampler's random state. A checkpoint is taken after the update of the
rollout that crossed the interval, so a resumed run continues exactly where it stopped, except
that the simulations get fresh seeds (``seed + samples``, as the SB3 runs). All randomness comes
from the run's seed: the simulations (``seed + b``) and one ``torch.Generator`` for the
initialisation, the action samples and the minibatch order; with one torch thread the same seed
gives the same metrics and model on the same machine.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from containergym_marl.config.bounds import (
    MAX_EPOCHS,
    MAX_HIDDEN_LAYERS,
    MAX_HIDDEN_WIDTH,
    MAX_MINIBATCH,
    MAX_N_STEPS,
    MAX_OVERFLOW_REWARD_SCALE,
    MAX_ROLLOUT_SAMPLES,
    check_count,
)
from containergym_marl.core.observations import DEFAULT_OBSERVATION, check_observation
from containergym_marl.policies.actor_critic import MASKED_LOGIT, ActorCritic, load_tensors
from containergym_marl.policies.safety import OWN_CHECK_LEAD_STEPS, OWN_CHECK_RISK, own_check_setting, own_deadline_due
from containergym_marl.rundir import UPDATE_FIELDS, append_metrics
from containergym_marl.training.checkpoints import SegmentClock, TrainingProgress, save_checkpoint
from containergym_marl.training.native import MemoryShapes
from containergym_marl.training.ppo_kernel import FlatAdam, act, blas_threads, parameter_layout, run_update

CHECKPOINT_FORMAT = "containergym-marl ppo checkpoint"
CHECKPOINT_VERSION = 2  # 1: the optimiser's state was torch.optim.Adam's (still read)


@dataclass(frozen=True)
class PPOArgs:
    """The native PPO's settings (``--hp KEY=VALUE``); SB3's defaults except the batch shape.

    One rollout is ``n_steps`` steps of every slot: n_envs × n_steps samples for ``fast_ppo``,
    n_envs × n × n_steps for ``fast_shared_ppo`` (one per container agent). The number of
    simulations is ``--n-envs`` if given, else :meth:`num_sims`: as many as make about
    ``rollout_samples`` samples per update, so the shared policy gets as many updates on a
    16-container plant as on a 5-container one.
    """

    rollout_samples: int = 4096  # samples per update the number of simulations is chosen for (unless --n-envs)
    n_steps: int = 64  # steps of every simulation per rollout (SB3 paper runs: 768 with 8 simulations)
    minibatch_size: int = 1024  # samples per gradient step (SB3: 64): a rollout is split into equal minibatches of about this
    n_epochs: int = 10  # passes over each rollout (SB3: 10)
    learning_rate: float = 3e-4  # Adam's step size (SB3: 3e-4)
    anneal_lr: bool = False  # the step size decays linearly to 0 at the budget (CleanRL's anneal_lr)
    adam_eps: float = 1e-5  # Adam's eps (SB3's actor-critic policies: 1e-5)
    clip_range: float = 0.2  # PPO's ratio clip (SB3: 0.2)
    gae_lambda: float = 0.95  # GAE's λ (SB3: 0.95)
    ent_coef: float = 0.0  # entropy bonus (SB3: 0)
    vf_coef: float = 0.5  # weight of the value loss (SB3: 0.5)
    max_grad_norm: float = 0.5  # gradient norm clip (SB3: 0.5)
    normalize_advantage: bool = True  # advantages normalised per minibatch (SB3: True)
    action_mask: bool = False  # mask the emptying actions while no PU is free
    hidden: tuple[int, ...] = (64, 64)  # hidden units of the policy and of the value network (SB3: 64, 64)
    observation: str = DEFAULT_OBSERVATION  # the container agents' observation variant (fast_shared_ppo only)
    # the container agents' own deadline check (policies.safety.own_deadline_due; fast_shared_ppo only), part of the
    # environment the policy learns in and of the trained policy: an agent whose own observation says its container
    # would overflow within own_check_lead_steps + 1 fills with probability above own_check_risk has its request made,
    # whatever it sampled (PPO learns from the actions it sampled); 0: no check
    own_check_risk: float = 0.0
    own_check_lead_steps: int = 1
    # the learner's reward at an overflow, as a multiple of the plant's r_min (reward shaping: 1 is the plant's
    # own reward); the plant, its returns, the best-model criterion and every evaluation keep r_min
    overflow_reward_scale: float = 1.0

    @classmethod
    def from_hyperparams(cls, hyperparams: dict[str, Any]) -> "PPOArgs":
        """The settings with ``hyperparams`` applied; a ValueError naming an unknown key or a bad value."""
        fields = {f.name: f for f in dataclasses.fields(cls)}
        unknown = sorted(set(hyperparams) - set(fields))
        if unknown:
            raise ValueError(f"hp: unknown native PPO setting(s) {unknown}; choose from {sorted(fields)}")
        values = {}
        for key, value in hyperparams.items():
            default = getattr(cls, key) if key != "hidden" else cls.hidden
            values[key] = coerce_setting(key, value, default)
        args = cls(**values)
        args.validate()
        return args

    def num_sims(self, agents_per_sim: int) -> int:
        """Simulations that give about ``rollout_samples`` samples per update with ``agents_per_sim``
        samples per simulation step (1 for the centralised controller, n for the container agents)."""
        return max(1, round(self.rollout_samples / (self.n_steps * agents_per_sim)))

    def validate(self) -> None:
        """Every setting within its bounds (:mod:`containergym_marl.config.bounds`), checked before
        anything is allocated or written; a ValueError naming it otherwise."""
        for name, hi in (("rollout_samples", MAX_ROLLOUT_SAMPLES), ("n_steps", MAX_N_STEPS),
                         ("minibatch_size", MAX_MINIBATCH), ("n_epochs", MAX_EPOCHS)):
            check_count(getattr(self, name), 1, hi, f"hp: {name}")
        positive = ("learning_rate", "adam_eps", "clip_range", "max_grad_norm")
        for name in positive:
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"hp: {name} must be a finite number > 0, got {value}")
        if not 0 <= self.gae_lambda <= 1:
            raise ValueError(f"hp: gae_lambda must be in [0, 1], got {self.gae_lambda}")
        for name in ("ent_coef", "vf_coef"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"hp: {name} must be a finite number >= 0, got {value}")
        scale = self.overflow_reward_scale
        if not (math.isfinite(scale) and 0 < scale <= MAX_OVERFLOW_REWARD_SCALE):
            raise ValueError(f"hp: overflow_reward_scale must be in (0, {MAX_OVERFLOW_REWARD_SCALE:g}] "
                             f"(1: the plant's r_min), got {scale}")
        check_hidden(self.hidden)
        check_observation(self.observation, "hp: observation")
        self.own_check()  # its two settings within their ranges

    def own_check(self) -> dict[str, Any] | None:
        """The model's own check (:func:`~containergym_marl.policies.safety.check_own_check`), or None."""
        return own_check_setting(self.own_check_risk, self.own_check_lead_steps)


def check_hidden(hidden: tuple[int, ...]) -> None:
    """1 to MAX_HIDDEN_LAYERS layer widths, each in [1, MAX_HIDDEN_WIDTH] (a ValueError naming ``hp: hidden``)."""
    if not 1 <= len(hidden) <= MAX_HIDDEN_LAYERS or any(not 1 <= h <= MAX_HIDDEN_WIDTH for h in hidden):
        raise ValueError(f"hp: hidden must list 1 to {MAX_HIDDEN_LAYERS} layer widths in [1, {MAX_HIDDEN_WIDTH}], "
                         f"got {list(hidden)}")


def coerce_setting(key: str, value: Any, default: Any) -> Any:
    """``value`` (a CLI string or a Python value) as the type of ``default``; a ValueError naming ``key``."""
    try:
        if isinstance(default, bool):
            if isinstance(value, str):
                if value.lower() not in ("true", "false", "1", "0"):
                    raise ValueError("expected true or false")
                return value.lower() in ("true", "1")
            if not isinstance(value, (bool, np.bool_)):
                raise ValueError("expected true or false")
            return bool(value)
        if isinstance(default, str):  # a name; the settings' validate() checks it among its choices
            if not isinstance(value, str):
                raise ValueError("expected a name")
            return value
        if isinstance(default, tuple):
            items = value.split(",") if isinstance(value, str) else list(value)
            return tuple(_integer(v) for v in items)
        if isinstance(default, int):
            return _integer(value)
        if isinstance(value, bool):
            raise ValueError("expected a number")
        return float(value)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"hp: {key}={value!r} is not valid ({exc})") from None


def _integer(value: Any) -> int:
    if isinstance(value, bool) or (isinstance(value, float) and not value.is_integer()):
        raise ValueError("expected an integer")
    return int(value)


# ---- the training state that a checkpoint holds ------------------------------------------------
@dataclass
class TrainingState:
    """The model, its optimiser and the sampler's generator: everything a resumed run needs besides
    the run directory's progress files. ``save(f)`` writes a tensor-only checkpoint."""

    model: ActorCritic
    optimizer: Any
    generator: torch.Generator
    num_timesteps: int = 0
    hyperparams: dict[str, Any] = field(default_factory=dict)

    def save(self, f) -> None:
        torch.save({"format": CHECKPOINT_FORMAT, "version": CHECKPOINT_VERSION, "model": self.model.to_dict(),
                    "optimizer": self.optimizer.state_dict(), "generator": self.generator.get_state(),
                    "num_timesteps": int(self.num_timesteps), "hyperparams": self.hyperparams}, f)


def new_state(env, hp: PPOArgs, view: str, seed: int, meta: dict[str, Any]) -> TrainingState:
    """A fresh model (initialised from ``seed``) and optimiser for ``env``'s spaces."""
    generator = torch.Generator().manual_seed(int(seed))
    model = ActorCritic(view, env.observation_space.shape[0], int(env.action_space.n), hp.hidden,
                        action_mask=hp.action_mask, meta=meta, generator=generator, observation=hp.observation,
                        own_check=hp.own_check())
    return TrainingState(model, _optimizer(model, hp), generator, 0, dataclasses.asdict(hp))


def state_from_model(model: ActorCritic, hp: PPOArgs, generator: torch.Generator, num_timesteps: int) -> TrainingState:
    """A training state that continues from ``model`` (an imitated policy, :mod:`~containergym_marl.training.dagger`)
    with a fresh optimiser, the run's generator and its samples so far."""
    return TrainingState(model, _optimizer(model, hp), generator, int(num_timesteps), dataclasses.asdict(hp))


def _optimizer(model: ActorCritic, hp: PPOArgs) -> FlatAdam:
    # SB3's update rule (Adam, eps 1e-5) on one flat buffer of the parameters (ppo_kernel.FlatAdam)
    return FlatAdam(model.net.parameters(), lr=hp.learning_rate, eps=hp.adam_eps)


def load_checkpoint(path: str | Path, hp: PPOArgs) -> TrainingState:
    """The training state saved at ``path`` (tensors only); a ValueError when it is broken or not a
    native PPO checkpoint."""
    data = load_tensors(path)
    source = f"checkpoint {str(path)!r}"
    if not isinstance(data, dict) or data.get("format") != CHECKPOINT_FORMAT:
        raise ValueError(f"{source} is not a native PPO checkpoint (format {CHECKPOINT_FORMAT!r})")
    if data.get("version") not in (1, CHECKPOINT_VERSION):
        raise ValueError(f"{source}: version {data.get('version')!r}; this package reads {CHECKPOINT_VERSION}")
    model = ActorCritic.from_dict(data.get("model"), source)
    optimizer = _optimizer(model, hp)
    generator = torch.Generator()
    try:
        optimizer.load_state_dict(data["optimizer"])
        generator.set_state(data["generator"])
        steps = int(data["num_timesteps"])
    except (KeyError, TypeError, ValueError, RuntimeError) as exc:
        raise ValueError(f"{source}: its optimiser or generator state is unreadable ({exc})") from exc
    return TrainingState(model, optimizer, generator, steps, dataclasses.asdict(hp))


# ---- the trainer --------------------------------------------------------------------------------
def learn(run: Path, state: TrainingState, env, budget: int, gamma: float, hp: PPOArgs,
          progress: TrainingProgress, interval: int, on_samples=None, bc: BehaviourCloning | None = None) -> None:
    """Train ``state`` on ``env`` (a native SB3-style VecEnv of the package) until ``budget``
    samples, discounting by ``gamma``: rollouts, GAE, clipped-loss updates (with ``bc``'s term at its
    weight for the update's samples); after every update a metrics row with its diagnostics (and the
    best model, the policy that collected the rollout, when the 100-episode training return improved),
    a checkpoint after the update of every rollout that crosses ``interval`` samples since the last one."""
    model, optimizer, generator = state.model, state.optimizer, state.generator
    slots, n_steps = env.num_envs, hp.n_steps
    obs_size, n_actions = model.observation_size, model.n_actions
    # Rollout buffers, allocated once.
    obs_buf = torch.zeros((n_steps, slots, obs_size))
    act_buf = torch.zeros((n_steps, slots), dtype=torch.long)
    logp_buf = torch.zeros((n_steps, slots))
    val_buf = torch.zeros((n_steps, slots))
    rew_buf = torch.zeros((n_steps, slots))
    start_buf = torch.zeros((n_steps, slots))  # 1 where the observation starts an episode
    mask_buf = torch.ones((n_steps, slots, n_actions), dtype=torch.bool) if hp.action_mask else None
    adv_buf = torch.zeros((n_steps, slots))  # GAE, written in place each rollout
    # log(-log(u)) of the rollout's uniforms, drawn in one call: the numbers a draw per step would give
    gumbel_buf = torch.zeros((n_steps, slots, n_actions))

    # the rollout's policy: one compiled call a step on the parameters' flat buffer (ppo_kernel.act)
    flat_param = optimizer.flat_param.numpy()
    layout, actor_layers = parameter_layout(model, optimizer.flat_param)
    no_masks = np.zeros((0, n_actions), np.bool_)
    obs_np, act_np, logp_np, val_np = obs_buf.numpy(), act_buf.numpy(), logp_buf.numpy(), val_buf.numpy()
    gumbel_np, last_value = gumbel_buf.numpy(), torch.zeros(slots)
    spare_actions, spare_logp = np.zeros(slots, np.int64), np.zeros(slots, np.float32)
    obs = env.reset()
    episode_start = torch.ones(slots)
    num_sims = env.num_sims
    episode_return, episode_length = np.zeros(num_sims), np.zeros(num_sims, dtype=np.int64)
    clock = SegmentClock(progress)
    last_checkpoint = state.num_timesteps
    best_file = run / "best_model.pt"

    while state.num_timesteps < budget:
        # ---- rollout: n_steps steps of every slot with the current policy
        with torch.inference_mode(), blas_threads(torch.get_num_threads()):
            gumbel_buf.uniform_(generator=generator).log_().neg_().log_()
            for t in range(n_steps):
                masks = env.action_masks() if mask_buf is not None else no_masks
                obs_np[t] = obs
                act(flat_param, layout, actor_layers, obs_np[t], gumbel_np[t], masks, MASKED_LOGIT, act_np[t],
                    logp_np[t], val_np[t])
                start_buf[t] = episode_start
                if mask_buf is not None:
                    mask_buf[t] = torch.from_numpy(masks)
                executed = act_np[t]
                if model.own_check is not None:  # the agents' own check: the environment the policy learns in
                    executed = np.where(own_deadline_due(obs, **model.own_check), 1, executed)
                next_obs, rewards, dones, infos = env.step(executed)
                rewards = torch.from_numpy(rewards)
                if dones.any():
                    if hp.overflow_reward_scale != 1.0:  # an overflow ends its episode: shaped only there
                        rewards[torch.from_numpy(env.overflow_slots())] *= hp.overflow_reward_scale
                    # A time-limit cut is not a terminal state: bootstrap with the value of the last
                    # observation (SB3's TimeLimit.truncated handling); an overflow is terminal.
                    cut = [k for k in np.flatnonzero(dones).tolist() if infos[k].get("TimeLimit.truncated")]
                    if cut:
                        last = torch.from_numpy(np.stack([infos[k]["terminal_observation"] for k in cut]))
                        rewards[cut] += gamma * model.value(last)
                rew_buf[t] = rewards
                episode_start = torch.from_numpy(dones.astype(np.float32))
                obs = next_obs
                state.num_timesteps += slots
                # the plant's return of every training episode (the best-model criterion)
                plant_reward, sim_done = env.last_plant_step()
                episode_return += plant_reward
                episode_length += 1
                if sim_done.any():
                    truncated = env.simulator.last_outcome.truncated
                    for b in np.flatnonzero(sim_done).tolist():
                        progress.add_episode(float(episode_return[b]), int(episode_length[b]), bool(truncated[b]))
                        episode_return[b], episode_length[b] = 0.0, 0
            act(flat_param, layout, actor_layers, np.ascontiguousarray(obs, np.float32), gumbel_np[0],
                no_masks, MASKED_LOGIT, spare_actions, spare_logp, last_value.numpy())

            compute_gae(rew_buf, val_buf, start_buf, last_value, episode_start, gamma, hp.gae_lambda, out=adv_buf)
            ret_buf = adv_buf + val_buf

        steps = state.num_timesteps
        saved_best = save_if_best(best_file, model, progress, steps)
        if hp.anneal_lr:
            # the step size of this update: linear from learning_rate at 0 samples to 0 at the budget
            for group in optimizer.param_groups:
                group["lr"] = hp.learning_rate * max(1.0 - (steps - slots * n_steps) / budget, 0.0)
        diagnostics = update(model, optimizer, hp, generator, obs_buf.view(-1, obs_size), act_buf.view(-1),
                             logp_buf.view(-1), adv_buf.view(-1), ret_buf.view(-1),
                             mask_buf.view(-1, n_actions) if mask_buf is not None else None, bc=bc,
                             bc_weight=0.0 if bc is None else bc.weight_at(steps - slots * n_steps))
        diagnostics["explained_variance"] = explained_variance(val_buf.view(-1), ret_buf.view(-1))
        log_rollout(run, progress, steps, clock.wall(), saved_best, diagnostics)
        if on_samples is not None:
            on_samples(steps, progress)

        clock.update()
        if steps - last_checkpoint >= interval and steps < budget:
            last_checkpoint = save_checkpoint(run, state, progress, suffix=".pt")
    clock.update()


def compute_gae(rewards, values, starts, last_value, last_start, gamma: float, lam: float, out=None):
    """Generalised advantage estimates [T, B] (SB3's ``compute_returns_and_advantage``).

    ``starts[t]`` is 1 where the observation of step t starts an episode (so step t - 1 ended one),
    ``last_value`` and ``last_start`` are the value and start flag of the observation after the
    last step. Rewards already include the bootstrap of time-limit cuts."""
    n_steps = rewards.shape[0]
    out = torch.empty_like(rewards) if out is None else out
    # every step's TD error and decay at once, then the backward recursion: two products a step
    not_done = 1.0 - torch.cat([starts[1:], last_start[None]])
    next_value = torch.cat([values[1:], last_value[None]])
    delta = rewards + gamma * next_value * not_done - values
    decay = gamma * lam * not_done
    gae = torch.zeros_like(last_value)
    for t in reversed(range(n_steps)):
        gae = torch.add(delta[t], torch.mul(decay[t], gae), out=out[t])
    return out


def explained_variance(values: torch.Tensor, returns: torch.Tensor) -> float:
    """1 - Var(returns - values) / Var(returns), as SB3 logs it: 1 for a perfect critic, 0 for one
    no better than a constant; nan when the returns do not vary."""
    var = float(returns.var())
    return float("nan") if var == 0 else 1.0 - float((returns - values).var()) / var


@dataclass(frozen=True)
class BehaviourCloning:
    """A decaying behaviour-cloning term beside PPO's loss (DAPG's augmented loss, Rajeswaran et al.,
    2018): ``weight`` × the cross-entropy of the policy's logits against ``labels`` on a minibatch of
    ``obs`` as large as PPO's, drawn (with replacement, from the run's generator) beside each of its
    minibatches. The weight is ``coef`` × 0.5^(PPO samples since ``start_timesteps`` / ``half_life``)."""

    obs: torch.Tensor  # [N, F] the demonstrations' observations
    labels: torch.Tensor  # [N] long: the demonstrated actions
    coef: float
    half_life: float  # samples after which the weight has halved
    start_timesteps: int  # the run's samples when PPO began

    def weight_at(self, timesteps: int) -> float:
        return self.coef * 0.5 ** (max(timesteps - self.start_timesteps, 0) / self.half_life)


def update(model: ActorCritic, optimizer: FlatAdam, hp: PPOArgs, generator, obs, actions, old_logp, advantages,
           returns, masks=None, bc: BehaviourCloning | None = None, bc_weight: float = 0.0) -> dict[str, float]:
    """``hp.n_epochs`` passes over one rollout's samples (flattened) in shuffled minibatches of about
    ``hp.minibatch_size`` (the rollout split into equal parts): SB3's clipped surrogate + ``vf_coef`` ×
    value MSE − ``ent_coef`` × entropy, advantages normalised per minibatch, gradient norm clipped, one
    Adam step per minibatch of ``optimizer`` (the :class:`FlatAdam` over the model's parameters).

    With ``bc`` and a ``bc_weight`` > 0, each minibatch's step also descends ``bc_weight`` × the
    cross-entropy on as many of ``bc``'s samples (drawn with replacement from ``generator``; the value
    network gets no gradient from them); the gradient clip covers the sum.

    The whole update is one compiled call (:func:`~containergym_marl.training.ppo_kernel.ppo_update`).
    Returns the update's diagnostics, as SB3 logs them (means over its minibatches): the policy's
    ``entropy`` (nats), ``approx_kl`` (the estimator E[(r - 1) - log r] of the ratio r) and the
    ``clip_fraction`` (share of samples whose ratio left the clip range)."""
    return run_update(model, optimizer, hp, generator, obs, actions, old_logp, advantages, returns, masks,
                      bc=bc, bc_weight=bc_weight)


def save_if_best(best_file: Path, model: ActorCritic, progress: TrainingProgress, steps: int) -> bool:
    """Save the model as the best one when the 100-episode mean training return improved (before
    the update: the best model is the policy that played those episodes); whether it did."""
    if not progress.returns:
        return False
    recent = float(np.mean(progress.returns))
    if recent <= progress.best_train_return:
        return False
    progress.best_train_return, progress.best_timesteps = recent, steps
    model.meta["timesteps"] = steps
    model.save(best_file, durable=False)  # made durable with the next checkpoint, or at the end
    return True


def log_rollout(run: Path, progress: TrainingProgress, steps: int, wall: float, saved_best: bool,
                diagnostics: dict[str, float] | None = None) -> None:
    """A metrics row, with the update's diagnostics (:data:`~containergym_marl.rundir.UPDATE_FIELDS`;
    nan where there was no PPO update, as in an imitation phase); nothing before the first training
    episode ends."""
    if not progress.returns:
        return
    append_metrics(run, {
        "timesteps": steps,
        "episodes": progress.episodes,
        "train_return_mean100": float(np.mean(progress.returns)),
        "train_episode_length_mean100": float(np.mean(progress.lengths)),
        "best_train_return": progress.best_train_return,
        "saved_best": int(saved_best),
        "wall_time_s": wall,
        **{name: (diagnostics or {}).get(name, math.nan) for name in UPDATE_FIELDS if name != "time_limit_share"},
        "time_limit_share": progress.time_limit_share,
    }, durable=False)


def save_final(state: TrainingState, path: Path) -> None:
    state.model.meta["timesteps"] = int(state.num_timesteps)
    state.model.save(path)


def batch_memory(settings: PPOArgs, shapes: MemoryShapes, prefix: str = "") -> dict[str, int]:
    """Bytes of a rollout and a minibatch at ``settings``, named by setting (``prefix``: the
    settings' prefix in those names, ``ppo_`` for a fine-tuning's)."""
    return {f"{prefix}n_steps={settings.n_steps}":
            shapes.rollout(settings.n_steps, shapes.obs + 8 + shapes.actions * settings.action_mask),
            f"{prefix}minibatch_size={settings.minibatch_size}":
            shapes.minibatch(settings.minibatch_size, 2 * sum(settings.hidden), settings.n_steps)}


class PPOTrainer:
    """The native PPO as ``train`` runs it (:class:`~containergym_marl.training.native.NativeTrainer`);
    ``defaults``: the method's own settings (its settings file and ``--hp`` override them)."""

    def __init__(self, defaults: dict[str, Any] | None = None):
        self.defaults = dict(defaults or {})

    def settings(self, hyperparams: dict[str, Any]) -> PPOArgs:
        return PPOArgs.from_hyperparams({**self.defaults, **hyperparams})

    def default_sims(self, settings: PPOArgs, agents_per_sim: int) -> int:
        return settings.num_sims(agents_per_sim)

    def env_options(self, settings: PPOArgs) -> dict[str, Any]:
        # the container agents' env only; the default asks nothing, so the centralised fast_ppo trains as ever
        return {} if settings.observation == DEFAULT_OBSERVATION else {"observation": settings.observation}

    def memory(self, settings: PPOArgs, shapes: MemoryShapes) -> dict[str, int]:
        return {**batch_memory(settings, shapes), f"hidden={list(settings.hidden)}": shapes.networks(settings.hidden)}

    def new_state(self, env, settings: PPOArgs, view: str, seed: int, meta: dict[str, Any]) -> TrainingState:
        return new_state(env, settings, view, seed, meta)

    def load_checkpoint(self, path: Path, settings: PPOArgs) -> TrainingState:
        return load_checkpoint(path, settings)

    def learn(self, run: Path, state: TrainingState, env, budget: int, gamma: float, settings: PPOArgs,
              progress: TrainingProgress, interval: int, seed: int, on_samples=None) -> TrainingState:
        learn(run, state, env, budget, gamma, settings, progress, interval, on_samples)
        return state

    def save_final(self, state: TrainingState, path: Path) -> None:
        save_final(state, path)

    def run_summary(self, run: Path) -> dict[str, Any]:
        return {}


#: The registry's native PPO (``fast_ppo``, ``fast_shared_ppo``).
TRAINER = PPOTrainer()
#: ``fast_shared_ppo_checked``'s check (:data:`~containergym_marl.policies.safety.OWN_CHECK_RISK`)
OWN_CHECK_SETTINGS = {"own_check_risk": OWN_CHECK_RISK, "own_check_lead_steps": OWN_CHECK_LEAD_STEPS}
#: ``fast_shared_ppo_checked``: the shared PPO that learns and acts with the agents' own check.
CHECKED_TRAINER = PPOTrainer(defaults=OWN_CHECK_SETTINGS)

__all__ = ["BehaviourCloning", "CHECKED_TRAINER", "OWN_CHECK_SETTINGS", "PPOArgs", "PPOTrainer", "TRAINER", "TrainingState", "batch_memory",
           "coerce_setting", "compute_gae", "explained_variance", "learn",
           "load_checkpoint", "log_rollout", "new_state", "save_final", "save_if_best", "state_from_model", "update"]
