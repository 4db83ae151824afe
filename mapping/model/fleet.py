"""The fleet-batched learner: every agent's training step in one batched field evaluation per bank.

In simulation all agents live in one process, and a training step of one agent is a few small
batched matmuls whose fixed cost (launching the kernels, the encoding, autograd's bookkeeping) is
paid per agent and bank. ``fleet_step`` pays it once per team: each agent samples its own rays from
its own keyframes with its own generators (``MappingAgent.training_batches``), the rows of every
agent's bank of one kind are stacked into one evaluation (rows = agents x instances), the output is
split back, and each agent's loss is its own data loss plus its own extra terms (eq. 12-13). One
backward of the sum gives every agent exactly the gradient of its own loss (the parameters are
disjoint), and each agent's AdamW steps its own rows with its own state. Nothing crosses between
agents: the batch is an arithmetic arrangement, not an exchange.

``MappingAgent.train`` stays the per-agent form (one process per robot, ``mapping.team.remote``);
``tests/test_fleet.py`` shows both give the same maps to float tolerance.
"""

from __future__ import annotations

from typing import Callable, Sequence

import torch

from mapping.model.agent import MappingAgent
from mapping.model.sdf_field import SdfBatch
from mapping.model.training_batch import TrainingBatch
from mapping.model.field import FieldOutput
from mapping.runtime import flushed_denormals

ExtraLoss = Callable[[], torch.Tensor] | None


def fleet_train(agents: Sequence[MappingAgent], iterations: Sequence[int],
                extra_losses: Sequence[ExtraLoss] | None = None) -> list[float]:
    """Run ``iterations[i]`` training steps of agent i, all agents' steps batched together.

    Step k trains the agents with more than k iterations; an agent's result is what
    ``agents[i].train(iterations[i], extra_losses[i])`` would give (its last total loss), 0.0 for an
    agent with no iterations.
    """
    if len(iterations) != len(agents):
        raise ValueError(f"{len(agents)} agents but {len(iterations)} iteration counts")
    extras = list(extra_losses) if extra_losses is not None else [None] * len(agents)
    if len(extras) != len(agents):
        raise ValueError(f"{len(agents)} agents but {len(extras)} extra losses")
    if any(n < 0 for n in iterations):
        raise ValueError(f"iteration counts must be >= 0, got {list(iterations)}")
    if len({id(a) for a in agents}) != len(agents):
        raise ValueError("an agent appears twice in the fleet")
    losses = [0.0] * len(agents)
    with flushed_denormals():  # as MappingAgent.train (mapping.runtime)
        for k in range(max(iterations, default=0)):
            active = [i for i, n in enumerate(iterations) if n > k]
            step = fleet_step([agents[i] for i in active], [extras[i] for i in active])
            for i, loss in zip(active, step):
                losses[i] = loss
    return losses


def fleet_step(agents: Sequence[MappingAgent], extra_losses: Sequence[ExtraLoss]) -> list[float]:
    """One training step of every agent (``MappingAgent.train_step`` each), the fields evaluated jointly."""
    batches = [agent.training_batches() for agent in agents]
    outputs = joint_evaluation(agents, batches)
    totals = []
    for agent, own_batches, own_outputs, extra in zip(agents, batches, outputs, extra_losses):
        total = torch.zeros((), device=agent.device)
        for batch, out in zip(own_batches, own_outputs):
            total = agent.add_batch_loss(total, batch, out)
        if extra is not None:
            total = total + extra()
        totals.append(total)
    for agent in agents:
        for optimiser in agent.optimisers.values():
            optimiser.zero_grad()
    graded = [t for t in totals if t.requires_grad]
    if graded:
        torch.autograd.backward(graded)  # each agent's own gradient: the parameters are disjoint
    return [agent.step_optimisers(total) for agent, total in zip(agents, totals)]


def joint_evaluation(agents: Sequence[MappingAgent], batches: Sequence[Sequence[TrainingBatch | SdfBatch]]
                     ) -> list[list[FieldOutput | None]]:
    """Every batch's field output, batches of the same bank kind (same network width, encoding,
    device and samples per instance) evaluated as one stacked computation; ``[agent][batch]`` (None for
    an ``SdfBatch``: MACIM's loss evaluates its network itself, with the gradient it needs)."""
    groups: dict[tuple, list[tuple[int, int]]] = {}
    for a, (agent, own) in enumerate(zip(agents, batches)):
        for b, batch in enumerate(own):
            if isinstance(batch, SdfBatch):  # MACIM's loss evaluates its own network (add_batch_loss)
                continue
            bank = agent.banks[batch.bank]
            key = (batch.bank, bank.config, str(bank.device), batch.positions.shape[1])
            groups.setdefault(key, []).append((a, b))
    outputs: list[list[FieldOutput | None]] = [[None] * len(own) for own in batches]
    for members in groups.values():
        banks = [agents[a].banks[batches[a][b].bank] for a, b in members]
        parts = [batches[a][b] for a, b in members]
        params = torch.cat([bank.params.index_select(0, part.rows) for bank, part in zip(banks, parts)])
        unit = torch.cat([bank.to_unit(part.positions, part.rows) for bank, part in zip(banks, parts)])
        occupancy, colour = banks[0].evaluate_unit(params, unit, with_colour=True)
        sizes = [len(part.rows) for part in parts]
        for (a, b), occ, col in zip(members, occupancy.split(sizes), colour.split(sizes)):
            outputs[a][b] = FieldOutput(occ, col)
    return outputs


__all__ = ["ExtraLoss", "fleet_step", "fleet_train", "joint_evaluation"]
