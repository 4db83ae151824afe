"""A team member's state as tensors, numbers, strings, lists and dicts (a weights-only checkpoint)."""

from __future__ import annotations

import numpy as np
import torch

from mapping.model.observed import ObservedSpace
from mapping.team.member import TeamMember
from mapping.team.messages import InstancePayload


def _space_state(space: ObservedSpace | None):
    """An observed space as a uint8 tensor of its wire bytes (None stays None)."""
    return None if space is None else torch.frombuffer(bytearray(space.to_bytes()), dtype=torch.uint8)


def _space(state) -> ObservedSpace | None:
    return None if state is None else ObservedSpace.from_bytes(state.numpy().tobytes())


def _payload_state(p: InstancePayload) -> dict:
    return {"id": p.instance_id, "bank": p.bank, "params": torch.as_tensor(p.params), "lo": torch.as_tensor(p.bound_lo),
            "hi": torch.as_tensor(p.bound_hi), "centre": torch.as_tensor(p.frame_centre), "half": float(p.frame_half),
            "origin": p.frame_origin, "version": p.frame_version, "caption": p.caption,
            "feature": torch.as_tensor(p.caption_feature), "confidence": float(p.confidence),
            "cloud": None if p.cloud is None else torch.as_tensor(p.cloud), "observed": _space_state(p.observed)}


def _payload(s: dict) -> InstancePayload:
    return InstancePayload(s["id"], s["bank"], s["params"].numpy(), s["lo"].numpy(), s["hi"].numpy(),
                           s["centre"].numpy(), s["half"], s["origin"], s["version"], s["caption"],
                           s["feature"].numpy(), s["confidence"], None if s["cloud"] is None else s["cloud"].numpy(),
                           _space(s.get("observed")))


def member_state(m: TeamMember) -> dict:
    """Everything a member holds, for ``Team.save``."""
    return {
        "mapper": m.mapper.state(), "keyframes": m.mapper.keyframes.state(), "fusion": m.fusion.state(),
        "next_frame": m.next_frame, "max_frame_read": m.max_frame_read, "labels": {int(k): v for k, v in m.labels.items()},
        "meaning": {int(k): [c, torch.as_tensor(f), float(conf)] for k, (c, f, conf) in m.meaning.items()},
        "held": {int(p): {int(i): _payload_state(x) for i, x in t.items()} for p, t in m.held.items()},
        "held_round": {int(k): int(v) for k, v in m.held_round.items()},
        "held_at": {int(p): {int(i): int(r) for i, r in t.items()} for p, t in m.held_at.items()},
        "matches": {int(p): {int(i): int(o) for i, o in t.items()} for p, t in m.matches.items()},
        "sent_vectors": {int(p): {int(i): torch.as_tensor(v) for i, v in t.items()} for p, t in m.sent_vectors.items()},
        "sent_cloud_points": {int(p): {int(i): int(v) for i, v in t.items()} for p, t in m.sent_cloud_points.items()},
        "sent_rounds": {int(p): {int(i): int(r) for i, r in t.items()} for p, t in m.sent_rounds.items()},
        "sent_features": {int(p): {int(i): torch.as_tensor(v) for i, v in t.items()} for p, t in m.sent_features.items()},
        "sent_observed": {int(p): {int(i): _space_state(v) for i, v in t.items()} for p, t in m.sent_observed.items()},
        "born_round": {int(i): int(r) for i, r in m.born_round.items()}, "round_seen": int(m.round_seen),
        "duals": {k: v.cpu() for k, v in m.duals.items()},
        "peer_positions": {int(k): [int(r), torch.as_tensor(x)] for k, (r, x) in m.peer_positions.items()},
        "delivered_round": {kind: {int(p): int(r) for p, r in t.items()} for kind, t in m.delivered_round.items()},
    }


def restore_member(m: TeamMember, s: dict) -> None:
    """Inverse of ``member_state``."""
    m.mapper.restore(s["mapper"])
    m.mapper.keyframes.restore(s["keyframes"])
    m.fusion.restore(s["fusion"])
    m.next_frame, m.max_frame_read = s["next_frame"], s["max_frame_read"]
    m.labels.clear()  # in place: the mapper's structure test holds this dict
    m.labels.update({int(k): v for k, v in s["labels"].items()})
    m.meaning = {int(k): (c, f.numpy(), conf) for k, (c, f, conf) in s["meaning"].items()}
    m.held = {int(p): {int(i): _payload(x) for i, x in t.items()} for p, t in s["held"].items()}
    m.held_round = dict(s["held_round"])
    m.held_at = {int(p): {int(i): int(r) for i, r in t.items()} for p, t in s["held_at"].items()} if "held_at" in s \
        else {p: {i: m.held_round[p] for i in t} for p, t in m.held.items()}  # older checkpoints: per message
    m.matches = {int(p): dict(t) for p, t in s["matches"].items()}
    m.sent_vectors = {int(p): {int(i): np.asarray(v.numpy()) for i, v in t.items()} for p, t in s["sent_vectors"].items()}
    m.sent_cloud_points = {int(p): dict(t) for p, t in s["sent_cloud_points"].items()}
    m.sent_rounds = {int(p): {int(i): int(r) for i, r in t.items()} for p, t in s.get("sent_rounds", {}).items()}
    m.sent_features = {int(p): {int(i): np.asarray(v.numpy()) for i, v in t.items()}
                       for p, t in s.get("sent_features", {}).items()}
    m.sent_observed = {int(p): {int(i): _space(v) for i, v in t.items()} for p, t in s.get("sent_observed", {}).items()}
    m.born_round = {int(i): int(r) for i, r in s.get("born_round", {}).items()}
    m.round_seen = int(s.get("round_seen", 0))
    m.duals = {k: v.to(m.mapper.device) for k, v in s["duals"].items()}
    m.peer_positions = {int(k): (int(r), x.numpy()) for k, (r, x) in s.get("peer_positions", {}).items()}
    m.delivered_round.update({kind: {int(p): int(r) for p, r in t.items()}
                              for kind, t in s.get("delivered_round", {}).items()})
    m._shadow = {}
