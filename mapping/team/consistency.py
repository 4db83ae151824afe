"""Parameter consistency between agents (paper eq. 12), as three options of one mechanism.

Each agent keeps the last parameters received from each peer for the instances both hold (aligned
ids, the same frame: ``mapping.instances.InstanceFrame``). A *pair* is (own row, peer vector). Per round:
``begin`` runs once before the consistency iterations, ``penalty`` is added to every iteration's loss.

- ``consensus`` (MACIM): (rho/2) ||theta - (theta_0 + theta_j)/2||^2, theta_0 the own parameters at the
  start of the round's consistency iterations (the midpoint is fixed during them), and with
  ``ConsistencyConfig.local_consensus`` also in every local iteration with theta_0 the current
  parameters (MACIM's per-step form); rho 3 by default (MACIM: 0.3).
- ``dinno`` (DiNNO's ADMM): ``begin`` updates each own row's dual, p += rho sum_j (theta - theta_j);
  the penalty is theta . p + rho sum_j ||theta - (theta_0 + theta_j)/2||^2.
- ``dsgd``: ``begin`` mixes with Metropolis weights W_kj = 1 / (max(deg_k, deg_j) + 1),
  theta <- W_kk theta + sum_j W_kj theta_j; no penalty (the iterations are plain gradient steps).
- ``none``: nothing (each agent optimises its data loss only).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

CONSISTENCY_ALGORITHMS = ("consensus", "dinno", "dsgd", "none")


@dataclass
class ConsistencyPairs:
    """The pairs of one bank: own ``rows`` (K,), peer ``vectors`` (K, D), the peers' ``degrees`` (K,)
    and this agent's degree per pair (K,) (peers it holds parameters of for that row)."""

    rows: Tensor
    vectors: Tensor
    peer_degrees: Tensor
    own_degrees: Tensor

    def __len__(self) -> int:
        return len(self.rows)


def consensus_penalty(params: Tensor, anchor: Tensor, pairs: ConsistencyPairs, rho: float) -> Tensor:
    """MACIM's (rho/2) sum_pairs ||theta_row - (anchor_row + theta_j)/2||^2.

    Args:
        params: (N, D) the bank's parameters (with grad).
        anchor: (N, D) the parameters when the iterations began, or the current ones detached (no grad).
        pairs: K pairs.
    """
    if len(pairs) == 0:
        return params.new_zeros(())
    mid = (anchor[pairs.rows] + pairs.vectors) / 2.0
    return 0.5 * rho * (params[pairs.rows] - mid).square().sum()


def dinno_dual_update(duals: Tensor, params: Tensor, pairs: ConsistencyPairs, rho: float) -> Tensor:
    """DiNNO's dual ascent: p_row += rho sum_j (theta_row - theta_j); (N, D) duals returned."""
    if len(pairs) == 0:
        return duals
    return duals.index_add(0, pairs.rows, rho * (params.detach()[pairs.rows] - pairs.vectors))


def dinno_penalty(params: Tensor, anchor: Tensor, duals: Tensor, pairs: ConsistencyPairs, rho: float) -> Tensor:
    """DiNNO's augmented term: theta . p + rho sum_j ||theta - (theta_0 + theta_j)/2||^2 on paired rows."""
    if len(pairs) == 0:
        return params.new_zeros(())
    rows = torch.unique(pairs.rows)
    linear = (params[rows] * duals[rows]).sum()
    mid = (anchor[pairs.rows] + pairs.vectors) / 2.0
    return linear + rho * (params[pairs.rows] - mid).square().sum()


def metropolis_mix(params: Tensor, pairs: ConsistencyPairs) -> Tensor:
    """DSGD's mixing step on the paired rows ((N, D) returned, unpaired rows unchanged):
    W_kj = 1 / (max(deg_k, deg_j) + 1), W_kk = 1 - sum_j W_kj."""
    if len(pairs) == 0:
        return params.detach().clone()
    weights = 1.0 / (torch.maximum(pairs.own_degrees, pairs.peer_degrees).to(params.dtype) + 1.0)  # (K,)
    mixed = params.detach().clone()
    self_weight = torch.ones(len(params), dtype=params.dtype, device=params.device).index_add(
        0, pairs.rows, -weights)
    mixed = mixed * self_weight[:, None]
    return mixed.index_add(0, pairs.rows, weights[:, None] * pairs.vectors)
