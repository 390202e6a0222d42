"""The native PPO's arithmetic as compiled calls: the rollout's policy step, and the update (every
epoch and minibatch of a rollout: the clipped loss's gradients, the networks' backward, the norm clip
and Adam) in one numba function.

The networks are small: two [64, 64] tanh MLPs on minibatches of 64 to a few thousand samples.
Written as torch operations, each minibatch step is about a hundred calls of a few microseconds, most
of them elementwise passes over a few thousand numbers: at SB3's minibatch of 64 the calls, not the
arithmetic, take nine tenths of the update, and at 1,024 about half. Here the matrix products are
BLAS calls (numba's ``np.dot``: SciPy's BLAS, run at torch's thread count) and everything between
them is fused loops over each minibatch's rows, the tanh a rational approximation the compiler
vectorises (Eigen's, within 4e-7), with no Python call per operation.

The equations are SB3's PPO: the loss's gradient in closed form (where the two surrogates tie, the
gradient flows through the ratio, as autograd's halves add up to; masked logits get none), the
backward layer by layer, ``clip_grad_norm_``'s rule and torch's Adam, in float32. The tests check an
update against autograd's and torch's Adam, and against SB3's PPO, to float rounding; the rounding
differs from torch's (another BLAS, another tanh), so a run does not reproduce one trained through
torch bit for bit (``studies/update_equivalence.py`` compares seeds trained both ways). The
parameters, gradients and Adam's moments are :class:`FlatAdam`'s flat buffers, read and written in
place as NumPy views of the same memory; the model's parameters are views of them.
"""

from __future__ import annotations

import contextlib
import math
from typing import Any

import numba as nb
import numpy as np
import torch

from containergym_marl.extras import missing_extra
from containergym_marl.policies.actor_critic import MASKED_LOGIT

#: float32's lowest finite value: the clamp of log π in the entropy (masked actions: p log p = 0)
_LOWEST = np.float32(np.finfo(np.float32).min)

# tanh as Eigen's float rational approximation (within 4e-7 of tanh): arithmetic the compiler
# vectorises, where the C library's tanhf is one call per number.
_T_CLAMP = np.float32(7.90531110763549805)
_T_A1, _T_A3, _T_A5, _T_A7 = (np.float32(4.89352455891786e-03), np.float32(6.37261928875436e-04),
                              np.float32(1.48572235717979e-05), np.float32(5.12229709037114e-08))
_T_A9, _T_A11, _T_A13 = np.float32(-8.60467152213735e-11), np.float32(2.00018790482477e-13), np.float32(-2.76076847742355e-16)
_T_B0, _T_B2, _T_B4, _T_B6 = (np.float32(4.89352518554385e-03), np.float32(2.26843463243900e-03),
                              np.float32(1.18534705686654e-04), np.float32(1.19825839466702e-06))


@nb.njit(cache=True, error_model="numpy")
def _tanh(x):
    x = _T_CLAMP if x > _T_CLAMP else x
    x = -_T_CLAMP if x < -_T_CLAMP else x
    x2 = x * x
    p = x * ((((((x2 * _T_A13 + _T_A11) * x2 + _T_A9) * x2 + _T_A7) * x2 + _T_A5) * x2 + _T_A3) * x2 + _T_A1)
    return p / (((x2 * _T_B6 + _T_B4) * x2 + _T_B2) * x2 + _T_B0)


@nb.njit(cache=True, error_model="numpy")
def _forward(flat, layout, first, last, x, acts):
    """Layers ``first`` .. ``last`` - 1 of ``layout`` on rows ``x`` [B, F]; ``acts[i]`` receives the
    input of layer ``first + i`` (the activations the backward needs). Returns the last layer's output."""
    h = x
    for li in range(first, last):
        w_off, b_off, n_out, n_in = layout[li, 0], layout[li, 1], layout[li, 2], layout[li, 3]
        weight = flat[w_off:w_off + n_out * n_in].reshape((n_out, n_in))
        bias = flat[b_off:b_off + n_out]
        acts[li - first] = h
        out = np.dot(h, weight.T)
        rows = out.shape[0]
        hidden = li < last - 1
        if hidden:
            for r in range(rows):
                for j in range(n_out):
                    out[r, j] = _tanh(out[r, j] + bias[j])
        else:
            for r in range(rows):
                for j in range(n_out):
                    out[r, j] += bias[j]
        h = out
    return h


@nb.njit(cache=True, error_model="numpy")
def _backward(flat, grad, layout, first, last, acts, g):
    """The gradients of layers ``first`` .. ``last`` - 1 into ``grad`` (written, not added), from the
    gradient ``g`` [B, out] of the last layer's output and the inputs in ``acts``."""
    for li in range(last - 1, first - 1, -1):
        w_off, b_off, n_out, n_in = layout[li, 0], layout[li, 1], layout[li, 2], layout[li, 3]
        x = acts[li - first]
        rows = g.shape[0]
        grad[b_off:b_off + n_out] = 0.0
        for r in range(rows):
            for j in range(n_out):
                grad[b_off + j] += g[r, j]
        grad[w_off:w_off + n_out * n_in] = np.dot(g.T, x).reshape(n_out * n_in)
        if li > first:  # through the layer, then through the tanh that made x: (1 - x²)
            weight = flat[w_off:w_off + n_out * n_in].reshape((n_out, n_in))
            gx = np.dot(g, weight)
            for r in range(rows):
                for k in range(n_in):
                    xv = x[r, k]
                    gx[r, k] = gx[r, k] - gx[r, k] * xv * xv
            g = gx


@nb.njit(cache=True, error_model="numpy")
def _log_softmax(z, masks, row, masked_logit, out):
    """``out`` = log softmax of the logits ``z`` (set to ``masked_logit`` in place where ``masks[row]``
    is False; ``masks`` [0, A] for none)."""
    if masks.shape[0] > 0:
        for j in range(z.shape[0]):
            if not masks[row, j]:
                z[j] = masked_logit
    top = z[0]
    for j in range(1, z.shape[0]):
        top = max(top, z[j])
    total = np.float32(0.0)
    for j in range(z.shape[0]):
        total += np.exp(z[j] - top)
    log_total = np.log(total)
    for j in range(z.shape[0]):
        out[j] = z[j] - top - log_total


@nb.njit(cache=True, error_model="numpy")
def act(flat, layout, actor_layers, obs, gumbel, masks, masked_logit, actions, log_probs, values):
    """The rollout's step of the policy on ``obs`` [S, F]: the actor's logits (``masks`` [S, A] False
    set to ``masked_logit``; [0, A] for none), the action of highest logit + Gumbel noise (``gumbel``
    [S, A] holds log(-log u): a sample of the softmax) into ``actions``, its log-probability into
    ``log_probs`` and the critic's value into ``values`` [S]."""
    n_layers = layout.shape[0]
    acts_actor = [np.empty((0, 0), np.float32) for _ in range(actor_layers)]
    acts_critic = [np.empty((0, 0), np.float32) for _ in range(n_layers - actor_layers)]
    logits = _forward(flat, layout, 0, actor_layers, obs, acts_actor)
    critic = _forward(flat, layout, actor_layers, n_layers, obs, acts_critic)
    logp = np.empty(logits.shape[1], np.float32)
    for r in range(obs.shape[0]):
        z = logits[r]
        _log_softmax(z, masks, r, masked_logit, logp)
        best = 0
        for j in range(1, z.shape[0]):
            if z[j] - gumbel[r, j] > z[best] - gumbel[r, best]:
                best = j
        actions[r] = best
        log_probs[r] = logp[best]
        values[r] = critic[r, 0]


@nb.njit(cache=True, error_model="numpy")
def ppo_update(flat, grad, exp_avg, exp_avg_sq, layout, actor_layers, obs, actions, old_logp, advantages,
               returns, masks, orders, bounds, bc_obs, bc_labels, bc_rows, bc_weight, clip_range, vf_coef,
               ent_coef, normalize_advantage, max_grad_norm, lr, beta1, beta2, eps, adam_steps, masked_logit):
    """``orders.shape[0]`` epochs over the rollout (``obs`` [N, F], ``actions``, ``old_logp``,
    ``advantages``, ``returns`` [N]; ``masks`` [N, A] or [0, A] for none), each epoch's rows in the
    order ``orders[e]`` split at ``bounds``; one Adam step per minibatch on ``flat`` (the parameters:
    the actor's layers then the critic's, as ``layout`` [L, 4] rows of weight offset, bias offset,
    outputs, inputs; the first ``actor_layers`` are the actor's). With ``bc_weight`` > 0 each step also
    descends ``bc_weight`` × the cross-entropy of the actor on ``bc_obs[bc_rows[s]]`` against
    ``bc_labels`` (``bc_rows`` [epochs, N]: as many rows as the minibatch's, at its place in ``orders``). Returns (entropy, approx_kl,
    clip_fraction) summed over minibatches, and Adam's step count after the update."""
    n_layers = layout.shape[0]
    n_actions = layout[actor_layers - 1, 2]
    n_obs = obs.shape[1]
    sums = np.zeros(3)
    acts_actor = [np.empty((0, 0), np.float32) for _ in range(actor_layers)]
    acts_critic = [np.empty((0, 0), np.float32) for _ in range(n_layers - actor_layers)]
    no_masks = masks[:0]  # the demonstrations' logits are not masked
    for e in range(orders.shape[0]):
        for k in range(bounds.shape[0] - 1):
            lo, hi = bounds[k], bounds[k + 1]
            b = hi - lo
            cloned = bc_weight > 0
            nb_rows = b if cloned else 0
            x = np.empty((b + nb_rows, n_obs), np.float32)
            for r in range(b):
                x[r] = obs[orders[e, lo + r]]
            for r in range(nb_rows):
                x[b + r] = bc_obs[bc_rows[e, lo + r]]
            logits = _forward(flat, layout, 0, actor_layers, x, acts_actor)
            values = _forward(flat, layout, actor_layers, n_layers, np.ascontiguousarray(x[:b]), acts_critic)

            # advantages of the minibatch, normalised (torch's std: Bessel's correction)
            adv = np.empty(b, np.float32)
            for r in range(b):
                adv[r] = advantages[orders[e, lo + r]]
            if normalize_advantage and b > 1:
                mean = np.float32(adv.sum() / np.float32(b))
                var = np.float32(0.0)
                for r in range(b):
                    d = adv[r] - mean
                    var += d * d
                std = np.float32(math.sqrt(var / np.float32(b - 1)))
                for r in range(b):
                    adv[r] = (adv[r] - mean) / (std + np.float32(1e-8))

            # the clipped loss's gradient with respect to the logits and values
            g_logits = np.zeros((b + nb_rows, n_actions), np.float32)
            g_values = np.empty((b, 1), np.float32)
            inv_b = np.float32(1.0) / np.float32(b)
            entropy_sum, kl_sum, clipped_sum = 0.0, 0.0, 0.0
            logp = np.empty(n_actions, np.float32)
            for r in range(b):
                row = orders[e, lo + r]
                _log_softmax(logits[r], masks, row, masked_logit, logp)
                a = actions[row]
                log_ratio = logp[a] - old_logp[row]
                ratio = np.exp(log_ratio)
                clipped = min(max(ratio, np.float32(1.0 - clip_range)), np.float32(1.0 + clip_range))
                coef = adv[r] * ratio if adv[r] * ratio <= adv[r] * clipped else np.float32(0.0)
                coef = coef / np.float32(-b)
                entropy = np.float32(0.0)
                for j in range(n_actions):
                    p = np.exp(logp[j])
                    entropy -= p * max(logp[j], _LOWEST)
                for j in range(n_actions):
                    p = np.exp(logp[j])
                    g = p * (-coef)
                    if j == a:
                        g += coef
                    if ent_coef != 0.0:
                        g += (p * max(logp[j], _LOWEST) + p * entropy) * np.float32(ent_coef * inv_b)
                    g_logits[r, j] = g
                g_values[r, 0] = (values[r, 0] - returns[row]) * np.float32(2.0 * vf_coef * inv_b)
                entropy_sum += entropy
                kl_sum += (ratio - 1.0) - log_ratio
                clipped_sum += 1.0 if abs(ratio - 1.0) > clip_range else 0.0
            sums[0] += entropy_sum / b
            sums[1] += kl_sum / b
            sums[2] += clipped_sum / b
            if cloned:  # d/dz of bc_weight × mean cross-entropy: bc_weight / rows × (softmax(z) - onehot)
                w = np.float32(bc_weight / nb_rows)
                for r in range(b, b + nb_rows):
                    _log_softmax(logits[r], no_masks, 0, masked_logit, logp)
                    for j in range(n_actions):
                        g_logits[r, j] = np.exp(logp[j]) * w
                    g_logits[r, bc_labels[bc_rows[e, lo + r - b]]] -= w

            _backward(flat, grad, layout, 0, actor_layers, acts_actor, g_logits)
            _backward(flat, grad, layout, actor_layers, n_layers, acts_critic, g_values)

            # clip_grad_norm_'s rule, then Adam (torch's: lerp, addcmul, sqrt / sqrt(bias2) + eps, addcdiv)
            square = 0.0
            for i in range(grad.shape[0]):
                square += grad[i] * grad[i]
            scale = min(np.float32(max_grad_norm) / (np.float32(math.sqrt(square)) + np.float32(1e-6)), np.float32(1.0))
            adam_steps += 1
            bias1 = 1.0 - beta1 ** adam_steps
            bias2_sqrt = math.sqrt(1.0 - beta2 ** adam_steps)
            step_size = np.float32(lr / bias1)
            one_b1, one_b2, fb2 = np.float32(1.0 - beta1), np.float32(1.0 - beta2), np.float32(beta2)
            fbias2, feps = np.float32(bias2_sqrt), np.float32(eps)
            for i in range(grad.shape[0]):
                g = grad[i] * scale
                grad[i] = g
                exp_avg[i] += (g - exp_avg[i]) * one_b1
                exp_avg_sq[i] = exp_avg_sq[i] * fb2 + one_b2 * g * g
                flat[i] -= step_size * (exp_avg[i] / (np.float32(math.sqrt(exp_avg_sq[i])) / fbias2 + feps))
    return sums, adam_steps


def _views(flat: torch.Tensor, params: list[torch.Tensor]) -> list[torch.Tensor]:
    """Consecutive views of ``flat`` shaped as each of ``params``, in order."""
    views, offset = [], 0
    for p in params:
        views.append(flat[offset:offset + p.numel()].view_as(p))
        offset += p.numel()
    return views


class FlatAdam:
    """Adam's state for parameters that are views of one flat buffer, stepped by :func:`ppo_update`
    (torch's update rule: no weight decay, no AMSGrad).

    Construction moves the parameters' values into :attr:`flat_param` and makes each parameter, and
    its ``.grad``, a view of :attr:`flat_param` and :attr:`flat_grad`. ``param_groups[0]["lr"]`` is
    the step size (as torch's optimisers, for a schedule). :meth:`state_dict` holds tensors only;
    :meth:`load_state_dict` also reads a ``torch.optim.Adam`` state of the same parameters (the
    checkpoints of version 1).
    """

    FORMAT = "containergym-marl flat adam"

    def __init__(self, params, lr: float, eps: float, betas: tuple[float, float] = (0.9, 0.999)):
        self.params = list(params)
        self.flat_param = torch.cat([p.detach().reshape(-1) for p in self.params])
        self.flat_grad = torch.zeros_like(self.flat_param)
        self.exp_avg, self.exp_avg_sq = torch.zeros_like(self.flat_param), torch.zeros_like(self.flat_param)
        for p, value, grad in zip(self.params, _views(self.flat_param, self.params), _views(self.flat_grad, self.params)):
            p.data, p.grad = value, grad
        self.param_groups = [{"lr": float(lr)}]
        self.eps, self.betas, self.steps = float(eps), (float(betas[0]), float(betas[1])), 0

    def state_dict(self) -> dict[str, Any]:
        return {"format": self.FORMAT, "steps": self.steps, "lr": self.param_groups[0]["lr"],
                "exp_avg": self.exp_avg.clone(), "exp_avg_sq": self.exp_avg_sq.clone()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """The moments and step count of ``state`` (this class's, or ``torch.optim.Adam``'s for the
        same parameters in the same order); a ValueError when they do not fit."""
        if state.get("format") == self.FORMAT:
            steps, lr, avg, avg_sq = state["steps"], state["lr"], state["exp_avg"], state["exp_avg_sq"]
        else:  # torch.optim.Adam's: per-parameter moments, indexed in parameter order
            per = [state["state"][i] for i in range(len(self.params))] if state.get("state") else []
            steps = int(per[0]["step"]) if per else 0
            lr = state["param_groups"][0]["lr"]
            avg = torch.cat([s["exp_avg"].reshape(-1) for s in per]) if per else torch.zeros_like(self.exp_avg)
            avg_sq = torch.cat([s["exp_avg_sq"].reshape(-1) for s in per]) if per else torch.zeros_like(self.exp_avg)
        if not (isinstance(avg, torch.Tensor) and isinstance(avg_sq, torch.Tensor)
                and avg.shape == avg_sq.shape == self.exp_avg.shape):
            raise ValueError(f"optimiser state: moments for {self.exp_avg.numel()} parameters expected")
        self.exp_avg.copy_(avg)
        self.exp_avg_sq.copy_(avg_sq)
        self.steps, self.param_groups[0]["lr"] = int(steps), float(lr)


_BLAS = None


@contextlib.contextmanager
def blas_threads(threads: int):
    """SciPy's BLAS, which numba's ``np.dot`` calls, at ``threads`` threads inside the block (its own
    count is the machine's cores: on the update's small products, threads that wait for each other)."""
    global _BLAS
    if _BLAS is None:
        try:
            import scipy.linalg.cython_blas  # noqa: F401  loads the BLAS that numba's np.dot calls
            from threadpoolctl import ThreadpoolController
        except ImportError as error:
            raise missing_extra("the native PPO's compiled update", "train", error) from error
        _BLAS = ThreadpoolController().select(user_api="blas").lib_controllers
    before = [c.get_num_threads() for c in _BLAS]
    for c in _BLAS:
        c.set_num_threads(threads)
    try:
        yield
    finally:
        for c, n in zip(_BLAS, before):
            c.set_num_threads(n)


def split_bounds(total: int, parts: int) -> np.ndarray:
    """Where ``torch.tensor_split`` cuts ``total`` rows into ``parts``: the first ``total % parts``
    parts one row longer. [parts + 1] offsets."""
    size, longer = divmod(total, parts)
    return np.cumsum([0] + [size + 1] * longer + [size] * (parts - longer)).astype(np.int64)


def parameter_layout(model, flat_param: torch.Tensor) -> tuple[np.ndarray, int]:
    """(``layout`` [L, 4], actor layers) of ``model``'s Linear layers, the actor's then the critic's:
    weight offset, bias offset (in ``flat_param``), outputs, inputs. A ValueError when a parameter is
    not a view of ``flat_param`` (the optimiser must be the FlatAdam over the model's parameters)."""
    base, size, rows = flat_param.data_ptr(), flat_param.numel(), []
    counts = []
    for net in (model.net.actor, model.net.critic):
        layers = [m for m in net if isinstance(m, torch.nn.Linear)]
        counts.append(len(layers))
        for m in layers:
            offsets = []
            for p in (m.weight, m.bias):
                offset, rest = divmod(p.data_ptr() - base, flat_param.element_size())
                if rest or not 0 <= offset <= size - p.numel() or not p.is_contiguous():
                    raise ValueError("update: the optimiser must be the FlatAdam over the model's parameters "
                                     "(each parameter a view of its flat buffer)")
                offsets.append(offset)
            rows.append((*offsets, m.weight.shape[0], m.weight.shape[1]))
    return np.array(rows, dtype=np.int64), counts[0]


def run_update(model, optimizer, hp, generator: torch.Generator, obs, actions, old_logp, advantages, returns,
               masks=None, bc=None, bc_weight: float = 0.0) -> dict[str, float]:
    """:func:`ppo_update` on torch tensors and a FlatAdam (see ``fast_ppo.update``): the generator's
    draws made first, in the order a loop over minibatches makes them (each epoch's permutation, then
    each minibatch's behaviour-cloning rows); SciPy's BLAS at torch's thread count for the call."""
    if not isinstance(optimizer, FlatAdam):
        raise TypeError(f"update: the optimiser must be a FlatAdam over the model's parameters, "
                        f"got {type(optimizer).__name__}")
    total = obs.shape[0]
    # equal minibatches of about minibatch_size: a rollout of 4160 samples is 4 of 1040, not 4 of 1024
    # and a last one of 64 whose normalised advantages and Adam step would rest on a handful of samples
    minibatches = max(1, round(total / hp.minibatch_size))
    bounds = split_bounds(total, minibatches)
    cloned = bc_weight > 0
    orders, bc_rows = [], []
    for _ in range(hp.n_epochs):
        orders.append(torch.randperm(total, generator=generator))
        if cloned:
            bc_rows += [torch.randint(bc.labels.shape[0], (int(bounds[k + 1] - bounds[k]),), generator=generator)
                        for k in range(minibatches)]
    layout, actor_layers = parameter_layout(model, optimizer.flat_param)
    n_obs = obs.shape[1]
    bc_obs = bc.obs.numpy() if cloned else np.zeros((0, n_obs), np.float32)
    bc_labels = bc.labels.numpy() if cloned else np.zeros(0, np.int64)
    bc_rows = (torch.cat(bc_rows).view(hp.n_epochs, total).numpy() if cloned else np.zeros((0, 0), np.int64))
    with blas_threads(torch.get_num_threads()):
        sums, steps = ppo_update(
            optimizer.flat_param.numpy(), optimizer.flat_grad.numpy(), optimizer.exp_avg.numpy(),
            optimizer.exp_avg_sq.numpy(), layout, actor_layers, obs.contiguous().numpy(),
            actions.contiguous().numpy(), old_logp.contiguous().numpy(), advantages.contiguous().numpy(),
            returns.contiguous().numpy(),
            np.zeros((0, model.n_actions), np.bool_) if masks is None else masks.contiguous().numpy(),
            torch.stack(orders).numpy(), bounds, bc_obs, bc_labels, bc_rows, float(bc_weight), float(hp.clip_range),
            float(hp.vf_coef), float(hp.ent_coef), bool(hp.normalize_advantage), float(hp.max_grad_norm),
            float(optimizer.param_groups[0]["lr"]), optimizer.betas[0], optimizer.betas[1], optimizer.eps,
            optimizer.steps, MASKED_LOGIT)
    optimizer.steps = int(steps)
    count = hp.n_epochs * minibatches
    entropy, approx_kl, clip_fraction = (sums / count).tolist()
    return {"entropy": entropy, "approx_kl": approx_kl, "clip_fraction": clip_fraction}
