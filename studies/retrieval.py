"""Retrieval study: top-1 of everyday queries on every scene preset, per encoder, with and without errors.

For each preset (only the scene description is built, no world) and each text encoder, a code book
holds what a run's fused code book holds: per instance the simulated captioner's phrasings of
``--views`` frames, their features averaged and re-normalised (as cross-frame fusion does), the most
frequent phrasing as caption, and the zero-shot label (``zero_shot_labels`` over the 34 categories).
With the error model (``SegmentationErrorConfig()`` defaults, agent 0, seed 0): an instance with a
semantic error has ``--partial-share`` of its views captioned as its wrong category (the error shows
in views cut by the image border), an over-segmented one is two or three entries with the same
category, an under-segmented pair is one entry captioned as the larger instance (the other is gone).

Every query of ``studies/retrieval_queries.yaml`` whose accepted categories occur in the scene is
ranked with ``RetrievalIndex``; top-1 is correct when the best entry's ground-truth category is
accepted. No image-text checkpoint ships, so the visual term is off. Tune only with ``--split tune``.

Run: `.venv/bin/python -m studies.retrieval [--encoders mpnet minilm] [--split tune]
[--label-share 0.6 --context-weight 0.0] [--out runs/bench_retrieval]`. Prints tables; writes OUT.json.

Figures: docs/front_end.md#retrieval-and-openmulti-query
"""

from __future__ import annotations

import argparse
import resource
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from mapping.evaluate.retrieval import RetrievalIndex, RetrievalWeights
from mapping.evaluate.semantic import zero_shot_labels
from mapping.perception import CodeBook, CodeBookEntry, TextEncoder
from mapping.perception.captioner import TemplateCaptioner
from mapping.perception.errors import SegmentationErrorConfig, plan_errors
from mapping.pipeline.records import write_json_atomic
from openmulti_env.world import REPLICA_LIKE_PRESETS, make_scene
from openmulti_env.world.furniture import CATEGORIES
from openmulti_env.world.scene import STRUCTURE_CATEGORIES
from openmulti_env.world.semantics import instance_infos

QUERIES = Path(__file__).with_name("retrieval_queries.yaml")
KINDS = ("name", "synonym", "function", "relation")
SPLITS = ("tune", "held_out")
VOCABULARY = list(CATEGORIES) + list(STRUCTURE_CATEGORIES)


@dataclass(frozen=True)
class Query:
    """One retrieval query: its text, kind, split and the categories that answer it."""

    text: str
    kind: str
    split: str
    accept: frozenset[str]


def load_queries(path: Path = QUERIES) -> list[Query]:
    """Queries of the YAML file (ValueError naming an unknown kind, split or category)."""
    known = set(VOCABULARY)
    out = []
    for rec in yaml.safe_load(path.read_text())["queries"]:
        q = Query(rec["text"], rec["kind"], rec["split"], frozenset(rec["accept"]))
        if q.kind not in KINDS or q.split not in SPLITS or not q.accept <= known:
            raise ValueError(f"{path}: query {q.text!r}: kind {q.kind!r}, split {q.split!r} or unknown "
                             f"categories {sorted(q.accept - known)}")
        out.append(q)
    return out


def scene_codebook(scene, encoder, errors: bool, views: int = 10, partial_share: float = 0.5,
                   seed: int = 0) -> tuple[CodeBook, dict[int, str]]:
    """A fused-looking code book of ``scene`` (see the module docstring) and entry id -> true category."""
    infos = instance_infos(scene)
    plan = plan_errors(infos, SegmentationErrorConfig() if errors else SegmentationErrorConfig.none(), seed, 0)
    area = {inst.instance_id: float(getattr(inst.mesh, "area", 0.0)) for inst in scene.instances}
    captioner = TemplateCaptioner(seed)
    book, truth, next_id = CodeBook(), {}, 1
    for info in infos:
        partner = plan.under_partner.get(info.instance_id)
        if partner is not None and (area[partner], -partner) > (area[info.instance_id], -info.instance_id):
            continue  # merged into its larger partner's mask
        wrong = plan.wrong_category.get(info.instance_id)
        for piece in range(plan.over_pieces.get(info.instance_id, 1)):
            phrasings = [captioner.caption(info, 0, f, wrong if wrong and f < views * partial_share else None, piece)
                         for f in range(views)]
            mean = encoder.encode(phrasings).mean(axis=0)
            book[next_id] = CodeBookEntry(max(sorted(set(phrasings)), key=phrasings.count),
                                          mean / np.linalg.norm(mean), confidence=1.0)
            truth[next_id] = info.category
            next_id += 1
    book.text_encoder = encoder.name
    labels = zero_shot_labels(book, VOCABULARY, encoder)
    for i, label in labels.items():
        book[i].label = label
    return book, truth


def evaluate(encoder, scenes: list[str], queries: list[Query], weights: RetrievalWeights, views: int,
             partial_share: float) -> tuple[list[dict], dict]:
    """Rows (one per query x scene x error setting) and zero-shot label accuracy per error setting."""
    rows, labelling = [], {False: [0, 0], True: [0, 0]}
    for name in scenes:
        scene = make_scene(name)
        for errors in (False, True):
            book, truth = scene_codebook(scene, encoder, errors, views, partial_share)
            labelling[errors][0] += sum(book[i].label == truth[i] for i in book)
            labelling[errors][1] += len(book)
            index = RetrievalIndex(book, encoder, weights=weights)
            present = set(truth.values())
            for q in queries:
                if q.accept & present:
                    best = index.rank(q.text)[0]
                    rows.append({"scene": name, "errors": errors, "query": q.text, "kind": q.kind, "split": q.split,
                                 "correct": truth[best.instance_id] in q.accept, "top_category": truth[best.instance_id],
                                 "top_caption": best.caption})
    return rows, {("on" if e else "off"): 100.0 * k / n for e, (k, n) in labelling.items()}


def _pct(rows: list[dict]) -> float | None:
    return 100.0 * float(np.mean([r["correct"] for r in rows])) if rows else None


def encoder_figures(name: str) -> dict:
    """Install size, load time, memory and encoding speed of one encoder (both backends)."""
    from importlib import metadata  # noqa: PLC0415

    from mapping.perception.text_encoder import TEXT_ENCODERS  # noqa: PLC0415

    size = sum(f.size or 0 for p in TEXT_ENCODERS[name].packages for f in metadata.distribution(p).files or [])
    out = {"install_mb": size / 1e6}
    captions = [f"a {c} {n} number {k}" for k in range(8) for c in ("red", "light oak", "black metal")
                for n in ("chair", "double bed", "floor lamp", "coffee table", "bookcase", "potted plant")]
    for backend in ("torch", "numpy"):
        rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        enc = TextEncoder(name, backend=backend)
        t = time.perf_counter()
        enc.folder()
        out["unpack_or_locate_s"] = time.perf_counter() - t
        t = time.perf_counter()
        enc._load()
        out[f"{backend}_load_s"] = time.perf_counter() - t
        t = time.perf_counter()
        enc.encode(captions)
        out[f"{backend}_ms_per_caption"] = 1000 * (time.perf_counter() - t) / len(captions)
        t = time.perf_counter()
        enc.encode(["somewhere to sleep"])
        out[f"{backend}_ms_one_query"] = 1000 * (time.perf_counter() - t)
        out[f"{backend}_peak_rss_gain_mb"] = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - rss0) / 1024
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", nargs="*", default=list(REPLICA_LIKE_PRESETS))
    parser.add_argument("--encoders", nargs="*", default=["mpnet", "minilm"])
    parser.add_argument("--split", choices=("tune", "held_out", "both"), default="both")
    parser.add_argument("--label-share", type=float, default=RetrievalWeights.label_share)
    parser.add_argument("--context-weight", type=float, default=RetrievalWeights.context_weight)
    parser.add_argument("--views", type=int, default=10)
    parser.add_argument("--partial-share", type=float, default=0.5)
    parser.add_argument("--figures", action="store_true", help="also time and size the encoders")
    parser.add_argument("--misses", action="store_true", help="print the misses of the tuning half")
    parser.add_argument("--out", default="runs/bench_retrieval")
    args = parser.parse_args()

    queries = [q for q in load_queries() if args.split == "both" or q.split == args.split]
    weights = RetrievalWeights(label_share=args.label_share, context_weight=args.context_weight)
    result = {"scenes": args.scenes, "weights": vars(weights), "views": args.views,
              "partial_share": args.partial_share, "encoders": {}}
    for name in args.encoders:
        encoder = TextEncoder(name)
        rows, labelling = evaluate(encoder, args.scenes, queries, weights, args.views, args.partial_share)
        entry = {"labelling_pct": labelling, "rows": rows}
        if args.figures:
            entry["figures"] = encoder_figures(name)
        result["encoders"][name] = entry
        _print(name, rows, labelling, args.scenes, entry.get("figures"), args.misses)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    write_json_atomic(out.with_suffix(".json"), result)
    print(f"\nWrote {out.with_suffix('.json')}")


def _print(name: str, rows: list[dict], labelling: dict, scenes: list[str], figures: dict | None, misses: bool) -> None:
    cell = lambda v: "-" if v is None else f"{v:.0f}"  # noqa: E731
    print(f"\n## {name}: top-1 [%] by split and kind (all presets, errors off + on; pairs in brackets)")
    print("| split | " + " | ".join(KINDS) + " | all |\n|---|" + "---:|" * (len(KINDS) + 1))
    for split in SPLITS:
        sel = [r for r in rows if r["split"] == split]
        if sel:
            print(f"| {split} | " + " | ".join(f"{cell(_pct([r for r in sel if r['kind'] == k]))} "
                                             f"({sum(r['kind'] == k for r in sel)})" for k in KINDS)
                  + f" | {cell(_pct(sel))} |")
    for split in SPLITS:
        sel = [r for r in rows if r["split"] == split]
        if not sel:
            continue
        print(f"\n{name}, {split}: top-1 [%] per preset, errors off / on")
        print("| kind | " + " | ".join(scenes) + " | min |\n|---|" + "---:|" * (len(scenes) + 1))
        for kind in KINDS:
            cells, lows = [], []
            for s in scenes:
                pair = [_pct([r for r in sel if r["kind"] == kind and r["scene"] == s and r["errors"] == e])
                        for e in (False, True)]
                cells.append(" / ".join(cell(v) for v in pair))
                lows += [v for v in pair if v is not None]
            print(f"| {kind} | " + " | ".join(cells) + f" | {cell(min(lows) if lows else None)} |")
    print(f"\nzero-shot labels right [% of code-book entries]: errors off {labelling['off']:.1f}, on {labelling['on']:.1f}")
    if figures:
        print("encoder figures: " + ", ".join(f"{k} {v:.2f}" for k, v in figures.items()))
    if misses:
        print("\nmisses (tuning half, errors off):")
        for r in rows:
            if r["split"] == "tune" and not r["errors"] and not r["correct"]:
                print(f"  [{r['kind']:<8}] {r['scene']:<8} {r['query']!r:<44} -> {r['top_category']:<13} {r['top_caption']!r}")


if __name__ == "__main__":
    main()
