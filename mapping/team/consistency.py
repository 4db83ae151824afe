"""Parameter consistency between agents (paper eq. 12), as three options of one mechanism.

Each agent keeps the last parameters received from each peer for the instances both hold (aligned
ids, the same frame: ``mapping.model.instances.InstanceFrame``). A *pair* is (own row, peer vector). Per round:
``begin`` runs once before the consistency iterations, ``penalty`` is added to every iteration's loss.

- ``consensus`` (MACIM): (rho/2) ||theta - (theta_0 + theta_j)/2||^2, theta_0 the own parameters at the
  start of the round's consistency iterations (the midpoint is fixed during them), and with
  ``ConsistencyConfig.local_consensus`` also in every local iteration with theta_0 the current
  parameters (MACIM's per-step form); rho 3 by default (MACIM: 0.3).
- ``dinno`` (DiNNO's ADMM): ``begin`` updates each own row's dual, p += rho sum_j (theta - theta_j);
  the penalty is theta . p + rho sum_j ||theta - (theta_0 + theta_j)/2||^2.
- ``dsgd``: ``begin`` mixes with Metropolis weights W_kj = 1 / (max(deg_k, deg_j) + 1),
  theta <- W_kk theta + sum_j W_kj theta_j; no penalty (the iterations are plain gradient steps).
  The weights must be the same at both ends of an edge, or W is not doubly stochastic and the team's
  average drifts: after the parameters arrive, each agent sends each peer a ``DegreeMessage`` listing
  its pairs with that peer and its degree per instance (``degree_listing``), and an edge is used only
  where both ends listed it and both listings arrived (``metropolis_weights``; the sender learns its
  listing arrived from the link's acknowledgement). The degrees are those listed, counted before
  the listings crossed, so a weight is known to both ends and every row of W still sums to 1
  (W_kk = 1 - sum_j W_kj >= 1 / (deg_k + 1)). W is doubly stochastic over the vectors as they were
  sent; an agent that refits a row's frame or merges instances when parameters arrive mixes its
  row as it is after that, so the team's average is kept only up to those changes.
- ``none``: nothing (each agent optimises its data loss only).

DiNNO and DSGD act only on vectors that arrived this round (``ConsistencyConfig.missing_edges``:
``skip``, as RAMEN skips the edges its channel dropped; ``last`` keeps using the last vector held, the
stale form, for comparison); consensus always pulls toward the last vector held, as MACIM does.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from typing import Mapping, Sequence

import torch
from torch import Tensor

CONSISTENCY_ALGORITHMS = ("consensus", "dinno", "dsgd", "none")
MISSING_EDGES = ("skip", "last")
"""What DiNNO and DSGD do with a peer whose vector did not arrive this round (see the module docstring)."""


@dataclass
class ConsistencyPairs:
    """The pairs of one bank: own ``rows`` (K,), peer ``vectors`` (K, D), and for DSGD each pair's
    Metropolis weight W_kj (K,) (None for the other algorithms)."""

    rows: Tensor
    vectors: Tensor
    weights: Tensor | None = None

    def __len__(self) -> int:
        return len(self.rows)


@dataclass(frozen=True, order=True)
class PairKey:
    """Who a pair joins: ``peer``'s instance ``peer_id`` paired with my instance ``own_id``."""

    peer: int
    own_id: int
    peer_id: int


def own_degrees(keys: Sequence[PairKey]) -> dict[int, int]:
    """My degree per instance: how many peers I pair it with."""
    return dict(Counter(key.own_id for key in keys))


def degree_listing(keys: Sequence[PairKey], peer: int) -> tuple[list[int], list[int], list[int]]:
    """What I tell ``peer`` after an exchange (a ``DegreeMessage``'s arrays): for each of my pairs with
    it, my instance id, its instance id, and my degree for that instance (how many peers I pair it with)."""
    degree = own_degrees(keys)
    mine = [k for k in keys if k.peer == peer]
    return [k.own_id for k in mine], [k.peer_id for k in mine], [degree[k.own_id] for k in mine]


def metropolis_weights(keys: Sequence[PairKey], listings: Mapping[int, tuple[Sequence[int], Sequence[int],
                                                                              Sequence[int]]],
                       acknowledged: set[int] | frozenset[int]) -> list[float]:
    """W_kj of each of my pairs (0: the edge is not used this round).

    Args:
        keys: my pairs (``PairKey``).
        listings: per peer, the ``degree_listing`` it sent me (its own ids, my ids, its degrees), for the
            peers whose listing arrived.
        acknowledged: the peers my own listing reached.

    An edge is used when both ends listed it and both listings arrived: then both ends hold the same two
    degrees and compute the same weight 1 / (max(deg_k, deg_j) + 1).
    """
    degree = own_degrees(keys)
    theirs = {peer: {(int(p), int(o)): int(d) for p, o, d in zip(*listing)} for peer, listing in listings.items()}
    weights = []
    for key in keys:
        peer_degree = theirs.get(key.peer, {}).get((key.peer_id, key.own_id)) if key.peer in acknowledged else None
        weights.append(0.0 if peer_degree is None else 1.0 / (max(degree[key.own_id], peer_degree) + 1.0))
    return weights


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
    theta_k <- W_kk theta_k + sum_j W_kj theta_j with the pairs' weights, W_kk = 1 - sum_j W_kj."""
    if len(pairs) == 0:
        return params.detach().clone()
    if pairs.weights is None:
        raise ValueError("DSGD's mixing needs the pairs' Metropolis weights (metropolis_weights)")
    weights = pairs.weights.to(params)  # (K,)
    mixed = params.detach().clone()
    self_weight = torch.ones(len(params), dtype=params.dtype, device=params.device).index_add(
        0, pairs.rows, -weights)
    mixed = mixed * self_weight[:, None]
    return mixed.index_add(0, pairs.rows, weights[:, None] * pairs.vectors)
