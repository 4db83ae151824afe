"""Codec benchmark: what coding a round's parameter messages costs against the round itself (issue 63's
target: encode + decode at most 5 % of a round's fleet time at `fast`), and the bytes each setting writes.

A `fast` round of `always` with 4 agents is 12 messages, each with the sender's instances (about 30 object
and 8 structure networks of 11,300 and 30,788 values, a 512-value caption feature); the vectors are drawn at
random with the spread of a trained network, the deltas as a round's change (1 % of each value). Each setting
codes every message (``Outbox.coded_vectors``' arithmetic), serialises it (``to_bytes``), decodes it
(``from_bytes``) and resolves its deltas (``resolved_payload``), timed side by side with float32 in one run.

Run: `.venv/bin/python benchmarks/bench_codec.py [--round-s 2.85] [--repeats 3] [--out runs/bench_codec]`;
`--round-s` is a round's fleet time at `fast` (the run's metrics.json: fleet_s / rounds). Prints a Markdown table
and writes OUT/bench_codec.json.

Figures: docs/codec.md#what-coding-costs
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from mapping.pipeline.records import write_json_atomic
from mapping.team.codec import encode_vector
from mapping.team.inbox import resolved_payload
from mapping.team.messages import InstancePayload, ParameterMessage, from_bytes, to_bytes

SETTINGS = {  # name -> (bits, delta, keep, lossless)
    "float32 (today)": (32, False, 1.0, "none"),
    "8 bits": (8, False, 1.0, "none"),
    "8 bits, deltas, 10 %, zstd": (8, True, 0.1, "zstd"),
    "4 bits, deltas, 5 %, zstd": (4, True, 0.05, "zstd"),
}
OBJECTS, STRUCTURES, FEATURE = 30, 8, 512
SIZES = {"object": 11_300, "structure": 30_788}


def instances(rng: np.random.Generator) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """(bank, vector, the copy a peer holds) of one agent's instances."""
    out = []
    for bank, count in (("object", OBJECTS), ("structure", STRUCTURES)):
        for _ in range(count):
            copy = (rng.normal(size=SIZES[bank]) * 0.05).astype(np.float32)
            out.append((bank, (copy + rng.normal(size=copy.size).astype(np.float32) * 5e-4).astype(np.float32), copy))
    return out


def code_round(items, feature: np.ndarray, bits: int, delta: bool, keep: float, lossless: str) -> tuple[int, float]:
    """Bytes and seconds of one message: coding, serialising, decoding, resolving."""
    start = time.perf_counter()
    payloads = []
    for k, (bank, vector, copy) in enumerate(items):
        base = copy if delta else None
        code, _ = encode_vector(vector, bits, 64, base, 0 if delta else None, keep if delta else 1.0)
        feature_code, _ = encode_vector(feature, bits if bits < 32 else 32, 64)
        payloads.append(InstancePayload(k, bank, vector, np.zeros(3, np.float32), np.ones(3, np.float32),
                                        np.full(3, 0.5, np.float32), 0.75, 0, 1, "a chair", None if delta else feature,
                                        0.5, None, None, code if bits < 32 or delta else None,
                                        None if delta or bits == 32 else feature_code))
    data = to_bytes(ParameterMessage(0, 1, 1, payloads, 3, lossless))
    back = from_bytes(data)
    held = {k: InstancePayload(k, bank, copy, np.zeros(3, np.float32), np.ones(3, np.float32),
                               np.full(3, 0.5, np.float32), 0.75, 0, 1, "a chair", feature, 0.5)
            for k, (bank, _, copy) in enumerate(items)}
    for inst in back.instances:
        resolved_payload(inst, held[inst.instance_id])
    return len(data), time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--round-s", type=float, default=None, help="a round's fleet time at fast (seconds)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", type=Path, default=Path("runs/bench_codec"))
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    items, feature = instances(rng), rng.normal(size=FEATURE).astype(np.float32)
    rows = []
    for name, setting in SETTINGS.items():
        times, size = [], 0
        for _ in range(args.repeats):
            size, seconds = code_round(items, feature, *setting)
            times.append(seconds)
        rows.append({"setting": name, "bytes": size, "message_s": min(times), "round_s": 12 * min(times)})
    base = rows[0]["bytes"]
    print("| setting | bytes a message | of float32's | a round's 12 messages [s] | of the round |")
    print("|---|---|---|---|---|")
    for row in rows:
        share = "" if args.round_s is None else f"{100 * row['round_s'] / args.round_s:.1f} %"
        print(f"| {row['setting']} | {row['bytes']:,} | {100 * row['bytes'] / base:.1f} % | {row['round_s']:.3f} | {share} |")
    args.out.mkdir(parents=True, exist_ok=True)
    write_json_atomic(args.out / "bench_codec.json", {"round_s": args.round_s, "rows": rows})


if __name__ == "__main__":
    main()
