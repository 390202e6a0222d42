"""The native PPO's gradients written out: the clipped loss's with respect to the logits and values,
and the actor's and critic's backward.

The update spends its time in two small MLPs ([64, 64], tanh) and a loss of some twenty operations
on minibatches of about a thousand samples. Through autograd every operation is a graph node with
its own saved tensors, the tanh's backward three passes over its activations, and the weight
gradient of the first layer a ``[64, B] @ [B, F]`` product that the BLAS runs several times slower
than its transpose when F (the observation) is small. Here the forward is the networks' own (the
same ``addmm`` and tanh, bit for bit), the loss's gradient is its closed form, and the backward runs
layer by layer into one flat gradient buffer that the parameters' ``.grad`` are views of, so the
norm clip is two operations instead of one per tensor. ``tests/training/test_ppo_gradients.py``
checks every gradient against autograd's on the same loss.
"""

from __future__ import annotations

import contextlib
import math
from typing import Any

import torch

from containergym_marl.policies._fast_tanh import tanh_of_doubled_
from containergym_marl.policies.actor_critic import MASKED_LOGIT, ActorCritic


def _views(flat: torch.Tensor, params: list[torch.Tensor]) -> list[torch.Tensor]:
    """Consecutive views of ``flat`` shaped as each of ``params``, in order."""
    views, offset = [], 0
    for p in params:
        views.append(flat[offset:offset + p.numel()].view_as(p))
        offset += p.numel()
    return views


class FlatAdam:
    """Adam on parameters that are views of one flat buffer: torch's update rule (no weight decay,
    no AMSGrad) in five in-place operations per step, where ``torch.optim.Adam`` (even fused) costs
    several times that in per-step bookkeeping for a dozen small tensors.

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

    def step(self) -> None:
        self.steps += 1
        beta1, beta2 = self.betas
        g = self.flat_grad
        self.exp_avg.lerp_(g, 1.0 - beta1)
        self.exp_avg_sq.mul_(beta2).addcmul_(g, g, value=1.0 - beta2)
        bias1, bias2 = 1.0 - beta1 ** self.steps, 1.0 - beta2 ** self.steps
        denom = (self.exp_avg_sq.sqrt() / math.sqrt(bias2)).add_(self.eps)
        self.flat_param.addcdiv_(self.exp_avg, denom, value=-self.param_groups[0]["lr"] / bias1)

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


class MLPGradients:
    """Forward and backward of ``model``'s two networks with the gradients in one flat buffer.

    ``forward(obs)`` returns (logits, values) and keeps the activations; ``backward(g_logits,
    g_values)`` writes the parameters' gradients (``p.grad``, views of :attr:`flat_grad`, for the
    optimiser); :meth:`clip_grad_norm_` is ``torch.nn.utils.clip_grad_norm_`` on that buffer, which is
    ``optimizer``'s own when it is a :class:`FlatAdam`.
    """

    def __init__(self, model: ActorCritic, optimizer=None):
        # each layer's (weight, bias) Parameters, looked up once: a module attribute lookup costs about
        # as much as the rollout's small matrix product (the Parameters persist when their data moves)
        self.params = [[(m.weight, m.bias) for m in net if isinstance(m, torch.nn.Linear)]
                       for net in (model.net.actor, model.net.critic)]
        # The forward's (bias, transposed weight) of each layer. A hidden layer's are copies times 2,
        # views of one buffer: its product is then 2x exactly (scaling by 2 rounds nothing), the tanh's
        # first doubling done; each forward copies them afresh, but once for all the forwards inside
        # fixed_parameters(). The output layers' are views of the parameters, valid while their data
        # stays where it is.
        self._hidden = [p for layers in self.params for layer in layers[:-1] for p in layer]
        self._doubled = torch.empty(sum(p.numel() for p in self._hidden))
        doubled = dict((id(p), d) for p, d in zip(self._hidden, _views(self._doubled, self._hidden)))
        self._forward_layers = [[(doubled[id(bias)], doubled[id(weight)].t()) for weight, bias in layers[:-1]]
                                + [(layers[-1][1], layers[-1][0].t())] for layers in self.params]
        self._fixed = False
        params = list(model.net.parameters())
        self.flat_grad = optimizer.flat_grad if isinstance(optimizer, FlatAdam) else torch.zeros(
            sum(p.numel() for p in params))
        for p, grad in zip(params, _views(self.flat_grad, params)):  # the optimiser reads p.grad: never replaced
            p.grad = grad
        self._inputs: list[list[torch.Tensor]] = [[], []]

    def forward(self, obs: torch.Tensor, keep: bool = True) -> tuple[torch.Tensor, torch.Tensor]:
        """The raw logits [B, A] and values [B] of observations [B, F]; with ``keep``, the
        activations for :meth:`backward` (without: the rollout's forward, no module calls)."""
        if torch.is_grad_enabled():
            with torch.no_grad():
                return self._forward(obs, keep)
        return self._forward(obs, keep)  # the rollout runs in inference mode: no context to enter

    @contextlib.contextmanager
    def fixed_parameters(self):
        """Forwards (a rollout's) between which the parameters do not change: the hidden layers'
        doubled copies are made once, on entering."""
        self._double()
        self._fixed = True
        try:
            yield self
        finally:
            self._fixed = False

    def _double(self) -> None:
        with torch.no_grad():
            torch.cat([p.reshape(-1) for p in self._hidden], out=self._doubled).mul_(2.0)

    def _forward(self, obs: torch.Tensor, keep: bool) -> tuple[torch.Tensor, torch.Tensor]:
        if not self._fixed:
            self._double()
        outputs = []
        for k, layers in enumerate(self._forward_layers):
            inputs, x, last = [], obs, len(layers) - 1
            for i, (bias, weight_t) in enumerate(layers):
                inputs.append(x)
                x = torch.addmm(bias, x, weight_t)
                if i < last:
                    x = tanh_of_doubled_(x)
            if keep:
                self._inputs[k] = inputs
            outputs.append(x)
        return outputs[0], outputs[1].squeeze(-1)

    def backward(self, g_logits: torch.Tensor, g_values: torch.Tensor) -> None:
        with torch.no_grad():
            for layers, inputs, g in zip(self.params, self._inputs, (g_logits, g_values[:, None])):
                for i in reversed(range(len(layers))):
                    (weight, bias), x = layers[i], inputs[i]
                    bias.grad.copy_(g.sum(0))
                    # dW = gᵀ x, the product taken with the narrower side as its rows (F = 7: 5× faster)
                    if x.shape[1] < g.shape[1]:
                        weight.grad.copy_(x.t().mm(g).t())
                    else:
                        torch.mm(g.t(), x, out=weight.grad)
                    if i > 0:  # through the layer, then through the tanh that made x: (1 − x²)
                        g = g.mm(weight)
                        g = torch.addcmul(g, g * x, x, value=-1.0)
            self._inputs = [[], []]

    def clip_grad_norm_(self, max_norm: float) -> None:
        # torch.nn.utils.clip_grad_norm_'s rule (coefficient max_norm / (norm + 1e-6), at most 1)
        norm = float(torch.linalg.vector_norm(self.flat_grad))
        self.flat_grad.mul_(min(max_norm / (norm + 1e-6), 1.0))


def ppo_loss_gradients(logits: torch.Tensor, values: torch.Tensor, actions: torch.Tensor, old_logp: torch.Tensor,
                       advantages: torch.Tensor, returns: torch.Tensor, clip_range: float, vf_coef: float,
                       ent_coef: float, masks: torch.Tensor | None = None
                       ) -> tuple[torch.Tensor, torch.Tensor, dict[str, torch.Tensor]]:
    """The gradients of SB3's PPO loss on one minibatch with respect to the networks' raw logits [B, A]
    and values [B], and the minibatch's diagnostics (0-d tensors: ``entropy``, ``approx_kl``,
    ``clip_fraction``).

    The loss is −mean(min(A·r, A·clip(r, 1 ± ε))) + vf_coef · mean((R − V)²) − ent_coef · mean(H)
    with r = π(a|s) / π_old(a|s), the advantages A as given (normalised by the caller). Where the two
    surrogates tie (r within the clip range), the gradient flows through r, as autograd's halves
    through both add up to; masked logits (``masks`` False) get none.
    """
    b = logits.shape[0]
    if masks is not None:
        logits = logits.masked_fill(~masks, MASKED_LOGIT)
    log_probs = torch.log_softmax(logits, -1)
    probs = log_probs.exp()
    a = actions[:, None]
    log_ratio = log_probs.gather(-1, a).squeeze(-1) - old_logp
    ratio = log_ratio.exp()
    clipped = ratio.clamp(1.0 - clip_range, 1.0 + clip_range)
    through_ratio = advantages * ratio <= advantages * clipped  # the unclipped surrogate is the min
    # d loss / d log π(a|s) = −A·r/B where the gradient flows; d log π(a|s) / d z = onehot(a) − π
    coef = torch.where(through_ratio, advantages * ratio, 0.0).div_(-b)
    g_logits = probs * (-coef[:, None])
    g_logits.scatter_add_(-1, a, coef[:, None])
    # masked actions have probability 0: p log p is 0 there, not nan
    plogp = probs * log_probs.clamp_min(torch.finfo(log_probs.dtype).min)
    entropy = -plogp.sum(-1)
    if ent_coef:  # d H / d z_k = −π_k (log π_k + H)
        g_logits.add_((plogp + probs * entropy[:, None]).mul_(ent_coef / b))
    g_values = (values - returns).mul_(2.0 * vf_coef / b)
    diagnostics = {"entropy": entropy.mean(), "approx_kl": ((ratio - 1) - log_ratio).mean(),
                   "clip_fraction": ((ratio - 1).abs() > clip_range).float().mean()}
    return g_logits, g_values, diagnostics


__all__ = ["FlatAdam", "MLPGradients", "ppo_loss_gradients"]
