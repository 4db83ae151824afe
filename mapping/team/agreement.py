"""Agreement between a team member and its peers: parameter consistency (eq. 12) and Cross Rendering
Supervision (eq. 13) in the consistency iterations after an exchange (step 6 of a round), and eq. 12's
consensus term inside the local iterations (``local_consensus``, MACIM's per-step form).

A mixin of ``TeamMember``: the state it reads and writes is the member's (``mapping.team.member``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import Callable, Sequence

import numpy as np
import torch

from mapping.model.field import InstanceFieldBank, LiveRows
from mapping.team.consistency import (ConsistencyPairs, PairKey, consensus_penalty, degree_listing,
                                      dinno_dual_update, dinno_penalty, metropolis_mix, metropolis_weights)
from mapping.team.cross_rendering import (instance_render_consistency_loss, peer_render_targets, rays_of_message,
                                         render_consistency_loss)
from mapping.team.inbox import payload_frame
from mapping.team.messages import DegreeMessage, InstancePayload, RayMessage
from mapping.team.report import ConsistencyTerms


class PenaltyReading:
    """The last value of a penalty computed inside the training loop, kept as a tensor (no device sync per
    step) and read once after it."""

    def __init__(self) -> None:
        self.value: torch.Tensor | None = None

    def read(self) -> float:
        return 0.0 if self.value is None else float(self.value)


@dataclass
class ConsistencyWork:
    """Consistency iterations about to run (``Agreement.prepare_consistency``): how many, the extra term
    each adds to the data loss and the terms they fill in."""

    iterations: int
    extra: Callable[[], torch.Tensor] | None
    terms: ConsistencyTerms
    seconds: float
    """Its own compute time so far (pairs, mixing, the peers' renderings)."""


class Agreement:
    """Eq. 12 and eq. 13 for a ``TeamMember``."""

    def local_consensus(self, reading: PenaltyReading) -> Callable[[], torch.Tensor] | None:
        """Eq. 12's consensus term toward the parameters held from the peers, for every local iteration
        (MACIM's midpoint of my current and the peer's parameters; its value goes to
        ``reading``); None when nothing is paired."""
        if self.config.consistency.algorithm != "consensus":
            return None
        pairs = {name: self._pairs(name)[0] for name in self.mapper.banks}
        if not any(len(p) for p in pairs.values()):
            return None
        rho = self.config.consistency.penalty_rho

        def penalty() -> torch.Tensor:
            total = torch.zeros((), device=self.mapper.device)
            for name, bank in self.mapper.banks.items():
                total = total + consensus_penalty(bank.params, bank.params.detach(), pairs[name], rho)
            reading.value = total.detach()  # a tensor: no device sync inside the training loop
            return total
        return penalty

    def degree_messages(self, round_index: int) -> list[DegreeMessage]:
        """DSGD: after this round's parameters arrived, one listing for each peer I pair instances with
        and whose copy of my parameters is this round's (the plan sent them and the link acknowledged
        them: otherwise the peer cannot use the edge, and the plan asked for no message): my pairs with
        it and my degree per instance, so that both ends weigh an edge alike. None for the other
        algorithms."""
        if self.config.consistency.algorithm != "dsgd":
            return []
        keys = [k for name in self.mapper.banks for k in self._pairs(name, self._fresh_round(round_index))[1]]
        reached = {peer for peer, r in self.delivered_round["params"].items() if r == round_index}
        return [DegreeMessage(self.index, peer, round_index, *(np.asarray(x, np.int64) for x in degree_listing(keys, peer)))
                for peer in sorted({k.peer for k in keys} & reached)]

    def consistency_round(self, ray_messages: Sequence[RayMessage], round_index: int,
                          listings: Sequence[DegreeMessage] = (), acknowledged: frozenset[int] = frozenset()
                          ) -> ConsistencyTerms:
        """Data loss + parameter consistency (eq. 12) + render consistency (eq. 13) iterations.

        Args:
            ray_messages: the ray messages that arrived this round.
            round_index: this round (DiNNO and DSGD use only the vectors that arrived in it).
            listings: DSGD: the peers' ``degree_messages`` that arrived; acknowledged: the peers my own
                listing reached.
        """
        work = self.prepare_consistency(ray_messages, round_index, listings, acknowledged)
        start = time.perf_counter()
        loss = self.mapper.train(work.iterations, work.extra) if work.iterations else 0.0
        return self.finish_consistency(work, loss, time.perf_counter() - start)

    def finish_consistency(self, work: ConsistencyWork, loss: float, train_s: float) -> ConsistencyTerms:
        """The round's consistency terms once ``work.iterations`` were trained (``loss``: the last total,
        ``train_s``: the seconds they took)."""
        if work.iterations:
            work.terms.loss = loss
        work.terms.seconds = work.seconds + train_s
        return work.terms

    def prepare_consistency(self, ray_messages: Sequence[RayMessage], round_index: int,
                            listings: Sequence[DegreeMessage] = (), acknowledged: frozenset[int] = frozenset()
                            ) -> ConsistencyWork:
        """``consistency_round`` up to its training: pairs, duals or mixing, the peers' renderings, and the
        extra term (eq. 12 + 13) every consistency iteration adds to the data loss."""
        c = self.config.consistency
        start = time.perf_counter()
        fresh = self._fresh_round(round_index)
        if c.algorithm == "dsgd":
            self.mixing_weights = {}
            received = {m.sender: (m.own_ids, m.peer_ids, m.degrees) for m in listings
                        if m.receiver == self.index and m.round == round_index}  # this round's, for me
            pairs = {name: self._weighted(*self._pairs(name, fresh), received, acknowledged)
                     for name in self.mapper.banks}
        else:
            pairs = {name: self._pairs(name, fresh)[0] for name in self.mapper.banks}
        anchors = {name: bank.params.detach().clone() for name, bank in self.mapper.banks.items()}
        if c.algorithm == "dinno":
            for name, bank in self.mapper.banks.items():
                dual = self.duals.get(name)
                if dual is None or dual.shape != bank.params.shape:
                    grown = torch.zeros_like(bank.params.detach())
                    if dual is not None:
                        grown[:len(dual)] = dual
                    dual = grown
                self.duals[name] = dinno_dual_update(dual, bank.params, pairs[name], c.penalty_rho)
        elif c.algorithm == "dsgd":
            for name, bank in self.mapper.banks.items():
                with torch.no_grad():
                    bank.params.copy_(metropolis_mix(bank.params, pairs[name]))
        rays = [rays_of_message(m, self.mapper.device) for m in ray_messages if m.sender in self.held] \
            if c.cross_rendering else []
        senders = [m.sender for m in ray_messages if m.sender in self.held] if c.cross_rendering else []
        terms = ConsistencyTerms()
        n_pairs = sum(len(p) for p in pairs.values())
        if n_pairs == 0 and not rays:
            return ConsistencyWork(0, None, terms, time.perf_counter() - start)

        own_fields, own_labels = self._own_fields()
        observed = self.mapper.keyframes.observes if c.blind_zones_only else None
        weights = replace(self.config.mapping.loss_weights, colour=0.0, depth_uncertainty=c.render_depth_uncertainty)
        instance_form = c.cross_rendering_form == "instance"
        # the peers' renderings do not change within the round: once per sender
        targets = [peer_render_targets(*self._peer_fields(sender), bundle, self.matches.get(sender, {}),
                                       own_fields if instance_form else None, observed, c.samples_per_box,
                                       surface_eps_m=self.config.mapping.sampler.surface_eps_m)
                   for sender, bundle in zip(senders, rays)]

        def extra() -> torch.Tensor:
            total = torch.zeros((), device=self.mapper.device)
            for name, bank in self.mapper.banks.items():
                if c.algorithm == "consensus":
                    total = total + consensus_penalty(bank.params, anchors[name], pairs[name], c.penalty_rho)
                elif c.algorithm == "dinno":
                    total = total + dinno_penalty(bank.params, anchors[name], self.duals[name], pairs[name], c.penalty_rho)
            terms.parameter = float(total.detach())
            render = torch.zeros((), device=self.mapper.device)
            used = 0
            for target in targets:
                if instance_form:
                    loss = instance_render_consistency_loss(own_fields, own_labels, target, self.config.mapping.sampler,
                                                            weights, self.mapper.generator)
                else:
                    loss = render_consistency_loss(own_fields, target, c.samples_per_box, c.free_space_weight)
                render, used = render + loss, used + len(target)
            terms.render, terms.render_rays = float(render.detach()), used
            return total + c.render_weight * render

        terms.pairs, terms.loss = n_pairs, 0.0
        return ConsistencyWork(c.iterations, extra, terms, time.perf_counter() - start)

    def _fresh_round(self, round_index: int) -> int | None:
        """The round whose vectors DiNNO and DSGD may use (None: any vector held)."""
        c = self.config.consistency
        return round_index if c.algorithm in ("dinno", "dsgd") and c.missing_edges == "skip" else None

    def _weighted(self, pairs: ConsistencyPairs, keys: list[PairKey], listings: dict, acknowledged: frozenset[int]
                  ) -> ConsistencyPairs:
        """DSGD: the pairs whose edge both ends agreed on, with their Metropolis weights."""
        values = metropolis_weights(keys, listings, acknowledged)
        self.mixing_weights.update({key: w for key, w in zip(keys, values) if w > 0})
        weights = torch.as_tensor(values, dtype=torch.float32, device=pairs.rows.device)
        used = weights > 0
        return ConsistencyPairs(pairs.rows[used], pairs.vectors[used], weights[used])

    def _pairs(self, bank_name: str, fresh_round: int | None = None) -> tuple[ConsistencyPairs, list[PairKey]]:
        """(own row, peer vector) of every instance both hold in one frame, one peer vector per own row
        and peer (the peer's instance with the largest box when several match one of mine), and who
        each pair joins; with ``fresh_round`` only the vectors that arrived in that round."""
        rows, vectors, keys = [], [], []
        bank = self.mapper.banks[bank_name]
        chosen: dict[tuple[int, int], InstancePayload] = {}
        for peer, table in self.matches.items():
            for pid, own in table.items():
                slot = self.mapper.slots.get(own)
                payload = self.held.get(peer, {}).get(pid)
                if slot is None or payload is None or not slot.alive or slot.bank != bank_name:
                    continue
                if fresh_round is not None and self.held_at.get(peer, {}).get(pid) != fresh_round:
                    continue
                if not payload_frame(payload).same_as(self.mapper.frame_of(own)):
                    continue
                key = (peer, own)
                size = float(np.prod(payload.bound_hi - payload.bound_lo))
                if key not in chosen or size > float(np.prod(chosen[key].bound_hi - chosen[key].bound_lo)):
                    chosen[key] = payload
        for (peer, own), payload in sorted(chosen.items()):
            rows.append(self.mapper.slots[own].row)
            vectors.append(torch.as_tensor(payload.params.astype(np.float32)))
            keys.append(PairKey(peer, own, payload.instance_id))
        dev = bank.device
        if not rows:
            return ConsistencyPairs(torch.zeros(0, dtype=torch.long, device=dev),
                                    torch.zeros(0, bank.param_dim, device=dev)), keys
        return ConsistencyPairs(torch.as_tensor(rows, device=dev), torch.stack(vectors).to(dev)), keys

    def _own_fields(self) -> tuple[list[LiveRows], list[torch.Tensor]]:
        """My live instances per bank, and the instance id of each of their rows."""
        fields, labels = [], []
        for name, bank in self.mapper.banks.items():
            live = sorted((s.row, iid) for iid, s in self.mapper.slots.items() if s.bank == name and s.alive)
            if live:
                fields.append(LiveRows(bank, [row for row, _ in live]))
                labels.append(torch.as_tensor([iid for _, iid in live], dtype=torch.long, device=bank.device))
        return fields, labels

    def _peer_fields(self, peer: int) -> tuple[list[InstanceFieldBank], list[torch.Tensor]]:
        """The peer's map as I hold it (its last parameters), rebuilt when new ones came in, and the
        peer's instance id of each row."""
        key = self.held_round.get(peer, -1)
        cached = self._shadow.get(peer)
        if cached is not None and cached[0] == key:
            return cached[1], cached[2]
        fields, labels = [], []
        for name, own_bank in self.mapper.banks.items():
            items = [p for p in self.held.get(peer, {}).values() if p.bank == name]
            if not items:
                continue
            bank = InstanceFieldBank(own_bank.config, own_bank.device)
            bank.add_instances(len(items), torch.as_tensor(np.stack([p.bound_lo for p in items])),
                               torch.as_tensor(np.stack([p.bound_hi for p in items])),
                               frame_centre=torch.as_tensor(np.stack([p.frame_centre for p in items])),
                               frame_half=torch.as_tensor([p.frame_half for p in items]),
                               params=torch.as_tensor(np.stack([p.params.astype(np.float32) for p in items])))
            bank.requires_grad_(False)
            fields.append(bank)
            labels.append(torch.as_tensor([p.instance_id for p in items], dtype=torch.long, device=own_bank.device))
        self._shadow[peer] = (key, fields, labels)
        return fields, labels
