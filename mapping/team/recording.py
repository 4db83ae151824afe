"""A recording of one team episode: what no communication decision changes, captured once by the real mapper.

A recorded episode (``mapping.team.recorded``) replays it and models what the actions change. The recording is
one real episode in which nobody sends (``never``): each agent's frames, poses and keyframes, its own instances
and their observed spaces are then its own work alone. Per round and own instance it keeps what a peer's copy
of that instance would bring: the ground-truth probes the instance alone reproduces (``instance_probe_coverage``),
the columns it alone fills (``instance_columns``), its box, confidence and network size, the bytes its payload
takes in a parameter message (with and without its cloud), and how far its network moved between any two rounds
(what ``change`` since a copy reads). Per pair of agents it keeps what the receiver's alignment (sec. III-C)
would decide if the sender's instance first arrived that round: match (to which own instance) or adopt.

Stored as one ``.npz`` read with ``allow_pickle=False``; ``meta`` (JSON) names the settings it was made with.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, replace

import numpy as np

from mapping.evaluate.probe import instance_probe_coverage
from mapping.model.topdown import ColumnGrid, column_map, instance_columns
from mapping.pointcloud import voxel_downsample
from mapping.team.arrival import InstanceView, align_arrivals
from mapping.team.messages import ParameterMessage, to_bytes
from mapping.team.plan import RoundPlan

RECORDING_FORMAT = 1
ADOPT = -1
"""``AgentRecording.matches`` entry: the receiver would adopt the sender's instance whole."""
UNALIGNED = -2
"""``AgentRecording.matches`` entry: the sender's instance had no cloud then; the receiver holds it, unaligned."""


class RecordingError(ValueError):
    """A recording that cannot be used: truncated, of another format, version, setting or world."""


@dataclass
class AgentRecording:
    """One agent's side of a recorded episode: T rounds, M own instances (``ids``) ever in its map."""

    ids: np.ndarray
    """(M,) its own instance ids."""
    is_object: np.ndarray
    """(M,) object bank (else a wall, floor or ceiling)."""
    frames_total: int
    frames_read: np.ndarray
    """(T,) frames read after each round."""
    positions: np.ndarray
    """(T, 3) camera position after each round (NaN before its first frame)."""
    frame_poses: np.ndarray
    """(F, 4, 4) the poses of the frames read, in order; ``frame_offsets`` (T + 1,) splits them by round."""
    frame_offsets: np.ndarray
    observed_points: np.ndarray
    """(K, 3) points its depth hit in each round, thinned to one per map cell; ``observed_offsets`` (T + 1,)."""
    observed_offsets: np.ndarray
    live: np.ndarray
    """(T, M) in its map after the round."""
    shareable: np.ndarray
    """(T, M) with pixels of its own keyframes after the round: what a parameter message carries (a live instance
    whose keyframes were all evicted still counts in its map, and is not sent)."""
    lo: np.ndarray
    """(T, M, 3) box."""
    hi: np.ndarray
    confidence: np.ndarray
    """(T, M)."""
    nparams: np.ndarray
    """(T, M) network values."""
    cloud_points: np.ndarray
    """(T, M) fused points (a cloud is sent again once they doubled, ``resend_cloud_growth``)."""
    payload_first: np.ndarray
    """(T, M) bytes the instance adds to a parameter message with its cloud."""
    payload_repeat: np.ndarray
    """(T, M) without its cloud (and as a delta to the copy with the codec's deltas)."""
    header_bytes: np.ndarray
    """(T,) bytes of a parameter message with no instance."""
    ray_bytes: np.ndarray
    """(T,) bytes of its ray message (0: it had read nothing)."""
    change: np.ndarray
    """(M, T, T) relative L2 change of the network from round c (row) to round t (column); NaN where not live."""
    coverage: np.ndarray
    """(T, M, ceil(P / 8)) packed bits: the probes the instance alone reproduces after the round."""
    probes: int
    top: np.ndarray
    """(T, H, W) its whole map's ``ColumnMap.top`` after the round; ``decided`` the same."""
    decided: np.ndarray
    column_index: np.ndarray
    """Concatenated per-instance columns (``InstanceColumns``), (T * M + 1,) offsets in ``column_offsets``."""
    column_top: np.ndarray
    column_decided: np.ndarray
    column_offsets: np.ndarray
    matches: dict[int, np.ndarray] = field(default_factory=dict)
    """Sender j -> (T + 1, K): row 0 the ids of j's instances, row t + 1 the own id this agent would match each to
    if it first arrived in round t (``ADOPT``: adopt it whole, also when the match is an instance its mapper does
    not hold yet, whose network it then takes from the copy; ``UNALIGNED``: not aligned on arrival, no cloud)."""

    @property
    def rounds(self) -> int:
        return len(self.frames_read)

    def covered(self, t: int, m: int) -> np.ndarray:
        """(P,) bool probes instance m alone reproduces after round t."""
        return np.unpackbits(self.coverage[t, m], count=self.probes).astype(bool)

    def columns(self, t: int, m: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Instance m's (columns, top, decided) after round t."""
        k = t * len(self.ids) + m
        a, b = self.column_offsets[k], self.column_offsets[k + 1]
        return self.column_index[a:b], self.column_top[a:b].astype(np.float64), self.column_decided[a:b].astype(np.float64)

    def arrays(self, prefix: str) -> dict[str, np.ndarray]:
        out = {f"{prefix}{k}": np.asarray(v) for k, v in self.__dict__.items() if k != "matches"}
        out.update({f"{prefix}match_{j}": v for j, v in self.matches.items()})
        return out

    @staticmethod
    def from_arrays(data, prefix: str) -> "AgentRecording":
        names = [k for k in AgentRecording.__dataclass_fields__ if k != "matches"]
        values = {k: data[f"{prefix}{k}"] for k in names}
        for k in ("frames_total", "probes"):
            values[k] = int(values[k])
        matches = {int(k[len(prefix) + 6:]): data[k] for k in data.files if k.startswith(f"{prefix}match_")}
        return AgentRecording(**values, matches=matches)


@dataclass
class Recording:
    """A recorded episode: ``meta`` (what it was made with) and one ``AgentRecording`` per agent."""

    meta: dict
    agents: list[AgentRecording]

    @property
    def rounds(self) -> int:
        return max(a.rounds for a in self.agents)

    def save(self, path) -> None:
        """Written whole: a temporary file renamed into place."""
        import os  # noqa: PLC0415
        import threading  # noqa: PLC0415
        from pathlib import Path  # noqa: PLC0415

        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".{path.stem}.{os.getpid()}.{threading.get_ident()}.tmp.npz")
        arrays = {"meta": np.asarray(json.dumps(self.meta, sort_keys=True, default=str))}
        for i, agent in enumerate(self.agents):
            arrays.update(agent.arrays(f"a{i}_"))
        np.savez_compressed(tmp, **arrays)
        os.replace(tmp, path)

    @staticmethod
    def load(path, expected: dict | None = None) -> "Recording":
        """The recording at ``path``; ``RecordingError`` naming what is wrong when it is truncated, of another
        format, or its ``meta`` differs from ``expected`` (each differing entry named)."""
        try:
            with np.load(path, allow_pickle=False) as data:
                meta = json.loads(str(data["meta"]))
                if not isinstance(meta, dict):
                    raise ValueError(f"meta is a {type(meta).__name__}, not a mapping")
                if meta.get("format") != RECORDING_FORMAT:
                    raise RecordingError(f"{path}: recording format {meta.get('format')!r}, expected {RECORDING_FORMAT}")
                if expected is not None:  # before the arrays: a file of other code is named as such
                    expected = json.loads(json.dumps(expected, sort_keys=True, default=str))  # tuples as lists
                    differ = sorted(k for k in expected if meta.get(k) != expected[k])
                    if differ:
                        said = "; ".join(f"{k}: {_short(meta.get(k))} recorded, {_short(expected.get(k))} asked"
                                         for k in differ)
                        raise RecordingError(f"{path}: made with other settings ({said})")
                agents = [AgentRecording.from_arrays(data, f"a{i}_") for i in range(int(meta["agents"]))]
        except RecordingError:
            raise
        except Exception as exc:  # noqa: BLE001  (a torn or foreign file: zip, zlib, npy, JSON, key or type errors)
            raise RecordingError(f"{path}: not a whole recording ({type(exc).__name__}: {exc})") from None
        rounds = {a.rounds for a in agents}
        if len(rounds) != 1 or 0 in rounds:
            raise RecordingError(f"{path}: not a whole recording (agents recorded {sorted(rounds)} rounds)")
        return Recording(meta, agents)


def _short(value) -> str:
    text = json.dumps(value, sort_keys=True, default=str)
    return text if len(text) <= 60 else text[:57] + "..."


class EpisodeRecorder:
    """Plays a real team with ``never`` to its end, capturing each round (see the module docstring).

    ``points``/``normals`` are the episode's ground-truth probes, ``grid`` the observation's column grid,
    ``cell_of`` maps (K, 3) points to flat map cells (the ``observed`` channel's raster), ``depth_stride`` the
    pixels between the depth points that channel marks."""

    def __init__(self, team, points: np.ndarray, normals: np.ndarray, grid: ColumnGrid, cell_centres, depth_stride: int):
        self.team, self.points, self.normals, self.grid = team, points, normals, grid
        self.cell_centres, self.depth_stride = cell_centres, depth_stride

    def record(self, meta: dict, progress=None) -> Recording:
        team, n = self.team, self.team.num_agents
        rows: list[list[dict]] = [[] for _ in range(n)]
        params: list[dict[int, list]] = [{} for _ in range(n)]
        matches: list[dict[int, list[dict[int, int]]]] = [{j: [] for j in range(n) if j != i} for i in range(n)]
        if team.done:
            raise RecordingError("the team has no frame to read: nothing to record")
        while not team.done:
            report = team.round(RoundPlan.never(n))
            t = report.round
            members = team.local_members()
            views = [self._views(m) for m in members]
            for i, member in enumerate(members):
                rows[i].append(self._capture(member, report.agents[i], t, params[i]))
                slots = member.mapper.slots
                for j in matches[i]:
                    decided = align_arrivals(views[i][0], views[j][1], team.config.arrival)
                    matches[i][j].append({d.peer_id: (ADOPT if d.kind == "adopt" or d.own_id not in slots
                                                      else int(d.own_id)) for d in decided})
            if progress is not None:
                progress(t)
        return Recording({**meta, "format": RECORDING_FORMAT, "agents": n},
                         [self._agent(rows[i], params[i], matches[i], members[i]) for i in range(n)])

    def _views(self, member) -> tuple[dict, dict]:
        """(what its alignment compares arrivals with, what its instances look like on arrival)."""
        own = {iid: InstanceView(inst.points, inst.caption_feature, inst.confidence)
               for iid, inst in member.fusion.instances.items()}
        voxel = member.config.exchange.cloud_voxel_m
        sent = {iid: InstanceView(voxel_downsample(member.fusion.instances[iid].points, voxel),
                                  member.entry(iid).caption_feature.astype(np.float32), member.entry(iid).confidence)
                for iid in member.shareable_ids()
                if iid in member.fusion.instances and len(member.fusion.instances[iid].points)}
        return own, sent

    def _capture(self, member, snapshot, t: int, params: dict[int, list]) -> dict:
        ids, shareable = member.mapper.live_ids(), set(member.shareable_ids())
        peer = (member.index + 1) % self.team.num_agents
        message = member.parameter_message(peer, t, self.team.num_agents - 1)
        member.acknowledge(peer, "params", False, t)  # nothing was sent: nothing booked
        empty = ParameterMessage(member.index, peer, t, [], self.team.num_agents - 1, member.config.exchange.codec.lossless)
        header = len(to_bytes(empty))
        first, repeat = {}, {}
        for payload in (message.instances if message is not None else []):
            alone = len(to_bytes(replace(empty, instances=[payload]))) - header
            bare = len(to_bytes(replace(empty, instances=[replace(payload, cloud=None, cloud_code=None)]))) - header
            size = int(np.asarray(member.mapper.export_instance(payload.instance_id).params).size)
            saved = member.vector_wire_bytes(size, False) - member.vector_wire_bytes(size, True)
            first[payload.instance_id], repeat[payload.instance_id] = alone, max(bare - saved, 0)
        rays = member.ray_message(peer, t, 0)  # its size with a one-digit seed (the replay adds the real seed's digits)
        exported = {iid: member.mapper.export_instance(iid) for iid in ids}
        for iid, inst in exported.items():
            params.setdefault(iid, []).append((t, np.asarray(inst.params, np.float32)))
        observed = [f.backproject(stride=self.depth_stride) for f in snapshot.new_frames]
        hit = self.cell_centres(np.concatenate(observed) if observed else np.zeros((0, 3)))
        whole = column_map(member.mapper, self.grid)
        fused = member.fusion.instances
        return {"ids": ids, "shareable": shareable, "exported": exported, "first": first, "repeat": repeat, "header": header,
                "rays": 0 if rays is None else len(to_bytes(rays)), "frames_read": snapshot.frames_read,
                "position": snapshot.position, "poses": [f.pose for f in snapshot.new_frames], "observed": hit,
                "confidence": {iid: member.confidence_of(iid) for iid in ids},
                "points": {iid: len(fused[iid].points) if iid in fused else 0 for iid in ids},
                "coverage": instance_probe_coverage(member.mapper, self.points, self.normals),
                "columns": instance_columns(member.mapper, self.grid), "top": whole.top, "decided": whole.decided,
                "objects": {iid: inst.bank == "object" for iid, inst in exported.items()}}

    def _agent(self, rows: list[dict], params: dict[int, list], matches: dict[int, list[dict[int, int]]],
               member) -> AgentRecording:
        ids = sorted({iid for row in rows for iid in row["ids"]})
        index = {iid: m for m, iid in enumerate(ids)}
        T, M, P = len(rows), len(ids), len(self.points)
        live, shareable = np.zeros((T, M), bool), np.zeros((T, M), bool)
        lo, hi = np.zeros((T, M, 3), np.float32), np.zeros((T, M, 3), np.float32)
        conf, nparams, points = np.zeros((T, M), np.float32), np.zeros((T, M), np.int32), np.zeros((T, M), np.int32)
        first, repeat = np.zeros((T, M), np.int32), np.zeros((T, M), np.int32)
        coverage = np.zeros((T, M, (P + 7) // 8), np.uint8)
        is_object = np.zeros(M, bool)
        col_index, col_top, col_decided, offsets = [], [], [], [0]
        for t, row in enumerate(rows):
            for iid in row["ids"]:
                m, inst = index[iid], row["exported"][iid]
                live[t, m], shareable[t, m] = True, iid in row["shareable"]
                lo[t, m], hi[t, m] = inst.bound_lo, inst.bound_hi
                conf[t, m], nparams[t, m], points[t, m] = row["confidence"][iid], np.asarray(inst.params).size, row["points"][iid]
                first[t, m], repeat[t, m] = row["first"].get(iid, 0), row["repeat"].get(iid, 0)
                is_object[m] = row["objects"][iid]
                if iid in row["coverage"]:
                    coverage[t, m] = np.packbits(row["coverage"][iid])
            for iid in ids:
                cols = row["columns"].get(iid) if live[t, index[iid]] else None
                if cols is not None:
                    col_index.append(cols.columns)
                    col_top.append(cols.top.astype(np.float32))
                    col_decided.append(cols.decided.astype(np.float32))
                    offsets.append(offsets[-1] + len(cols.columns))
                else:
                    offsets.append(offsets[-1])
        change = np.full((M, T, T), np.nan, np.float32)
        for iid, series in params.items():
            m = index[iid]
            for c, pc in series:
                norm = max(float(np.linalg.norm(pc)), 1e-12)
                for t, pt in series:
                    if pt.shape == pc.shape:
                        change[m, c, t] = float(np.linalg.norm(pt - pc)) / norm
        frame_offsets = np.cumsum([0] + [len(r["poses"]) for r in rows])
        observed_offsets = np.cumsum([0] + [len(r["observed"]) for r in rows])
        match_arrays = {}
        for j, per_round in matches.items():
            sender_ids = sorted({pid for d in per_round for pid in d})
            table = np.full((T, max(len(sender_ids), 0)), -2, np.int64)
            for t, d in enumerate(per_round):
                for k, pid in enumerate(sender_ids):
                    table[t, k] = d.get(pid, -2)
            match_arrays[j] = np.concatenate([np.asarray(sender_ids, np.int64)[None], table]) if sender_ids \
                else np.zeros((T + 1, 0), np.int64)
        nan3 = np.full(3, np.nan)
        return AgentRecording(
            ids=np.asarray(ids, np.int64), is_object=is_object, frames_total=len(member.stream),
            frames_read=np.asarray([r["frames_read"] for r in rows], np.int32),
            positions=np.stack([nan3 if r["position"] is None else np.asarray(r["position"], float) for r in rows]),
            frame_poses=np.asarray([p for r in rows for p in r["poses"]], np.float64).reshape(-1, 4, 4),
            frame_offsets=frame_offsets.astype(np.int64),
            observed_points=np.concatenate([r["observed"] for r in rows]).astype(np.float32).reshape(-1, 3),
            observed_offsets=observed_offsets.astype(np.int64), live=live, shareable=shareable, lo=lo, hi=hi, confidence=conf,
            nparams=nparams, cloud_points=points, payload_first=first, payload_repeat=repeat,
            header_bytes=np.asarray([r["header"] for r in rows], np.int32),
            ray_bytes=np.asarray([r["rays"] for r in rows], np.int32),
            change=change, coverage=coverage, probes=P,
            top=np.stack([r["top"] for r in rows]).astype(np.float32),
            decided=np.stack([r["decided"] for r in rows]).astype(np.float32),
            column_index=np.concatenate(col_index).astype(np.int32) if col_index else np.zeros(0, np.int32),
            column_top=np.concatenate(col_top) if col_top else np.zeros(0, np.float32),
            column_decided=np.concatenate(col_decided) if col_decided else np.zeros(0, np.float32),
            column_offsets=np.asarray(offsets, np.int64), matches=match_arrays)


__all__ = ["ADOPT", "AgentRecording", "EpisodeRecorder", "RECORDING_FORMAT", "Recording", "RecordingError"]
