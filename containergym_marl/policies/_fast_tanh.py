"""tanh as 2·sigmoid(2x) − 1, for the native PPO's networks.

On x86 CPUs torch's own ``tanh`` kernel (SLEEF's 1-ULP tanh) costs several times its ``sigmoid``,
and the two tanh layers of each network were the largest single cost of a PPO update
(``benchmarks/RESULTS.md``, run 10). This form computes the same function to within 2e-7
(absolute) from the fast sigmoid, and its backward reuses the output: d tanh = 1 − y².
"""

from __future__ import annotations

import torch


_MINUS_ONE = torch.tensor(-1.0)


def tanh_of_doubled_(z2: torch.Tensor) -> torch.Tensor:
    """tanh of x = z2 / 2, in place on ``z2``, outside autograd: 2·sigmoid(z2) − 1 computed as
    −1 + 2·sigmoid(z2), two passes (2·s is exact, so it rounds as 2·s − 1 would). The one formula of the
    module, the trainer's forward (which doubles its weights instead of x) and the decisions'."""
    return torch.add(_MINUS_ONE, torch.sigmoid_(z2), alpha=2.0, out=z2)


def tanh_(x: torch.Tensor) -> torch.Tensor:
    """:class:`Tanh` of ``x`` in place, outside autograd (the same values): the decisions' forward,
    without the module's and the autograd function's per-call cost."""
    return tanh_of_doubled_(x.mul_(2.0))  # doubling is exact


class _TanhFunction(torch.autograd.Function):
    @staticmethod
    def forward(ctx, x):
        y = tanh_of_doubled_(x * 2.0)
        ctx.save_for_backward(y)
        return y

    @staticmethod
    def backward(ctx, grad):
        (y,) = ctx.saved_tensors
        return grad * (1.0 - y * y)


class Tanh(torch.nn.Module):
    """``torch.nn.Tanh`` computed through the sigmoid (no parameters: state dicts are unchanged)."""

    def forward(self, x):
        return _TanhFunction.apply(x)
