"""What the fused losses share: numpy views of their tensors, and a loss value whose gradient the
numba pass that computed it has already written.

`ncc_fused` and `normals_fused` compute a scalar loss and its gradient in one pass; each loss's
autograd node is a subclass of `PrecomputedGrad` (so the graph names the loss), which hands the
value to torch and scales the stored gradient by the upstream one on the way back.
"""

from __future__ import annotations

import numpy as np
import torch
from numba import njit


def as_numpy(t: torch.Tensor) -> np.ndarray:
    """A C-contiguous numpy array of a CPU tensor's values (no gradient)."""
    return np.ascontiguousarray(t.detach().numpy())


class PrecomputedGrad(torch.autograd.Function):
    """apply(x, value, grad): the scalar value as a function of x with dL/dx = grad."""

    @staticmethod
    def forward(ctx, x, value, grad):
        ctx.grad = grad
        return x.new_tensor(value)

    @staticmethod
    def backward(ctx, g):
        return g * ctx.grad, None, None


def loss_with_grad(node: type[PrecomputedGrad], x: torch.Tensor, value: float, grad: np.ndarray) -> torch.Tensor:
    """The scalar `value` (x's dtype) as a loss of x whose gradient dL/dx is grad (x's shape),
    through the autograd node `node`."""
    return node.apply(x, value, torch.from_numpy(grad))


@njit(cache=True)
def ordered_sums(totals, counts):
    """(sum of totals [R], sum of counts [R]) added in row order: the per-row partial sums of a pass
    that ran its rows in parallel, so that the result does not depend on the thread count."""
    total, count = 0.0, 0
    for i in range(totals.shape[0]):
        total += totals[i]
        count += counts[i]
    return total, count
