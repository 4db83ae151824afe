"""Where the bytes of a run go: every message a run sends, cut into the parts of its wire form (framing, JSON
header, network vectors, caption features, boxes, clouds, observed grids, ray poses, point clouds), summed over
the run. Measured before the codec was chosen (issue 63) and again with it, so a codec setting is judged by
what it leaves.

    python -m studies.message_bytes --preset fast --scene room0 --seed 0 --policy always \\
        --out runs/study_message_bytes [--set team.exchange.codec.bits=8 ...]

Writes ``OUT/message_bytes.json`` (the totals, per kind and part, and the run's completion) and prints a table.
Figures: docs/codec.md
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import Counter
from pathlib import Path

from mapping.team.wire import MAGIC, read_message, unseal

FRAMING = len(MAGIC) + 1 + 4
"""Magic, version byte and the header's length."""


def wire_parts(data: bytes) -> tuple[str, dict[str, int]]:
    """A serialised message's kind and its bytes by part: ``framing``, ``header`` (JSON), and each array by
    the name after its instance number (``params``, ``params.q``, ``feature``, ``observed``, ``poses``, ...); a
    sealed message (the codec's lossless stage) adds ``lossless``: what sealing added, negative when it saved."""
    raw = unseal(data)
    kind, _, table, body = read_message(raw)
    parts: Counter = Counter({"framing": FRAMING, "header": len(raw) - FRAMING - len(body)})
    for name, entry in table.items():
        part = name.split(".", 1)[1] if name.split(".", 1)[0].isdigit() else name
        parts[part] += entry.size
    if len(raw) != len(data):
        parts["lossless"] = len(data) - len(raw)
    return kind, dict(parts)


def tally_run(argv: list[str]) -> tuple[dict, dict]:
    """Run ``openmulti run ARGV`` in this process with every transmitted message cut into parts; returns the
    (kind -> part -> bytes) totals and the run's metrics."""
    from mapping.team import channel as channel_module  # noqa: PLC0415
    from openmulti_env.runs.cli import main  # noqa: PLC0415

    totals: dict[str, Counter] = {}
    wire_total: Counter = Counter()
    original = channel_module.Channel.transmit_bytes

    def counted(self, sender, receiver, kind, data, accept=None):
        delivery = original(self, sender, receiver, kind, data, accept)
        if delivery.status != channel_module.OVER_BUDGET:
            message_kind, parts = wire_parts(data)
            totals.setdefault(message_kind, Counter()).update(parts)
            wire_total[message_kind] += len(data)
        return delivery

    channel_module.Channel.transmit_bytes = counted
    try:
        code = main(["run", *argv])
    finally:
        channel_module.Channel.transmit_bytes = original
    if code != 0:
        raise SystemExit(code)
    out = Path(argv[argv.index("--out") + 1])
    metrics = json.loads((out / "metrics.json").read_text())
    result = {kind: {**dict(parts), "wire": wire_total[kind]} for kind, parts in totals.items()}
    return result, metrics


def table(result: dict) -> str:
    """A markdown table: per kind and part, MB and share of all bytes."""
    total = sum(parts["wire"] for parts in result.values())
    lines = ["| message | part | MB | share |", "|---|---|---|---|"]
    for kind, parts in sorted(result.items()):
        for part, size in sorted(parts.items(), key=lambda item: -item[1]):
            if part == "wire":
                continue
            lines.append(f"| {kind} | {part} | {size / 1e6:.3f} | {100 * size / max(total, 1):.1f} % |")
        lines.append(f"| {kind} | **on the wire** | {parts['wire'] / 1e6:.3f} | {100 * parts['wire'] / max(total, 1):.1f} % |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--preset", default="fast")
    parser.add_argument("--scene", default="room0")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--policy", default="always")
    parser.add_argument("--out", type=Path, default=Path("runs/study_message_bytes"))
    parser.add_argument("--set", nargs="*", default=[], metavar="PATH=VALUE",
                        help="tree options of the run, e.g. team.exchange.codec.bits=8")
    parser.add_argument("--no-evaluation", action="store_true", help="bytes only: skip the scoring")
    args = parser.parse_args(argv)
    extra = []
    for item in args.set:
        key, _, value = item.partition("=")
        extra += [f"--{key.replace('_', '-')}", value]
    run_argv = ["--preset", args.preset, "--scene", args.scene, "--seed", str(args.seed), "--policy", args.policy,
                "--out", str(args.out), *extra] + (["--no-evaluation"] if args.no_evaluation else [])
    result, metrics = tally_run(run_argv)
    mean = metrics.get("mean", {})
    record = {"argv": run_argv, "bytes": result, "bytes_sent_total": metrics.get("bytes_sent_total"),
              "comp_ratio": mean.get("comp_ratio"), "acc_cm": mean.get("acc_cm")}
    path = args.out / "message_bytes.json"
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(record, indent=1))
    tmp.replace(path)
    print(table(result))
    print(f"completion {record['comp_ratio']} %, {record['bytes_sent_total']} bytes sent")
    return 0


if __name__ == "__main__":
    sys.exit(main())
