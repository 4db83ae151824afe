"""Retrieval benchmark: top-1 accuracy of open-vocabulary queries on the scene presets, and zero-shot labelling.

For each preset (room0-2, office0-4; only the scene description is built, no world), a code book holds
every instance with its caption encoded by SBERT (``Instance.caption``, the scene's metadata caption).
Every query of ``benchmarks/retrieval_queries.yaml`` whose accepted categories occur in the scene is
scored with ``score_instances``; top-1 is correct when the best instance's ground-truth category is
accepted. No image-text encoder: the caption term only. The labelling part measures how often
``zero_shot_labels`` gives an instance its ground-truth category, for a few category-name prompts.

Run: `.venv/bin/python benchmarks/bench_retrieval.py [--scenes room0 ...] [--out runs/bench_retrieval]`.
Prints tables; writes ``OUT.json`` and ``OUT.png`` (top-1 per query kind and scene).
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import yaml  # noqa: E402

from mapping.evaluate.retrieval import score_instances  # noqa: E402
from mapping.evaluate.semantic import zero_shot_labels  # noqa: E402
from mapping.perception import CodeBook, CodeBookEntry, shared_text_encoder  # noqa: E402
from mapping.perception.captioner import TemplateCaptioner  # noqa: E402
from openmulti_env.results import write_json_atomic  # noqa: E402
from openmulti_env.world.semantics import instance_infos  # noqa: E402
from openmulti_env.world import REPLICA_LIKE_PRESETS, make_scene  # noqa: E402
from openmulti_env.world.furniture import CATEGORIES  # noqa: E402
from openmulti_env.world.scene import STRUCTURE_CATEGORIES  # noqa: E402

QUERIES = Path(__file__).with_name("retrieval_queries.yaml")
KINDS = ("name", "synonym", "function")
LABEL_PROMPTS = ("{}", "a {}", "a photo of a {}", "a {} in a room")


@dataclass(frozen=True)
class Query:
    """One benchmark query: its text, kind and the categories that answer it."""

    text: str
    kind: str
    accept: frozenset[str]


def load_queries(path: Path) -> list[Query]:
    """Queries of the YAML file (ValueError naming an unknown kind or category)."""
    known = set(CATEGORIES) | set(STRUCTURE_CATEGORIES)
    out = []
    for rec in yaml.safe_load(path.read_text())["queries"]:
        q = Query(rec["text"], rec["kind"], frozenset(rec["accept"]))
        if q.kind not in KINDS or not q.accept <= known:
            raise ValueError(f"{path}: query {q.text!r} has kind {q.kind!r} or unknown categories "
                             f"{sorted(q.accept - known)}")
        out.append(q)
    return out


def scene_codebook(scene, encoder, captions: str = "metadata", seed: int = 0,
                   views: int = 10) -> tuple[CodeBook, dict[int, str]]:
    """Code book of a scene's instances and id -> ground-truth category.

    ``captions``: "metadata" = the scene's own caption of each instance; "captioner" = what the fused
    code book of a run holds without semantic errors: the simulated captioner's phrasings of
    ``views`` frames, their SBERT features averaged and re-normalised (as cross-frame fusion does)
    and the most frequent phrasing as the caption text.
    """
    if captions == "metadata":
        texts = [inst.caption for inst in scene.instances]
        features = encoder.encode(texts)
    else:
        captioner = TemplateCaptioner(seed)
        texts, features = [], []
        for info in instance_infos(scene):
            phrasings = [captioner.caption(info, agent=0, frame_index=f) for f in range(views)]
            mean = encoder.encode(phrasings).mean(axis=0)
            features.append(mean / np.linalg.norm(mean))
            texts.append(max(sorted(set(phrasings)), key=phrasings.count))
    book = CodeBook({inst.instance_id: CodeBookEntry(text, f, confidence=1.0)
                     for inst, text, f in zip(scene.instances, texts, features)})
    return book, {inst.instance_id: inst.category for inst in scene.instances}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", nargs="*", default=list(REPLICA_LIKE_PRESETS))
    parser.add_argument("--queries", type=Path, default=QUERIES)
    parser.add_argument("--out", default="runs/bench_retrieval", help="prefix of the .json and .png written")
    parser.add_argument("--captions", choices=("metadata", "captioner"), default="metadata",
                        help="the scene's own captions, or the simulated captioner's phrasings")
    args = parser.parse_args()

    queries = load_queries(args.queries)
    encoder = shared_text_encoder()
    vocabulary = list(CATEGORIES) + list(STRUCTURE_CATEGORIES)
    rows, labelling = [], {p: [0, 0] for p in LABEL_PROMPTS}
    for name in args.scenes:
        scene = make_scene(name)
        book, truth = scene_codebook(scene, encoder, args.captions)
        present = set(truth.values())
        for q in queries:
            if not q.accept & present:
                continue
            best = score_instances(q.text, book, encoder)[0]
            rows.append({"scene": name, "query": q.text, "kind": q.kind, "correct": truth[best.instance_id] in q.accept,
                         "top_caption": best.caption, "top_category": truth[best.instance_id],
                         "score": round(best.score, 4)})
        for prompt in LABEL_PROMPTS:
            labels = zero_shot_labels(book, vocabulary, encoder, prompt=prompt)
            labelling[prompt][0] += sum(labels[i] == truth[i] for i in labels)
            labelling[prompt][1] += len(labels)

    table = _table(rows, args.scenes)
    _print_tables(rows, table, labelling, args.scenes, args.captions)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    result = {"scenes": args.scenes, "queries": len(queries), "captions": args.captions, "image_encoder": None,
              "top1_pct": table, "labelling_pct": {p: 100.0 * k / n for p, (k, n) in labelling.items()},
              "rows": rows}
    write_json_atomic(out.with_suffix(".json"), result)
    _plot(table, args.scenes, out.with_suffix(".png"), args.captions)
    print(f"\nWrote {out.with_suffix('.json')} and {out.with_suffix('.png')}")


def _table(rows: list[dict], scenes: list[str]) -> dict:
    """kind -> {"queries", "n" (query, scene) pairs, "all", scene: top-1 %} (None: no query of that kind)."""
    table = {}
    for kind in KINDS + ("all",):
        sel = [r for r in rows if kind == "all" or r["kind"] == kind]
        entry = {"queries": len({r["query"] for r in sel}), "n": len(sel), "all": _pct(sel)}
        entry.update({s: _pct([r for r in sel if r["scene"] == s]) for s in scenes})
        table[kind] = entry
    return table


def _pct(rows: list[dict]) -> float | None:
    return 100.0 * float(np.mean([r["correct"] for r in rows])) if rows else None


def _print_tables(rows: list[dict], table: dict, labelling: dict, scenes: list[str], captions: str) -> None:
    cell = lambda v: "-" if v is None else f"{v:.0f}"  # noqa: E731
    print(f"Top-1 retrieval [%], caption term only ({captions} captions, SBERT), {len(rows)} (query, scene) pairs")
    print("| kind | queries | pairs | top-1 | " + " | ".join(scenes) + " |")
    print("|---|---:|---:|---:|" + "---:|" * len(scenes))
    for kind, e in table.items():
        print(f"| {kind} | {e['queries']} | {e['n']} | {cell(e['all'])} | "
              + " | ".join(cell(e[s]) for s in scenes) + " |")
    print("\nMisses:")
    for r in rows:
        if not r["correct"]:
            print(f"  [{r['kind']:<8}] {r['scene']:<8} {r['query']!r:<38} -> {r['top_category']:<13} {r['top_caption']!r}")
    print("\nZero-shot labelling [% of instances given their ground-truth category], by category-name prompt")
    for prompt, (k, n) in labelling.items():
        print(f"  {prompt!r:<20} {100.0 * k / n:5.1f}  ({k}/{n})")


def _plot(table: dict, scenes: list[str], path: Path, captions: str) -> None:
    fig, ax = plt.subplots(figsize=(10, 4))
    width = 0.8 / len(KINDS)
    x = np.arange(len(scenes) + 1)
    for k, kind in enumerate(KINDS):
        values = [table[kind]["all"]] + [table[kind][s] for s in scenes]
        ax.bar(x + (k - 1) * width, [np.nan if v is None else v for v in values], width, label=kind)
    ax.set_xticks(x, ["all"] + scenes)
    ax.set_ylabel("top-1 [%]")
    ax.set_ylim(0, 118)
    ax.axhline(85, color="grey", lw=0.8, ls="--")
    ax.axhline(70, color="grey", lw=0.8, ls=":")
    ax.legend(ncol=3, loc="upper center", fontsize=9)
    ax.set_title(f"Open-vocabulary retrieval, caption term only (SBERT on {captions} captions)")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


if __name__ == "__main__":
    main()
