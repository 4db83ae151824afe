"""What agents send each other, and its real serialised form (bytes are counted as ``len(to_bytes())``).

Two kinds, as the paper's exchange (sec. III-D), a third for the transmission baseline and a fourth
for DSGD:
- ``ParameterMessage``: per instance, its network vector, box, frame and code-book entry, and, the
  first time that instance goes to that peer (or after its cloud grew), its down-sampled point cloud
  for the Cross-Agent Instance Alignment.
- ``RayMessage``: camera poses of views the sender has mapped (by default drawn from the frames it read
  before this round; ``ConsistencyConfig.ray_poses``) and a sampling seed the receiver
  replays to get the same pixels (never depth: the receiver renders the peer's depth itself with the
  peer's parameters, eq. 13).
- ``PointCloudMessage``: the down-sampled points the sender has observed so far: what point-cloud
  sharing (the paper's Table VI baseline) would send instead of parameters; it trains nothing here,
  it exists so that its bytes are counted the same way as the others'.
- ``DegreeMessage``: DSGD only, after the parameters arrived: the sender's pairs with the receiver
  and its degree per instance, so that both ends of an edge use the same Metropolis weight
  (``mapping.team.consistency``).

The bytes are ``mapping.team.wire``'s format; parameters may travel as float16, or coded
(``mapping.team.codec``: quantised, as deltas to the receiver's copy, sparsified, the whole message compressed).
``from_bytes`` checks every field against what the receiving team can use (``MessageRules``): a message
that fails is refused with ``MessageError`` naming the field, and the channel counts it as dropped.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from mapping.model.observed import ObservedSpace
from mapping.team.message_checks import (InstanceMeta, MessageRules, agent_field, checked_array, checked_ids,
                                         checked_intrinsics, checked_observed, count_field, instance_meta, rigid_poses)
from mapping.team.codec import CodedCloud, CodedVector, coded_arrays, decode_vector, read_cloud, read_coded
from mapping.team.message_size import check_decoded_size
from mapping.team.wire import ENVELOPE, LOSSLESS, ArrayEntry, MessageError, decode_arrays, pack, read_message, seal

__all__ = ["DegreeMessage", "InstancePayload", "Message", "MessageError", "MessageRules", "ParameterMessage",
           "PointCloudMessage", "RayMessage", "from_bytes", "replay_pixels", "to_bytes"]

@dataclass
class InstancePayload:
    """One instance as it travels.

    Attributes:
        instance_id: the sender's id for it.
        bank: ``object`` or ``structure`` (network width).
        params: (D,) float16 or float32 network vector (arrived as a delta: the delta, until the receiver adds
            its copy: ``params_code.base`` says which).
        bound_lo, bound_hi: (3,) float32 box.
        frame_centre: (3,) float32; ``frame_half``, ``frame_origin``, ``frame_version``: its frame.
        caption, caption_feature ((d,) float16/32; None: the receiver holds it unchanged), confidence: its
            code-book entry.
        cloud: (P, 3) float32 down-sampled points, or None (already sent).
        observed: where its keyframes have looked (2 bits a cell on the wire), or None (the sender keeps none).
        params_code, feature_code: how the vector and the feature travel (``mapping.team.codec``), or None
            (whole, as float16 or float32).
        cloud_code: how the cloud travels (integers over its box), or None (float32).
        observed_code: None (``observed`` is the whole space), ``held`` (left out: the receiver holds it unchanged)
            or ``delta`` (``observed`` holds only the cells that changed since the receiver's copy).
    """

    instance_id: int
    bank: str
    params: np.ndarray
    bound_lo: np.ndarray
    bound_hi: np.ndarray
    frame_centre: np.ndarray
    frame_half: float
    frame_origin: int
    frame_version: int
    caption: str
    caption_feature: np.ndarray
    confidence: float
    cloud: np.ndarray | None = None
    observed: ObservedSpace | None = None
    params_code: CodedVector | None = None
    feature_code: CodedVector | None = None
    cloud_code: CodedCloud | None = None
    observed_code: str | None = None


@dataclass
class ParameterMessage:
    """Sender's instances for one receiver in one round; ``degree`` = how many peers the sender sent
    parameters to this round (informational: DSGD's weights come from ``DegreeMessage``)."""

    sender: int
    receiver: int
    round: int
    instances: list[InstancePayload] = field(default_factory=list)
    degree: int = 1
    lossless: str = "none"
    """The codec's lossless stage over the whole message (``wire.seal``)."""
    kind = "params"


@dataclass
class RayMessage:
    """Camera poses of views the sender has mapped ((F, 4, 4) float32, camera-to-world), its intrinsics
    (fx, fy, cx, cy, width, height), and the seed and count of the pixels to replay per pose."""

    sender: int
    receiver: int
    round: int
    poses: np.ndarray
    intrinsics: tuple[float, float, float, float, int, int]
    seed: int
    rays_per_pose: int
    kind = "rays"


@dataclass
class PointCloudMessage:
    """The sender's observed points so far, (P, 3) float32, down-sampled (point-cloud sharing)."""

    sender: int
    receiver: int
    round: int
    points: np.ndarray
    kind = "points"


@dataclass
class DegreeMessage:
    """DSGD's listing for one receiver: per pair of the sender's instance ``own_ids[m]`` with the
    receiver's ``peer_ids[m]``, the sender's degree for that instance ``degrees[m]`` ((n,) int each)."""

    sender: int
    receiver: int
    round: int
    own_ids: np.ndarray
    peer_ids: np.ndarray
    degrees: np.ndarray
    kind = "degrees"


Message = ParameterMessage | RayMessage | PointCloudMessage | DegreeMessage


def replay_pixels(message: RayMessage) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The pixels a ray message stands for: (M,) pose index, (M,) u and (M,) v, M = poses x count.

    Sender and receiver both call this: the seed fixes the pixels, so only the seed travels."""
    width, height = int(message.intrinsics[4]), int(message.intrinsics[5])
    rng = np.random.default_rng(message.seed)
    n = len(message.poses) * message.rays_per_pose
    pose = np.repeat(np.arange(len(message.poses)), message.rays_per_pose)
    return pose, rng.integers(0, width, n), rng.integers(0, height, n)


def to_bytes(message: Message) -> bytes:
    """The message's serialised form (what a radio would carry)."""
    base = {"sender": message.sender, "receiver": message.receiver, "round": message.round}
    if isinstance(message, PointCloudMessage):
        return pack("points", base, {"points": np.asarray(message.points, np.float32)})
    if isinstance(message, DegreeMessage):
        return pack("degrees", base, {name: np.asarray(getattr(message, name), np.int32)
                                       for name in ("own_ids", "peer_ids", "degrees")})
    if isinstance(message, RayMessage):
        return pack("rays", {**base, "intrinsics": list(message.intrinsics), "seed": int(message.seed),
                              "rays_per_pose": int(message.rays_per_pose)},
                     {"poses": np.asarray(message.poses, np.float32)})
    scalars = {**base, "degree": message.degree, "instances": []}
    arrays = {}
    for k, inst in enumerate(message.instances):
        scalars["instances"].append({"id": inst.instance_id, "bank": inst.bank, "half": float(inst.frame_half),
                                     "origin": inst.frame_origin, "version": inst.frame_version,
                                     "caption": inst.caption, "confidence": float(inst.confidence),
                                     "cloud": inst.cloud is not None, "observed": inst.observed is not None})
        meta = scalars["instances"][-1]
        if inst.params_code is not None:
            meta["params_code"], coded = coded_arrays(f"{k}.params", inst.params_code)
            arrays.update(coded)
        else:
            arrays[f"{k}.params"] = inst.params
        arrays[f"{k}.box"] = np.concatenate([inst.bound_lo, inst.bound_hi, inst.frame_centre]).astype(np.float32)
        if inst.caption_feature is None:
            meta["feature_code"] = "held"
        elif inst.feature_code is not None:
            meta["feature_code"], coded = coded_arrays(f"{k}.feature", inst.feature_code)
            arrays.update(coded)
        else:
            arrays[f"{k}.feature"] = inst.caption_feature
        if inst.cloud_code is not None:
            meta["cloud_bits"] = inst.cloud_code.bits
            arrays[f"{k}.cloud.q"], arrays[f"{k}.cloud.scale"] = inst.cloud_code.codes, inst.cloud_code.frame
        elif inst.cloud is not None:
            arrays[f"{k}.cloud"] = np.asarray(inst.cloud, np.float32)
        if inst.observed_code is not None:
            meta["observed_code"] = inst.observed_code
        if inst.observed is not None:
            arrays[f"{k}.observed"] = np.frombuffer(inst.observed.to_bytes(), np.uint8)
    return seal(pack("params", scalars, arrays), message.lossless)


def from_bytes(data: bytes, rules: MessageRules = MessageRules()) -> Message:
    """Inverse of ``to_bytes``; anything else (truncated, corrupt, an array of the wrong shape or dtype,
    non-finite values, a field outside ``rules``, a parameter message over its cap) raises MessageError naming
    the field, and nothing else escapes: nothing malformed is ever applied. Arrays decode to no more than the
    bytes that arrived (``wire``); a parameter message's grids, which inflate, are bounded by its cap first."""
    try:
        data = bytes(data)
        if not rules.coded and data.startswith(ENVELOPE):
            raise MessageError("a compressed message, and this team's codec is off")
        kind, s, table, body = read_message(data)
        base = (agent_field(s, "sender", rules), agent_field(s, "receiver", rules), count_field(s, "round"))
        if kind == "params":
            message = _parameter_message(base, s, table, body, rules)
            message.lossless = LOSSLESS[data[len(ENVELOPE)]] if data.startswith(ENVELOPE) else "none"
            return message
        a = decode_arrays(table, body)
        if kind == "rays":
            poses = rigid_poses(checked_array(a, "poses", (None, 4, 4)))
            intrinsics = checked_intrinsics(s.get("intrinsics"), rules)
            rays_per_pose = count_field(s, "rays_per_pose")
            if len(poses) * rays_per_pose > rules.max_rays:
                raise MessageError(f"field rays_per_pose: {len(poses)} poses x {rays_per_pose} rays exceed the "
                                   f"{rules.max_rays} rays a message may ask for")
            return RayMessage(*base, poses, intrinsics, count_field(s, "seed", 2**64 - 1), rays_per_pose)
        if kind == "points":
            return PointCloudMessage(*base, checked_array(a, "points", (None, 3)))
        if kind == "degrees":
            lists = [checked_ids(a, name) for name in ("own_ids", "peer_ids", "degrees")]
            if len({len(x) for x in lists}) != 1:
                raise MessageError(f"arrays own_ids, peer_ids, degrees: lengths {[len(x) for x in lists]} differ")
            if np.any(lists[2] < 1):
                raise MessageError("array degrees: every degree must be >= 1")
            return DegreeMessage(*base, *lists)
        raise MessageError(f"unknown message kind {kind[:40]!r}")
    except MessageError:
        raise
    except Exception as exc:  # noqa: BLE001  (whatever a crafted message provokes is a refusal, not a crash)
        raise MessageError(f"corrupt message ({type(exc).__name__}: {str(exc)[:120]})") from None


def _parameter_message(base: tuple[int, int, int], scalars: dict, table: dict[str, ArrayEntry], body: memoryview,
                       rules: MessageRules) -> ParameterMessage:
    """A parameter message, its size checked against its cap (``message_size``) before any array is copied out
    or any grid inflated."""
    metas = scalars.get("instances")
    if not isinstance(metas, list):
        raise MessageError("field instances: expected a list")
    checked = [instance_meta(k, meta, rules) for k, meta in enumerate(metas)]
    check_decoded_size(checked, table, body, rules)
    arrays = decode_arrays(table, body)
    instances = [_instance(k, m, arrays, rules) for k, m in enumerate(checked)]
    ids = [inst.instance_id for inst in instances]
    if len(set(ids)) != len(ids):
        raise MessageError("field instances: an instance id appears twice")
    return ParameterMessage(*base, instances, count_field(scalars, "degree"))


def _instance(k: int, m: InstanceMeta, arrays: dict[str, np.ndarray], rules: MessageRules) -> InstancePayload:
    want = None if rules.param_counts is None else rules.param_counts[m.bank]
    params_code = None
    if m.params_code is not None:
        params_code = read_coded(f"{k}.params", m.params_code, arrays, want, rules.max_vector_values)
        params = decode_vector(params_code)  # finite: read_coded checked every value times its scale
    else:
        params = checked_array(arrays, f"{k}.params", (None,))
        if want is not None and len(params) != want:
            raise MessageError(f"array {k}.params: {len(params)} values, a {m.bank} network has {want}")
    box = checked_array(arrays, f"{k}.box", (9,))
    if np.any(box[:3] > box[3:6]):
        raise MessageError(f"array {k}.box: its low corner lies above its high corner")
    feature_code = None
    if m.feature_code == "held":
        feature = None
    elif m.feature_code is not None:
        feature_code = read_coded(f"{k}.feature", m.feature_code, arrays, rules.feature_dim, rules.max_vector_values)
        if feature_code.base is not None:
            raise MessageError(f"field instances[{k}].feature_code: a feature travels whole, not as a delta")
        feature = decode_vector(feature_code)
    else:
        feature = checked_array(arrays, f"{k}.feature", (rules.feature_dim,))
    cloud, cloud_code = None, None
    if m.cloud_bits is not None:
        cloud = read_cloud(f"{k}.cloud", m.cloud_bits, arrays, rules.max_cloud_points)
        cloud_code = CodedCloud(arrays[f"{k}.cloud.q"], arrays[f"{k}.cloud.scale"], m.cloud_bits)
    elif m.cloud:
        cloud = checked_array(arrays, f"{k}.cloud", (None, 3))
    observed = checked_observed(arrays, k, box[:3], box[3:6], rules) if m.observed else None
    return InstancePayload(m.id, m.bank, params, box[:3], box[3:6], box[6:9], m.half, m.origin, m.version,
                           m.caption, feature, m.confidence, cloud, observed, params_code, feature_code, cloud_code,
                           m.observed_code)
