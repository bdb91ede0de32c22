"""The paper's semi-supervised loss, Eq. (8), plus the optional class-balance term (see the package docstring)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F


@dataclass(frozen=True)
class LossParts:
    """Scalar tensors: total = labelled + constraint + balance (each 0 when its part is empty/off)."""

    total: torch.Tensor
    labelled: torch.Tensor
    constraint: torch.Tensor
    balance: torch.Tensor


def semi_supervised_loss(
    logits_labelled: torch.Tensor,
    labels: torch.Tensor,
    logits_i: torch.Tensor,
    logits_j: torch.Tensor,
    gamma: float,
    pair_weights: torch.Tensor | None = None,
    balance_weight: float = 0.0,
    constraint_loss: str = "paper",
) -> LossParts:
    """The paper's L = L_l + L_c, plus the optional class-balance term.

    logits_labelled: (m, K) of the labelled samples, labels (m,) int64; m may be 0.
    logits_i, logits_j: (n, K) of the two sides of the n pairs; n may be 0.
    pair_weights: (n,) w_n, None = all 1 (the paper).
    constraint_loss: "paper" (1 - P_i . P_j) or "squared" (1/2 |P_i - P_j|^2, `TrainingConfig`).
    """
    m, n = len(logits_labelled), len(logits_i)
    if m == 0 and n == 0:
        raise ValueError("a batch needs labelled samples or pairs")
    zero = (logits_labelled if m else logits_i).new_zeros(())
    l_l = F.cross_entropy(logits_labelled, labels) if m else zero
    l_c, l_b = zero, zero
    if n:
        p_i = torch.softmax(logits_i, dim=1)  # (n, K)
        p_j = torch.softmax(logits_j, dim=1)  # (n, K)
        if constraint_loss == "squared":
            disagree = 0.5 * (p_i - p_j).square().sum(dim=1)  # (n,)
        else:
            disagree = 1.0 - (p_i * p_j).sum(dim=1)  # (n,) P(y_i != y_j)
        if pair_weights is not None:
            disagree = disagree * pair_weights
        l_c = gamma * disagree.sum() / n
        if balance_weight > 0:
            p_mean = torch.cat([p_i, p_j]).mean(dim=0)  # (K,) batch-mean prediction
            entropy = -(p_mean * torch.log(p_mean.clamp_min(1e-12))).sum()
            l_b = balance_weight * (math.log(p_mean.numel()) - entropy)
    return LossParts(l_l + l_c + l_b, l_l, l_c, l_b)
