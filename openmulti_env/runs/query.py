"""``openmulti query --run DIR "TEXT"``: open-vocabulary instance retrieval on a finished run.

A run directory holds ``metrics.json`` (its ``config``), ``meshes/agent_K.ply`` (scene meshes whose
vertices carry instance ids) and ``codebook/agent_K.json/.npz`` (each agent's ids are its own).
``load_map(DIR)`` reads the code books once and encodes them for retrieval
(``mapping.evaluate.retrieval.RetrievalIndex``), so ``.query(text)`` costs one query encoding.

Speed: the text encoder runs on the NumPy backend (no torch import) and nothing heavy is imported
until needed; the top-down picture (``DIR/plots/query_<slug>.png``, best instance highlighted) needs
the meshes and matplotlib, so it is drawn only when asked (``plot=True``, ``--plot``).
"""

from __future__ import annotations

import re
import sys
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mapping.evaluate.retrieval import RetrievalHit, RetrievalIndex, check_encoder
from mapping.perception.codebook import CodeBook, CodeBookError
from mapping.safe_parse import load_json

__all__ = ["QueryResult", "RunMap", "load_map", "load_run_codebooks", "query_slug", "run_query"]

MAX_PLOT_POINTS = 150_000
"""Background points drawn at most (a random subset beyond that keeps the scatter fast)."""

PLOT_POINTS_PER_MESH = 60_000
"""Surface samples added to each agent mesh's vertices for the picture."""


def vocabulary() -> tuple[str, ...]:
    """Categories for zero-shot labels of instances whose code book has none (the simulator's 34)."""
    from openmulti_env.world.furniture import CATEGORIES  # noqa: PLC0415 (heavy: only when a book lacks labels)
    from openmulti_env.world.scene import STRUCTURE_CATEGORIES  # noqa: PLC0415

    return tuple(CATEGORIES) + tuple(STRUCTURE_CATEGORIES)


@dataclass
class QueryResult:
    """What ``run_query`` found: the JSON printed and the picture written (None without one)."""

    payload: dict
    plot: Path | None


def query_slug(text: str, max_len: int = 60) -> str:
    """File-name-safe form of a query: lowercase words joined by ``_`` ("Somewhere to sleep?" -> "somewhere_to_sleep")."""
    slug = re.sub(r"[^a-z0-9]+", "_", text.lower()).strip("_")[:max_len].rstrip("_")
    return slug or "query"


def load_run_codebooks(run_dir: Path) -> dict[str, CodeBook]:
    """``{"agent_K": book}`` for every agent.

    Raises:
        FileNotFoundError: the run directory does not exist.
        CodeBookError: there is no code book, or one is corrupt.
    """
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise FileNotFoundError(f"run directory not found: {run_dir}")
    folder = run_dir / "codebook"
    names = sorted((p.stem for p in folder.glob("agent_*.json")), key=_agent_index)
    if not names:
        metrics = run_dir / "metrics.json"
        if metrics.is_file() and load_json(metrics).get("evaluated") is False:
            raise CodeBookError(f"{run_dir} was mapped with --no-evaluation: it has no code books yet; run the same "
                                "command without --no-evaluation to score the maps and write them")
        raise CodeBookError(f"no code book in {folder} (expected agent_K.json + agent_K.npz): was the run made with the perception front end?")
    return {name: CodeBook.load(folder, name) for name in names}


class RunMap:
    """A finished run's code books, encoded once: ``query(text)`` answers in milliseconds.

    Args:
        run_dir: the run directory (see the module docstring).
        text_encoder: an encoder object, an encoder name ("mpnet", "minilm"), or None for the encoder
            the code books record. Another encoder than theirs is refused (EncoderMismatchError).
        image_encoder: None, or a CLIP-like encoder with ``encode_texts`` (visual term weight 0.8).
        backend: text encoder backend when it is made here: "numpy" (fast start) or "torch".
    """

    def __init__(self, run_dir: str | Path, text_encoder=None, image_encoder=None, backend: str = "numpy"):
        self.run_dir = Path(run_dir)
        self.books = load_run_codebooks(self.run_dir)
        if text_encoder is None or isinstance(text_encoder, str):
            from mapping.perception.text_encoder import DEFAULT_TEXT_ENCODER, shared_text_encoder  # noqa: PLC0415

            recorded = next((b.encoder_name() for b in self.books.values() if b.encoder_name()), None)
            text_encoder = shared_text_encoder(name=text_encoder or recorded or DEFAULT_TEXT_ENCODER, backend=backend,
                                               persist=True)  # category prompts are encoded once per machine
        self.text_encoder, self.image_encoder = text_encoder, image_encoder
        self.indexes: dict[str, RetrievalIndex] = {}
        for agent, book in self.books.items():
            check_encoder(book, text_encoder)  # before any labelling, so the error names the encoders
            labels = {i: e.label for i, e in book.items()}
            if any(v is None for v in labels.values()):
                from mapping.evaluate.semantic import zero_shot_labels  # noqa: PLC0415

                zero_shot = zero_shot_labels(book, vocabulary(), text_encoder, image_encoder)
                labels = {i: labels[i] or zero_shot[i] for i in book}
            self.indexes[agent] = RetrievalIndex(book, text_encoder, image_encoder, labels)

    def rank(self, text: str) -> list[tuple[str, RetrievalHit]]:
        """(agent, hit) of every instance of every code book, best first."""
        if not isinstance(text, str) or not text.strip():
            raise ValueError("the query text is empty: give what to look for, e.g. \"somewhere to sleep\"")
        hits = [(agent, h) for agent, index in self.indexes.items() for h in index.rank(text)]
        hits.sort(key=lambda ah: (-ah[1].score, _agent_index(ah[0]), ah[1].instance_id))
        return hits

    def query(self, text: str, top_k: int = 5) -> list[dict]:
        """The ``top_k`` best instances as dicts (id, agent, category, caption, score, terms)."""
        if top_k < 1:
            raise ValueError(f"--top must be at least 1, got {top_k}")
        return [{"id": h.instance_id, "agent": agent, "category": h.label, "caption": h.caption,
                 "score": round(h.score, 4), "terms": list(h.terms)} for agent, h in self.rank(text)[:top_k]]


def load_map(run_dir: str | Path, text_encoder=None, image_encoder=None, backend: str = "numpy") -> RunMap:
    """``RunMap`` of a finished run: ``load_map("runs/demo").query("somewhere to sleep")``."""
    return RunMap(run_dir, text_encoder, image_encoder, backend)


def _agent_index(name: str) -> int:
    tail = name.rsplit("_", 1)[-1]
    return int(tail) if tail.isdigit() else 1 << 30


def _load_meshes(run_dir: Path, points_per_mesh: int = PLOT_POINTS_PER_MESH) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """agent name -> (points (n, 3) float64, instance ids (n,) int) of ``meshes/agent_K.ply``.

    The points are the vertices plus area-uniform samples on the faces (each sample takes the id of
    its face's first vertex), so low-poly meshes still draw as filled shapes.
    """
    import trimesh  # noqa: PLC0415 (meshes are for the picture only)

    from mapping.evaluate.meshing import load_scene_mesh  # noqa: PLC0415

    out = {}
    for path in sorted((run_dir / "meshes").glob("agent_*.ply"), key=lambda p: _agent_index(p.stem)):
        mesh, ids = load_scene_mesh(path)
        verts, ids = np.asarray(mesh.vertices, np.float64), np.asarray(ids)
        if len(mesh.faces) and mesh.area > 0:
            samples, face = trimesh.sample.sample_surface(mesh, points_per_mesh, seed=0)
            verts = np.concatenate([verts, samples])
            ids = np.concatenate([ids, ids[np.asarray(mesh.faces)[face, 0]]])
        out[path.stem] = (verts, ids)
    return out


def image_encoder_or_none(checkpoint: str | None):
    """The image-text encoder for ``checkpoint`` (None without one; the loader says so once)."""
    try:
        from mapping.perception.image_encoder import ImageEncoderError, load_image_encoder  # noqa: PLC0415
    except ImportError:
        if checkpoint:
            raise ValueError("--clip-checkpoint given but this install has no image-text encoder module") from None
        print("openmulti query: no image-text encoder: caption term only", file=sys.stderr)
        return None
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("always")
            warnings.showwarning = _warning_to_stderr
            return load_image_encoder(checkpoint)
    except ImageEncoderError as exc:
        raise ValueError(str(exc)) from exc


def _warning_to_stderr(message, category, filename, lineno, file=None, line=None) -> None:
    print(f"openmulti query: {message}", file=sys.stderr)


def run_query(run_dir: str | Path, text: str, top_k: int = 5, clip_checkpoint: str | None = None,
              text_encoder=None, plot: bool = False, run_map: RunMap | None = None) -> QueryResult:
    """Score every instance of a run against ``text``; return the JSON payload (and the picture if asked).

    Args:
        run_dir: the run directory (see the module docstring).
        text: the query, not blank.
        top_k: how many hits to report (>= 1).
        clip_checkpoint: optional local image-text checkpoint (visual term weight 0.8 when loaded).
        text_encoder: an encoder, an encoder name, or None for the code books' own encoder.
        plot: also write ``DIR/plots/query_<slug>.png`` (loads the meshes: about a second more).
        run_map: a ``RunMap`` already loaded (many queries on one run).

    Raises:
        ValueError: blank text, bad ``top_k``, another encoder than the code books', or a missing /
            corrupt code book (CodeBookError).
        FileNotFoundError: no such run directory.
    """
    if not isinstance(text, str) or not text.strip():
        raise ValueError("the query text is empty: give what to look for, e.g. \"somewhere to sleep\"")
    if top_k < 1:
        raise ValueError(f"--top must be at least 1, got {top_k}")
    run_dir = Path(run_dir)
    if run_map is None:
        run_map = RunMap(run_dir, text_encoder, image_encoder_or_none(clip_checkpoint))
    hits = run_map.rank(text)
    results = run_map.query(text, top_k)
    payload = {"query": text, "run": str(run_dir), "scene": _scene_name(run_dir), "results": results}
    meshes = _load_meshes(run_dir) if plot else {}
    picture = None
    if plot and hits and meshes:
        labels_by_agent = {agent: index.labels for agent, index in run_map.indexes.items()}
        picture = _plot_query(run_dir / "plots" / f"query_{query_slug(text)}.png", text, hits[0], meshes,
                              labels_by_agent, hits[1:top_k])
    payload["plot"] = None if picture is None else str(picture)
    return QueryResult(payload, picture)


def _scene_name(run_dir: Path) -> str | None:
    try:
        return load_json(run_dir / "metrics.json")["config"]["scene"]
    except (OSError, ValueError, KeyError, TypeError):
        return None


def _plot_query(path: Path, text: str, best: tuple[str, RetrievalHit], meshes: dict,
                labels_by_agent: dict, runners_up: list[tuple[str, RetrievalHit]]) -> Path:
    """Top-down scatter of the meshes' points (grey shades by height, ceiling left out), the best
    instance in red, the runners-up's ranks written at their centres."""
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    def points_of(agent: str, instance_id: int) -> np.ndarray:
        sources = [meshes[agent]] if agent in meshes else []
        return np.concatenate([v[ids == instance_id] for v, ids in sources] or [np.zeros((0, 3))])

    background = []
    for agent, (verts, ids) in meshes.items():
        labels = labels_by_agent.get(agent, {})
        ceiling = [i for i, label in labels.items() if label == "ceiling"]
        background.append(verts[~np.isin(ids, ceiling)])
    background = np.concatenate(background)
    if len(background) > MAX_PLOT_POINTS:
        background = background[np.random.default_rng(0).choice(len(background), MAX_PLOT_POINTS, replace=False)]
    background = background[np.argsort(background[:, 2], kind="stable")]  # higher surfaces drawn on top

    fig, ax = plt.subplots(figsize=(7, 6))
    sc = ax.scatter(background[:, 0], background[:, 1], c=background[:, 2], cmap="Greys", s=0.5,
                    vmin=background[:, 2].min() - 0.5 if len(background) else 0, linewidths=0, rasterized=True)
    fig.colorbar(sc, ax=ax, label="height z [m]", shrink=0.8)
    for rank, (agent, hit) in enumerate(runners_up, start=2):  # rank numbers at their centres
        pts = points_of(agent, hit.instance_id)
        if len(pts):
            ax.annotate(str(rank), pts[:, :2].mean(axis=0), color="darkorange", fontsize=11, weight="bold",
                        ha="center", va="center")
    agent, hit = best
    pts = points_of(agent, hit.instance_id)
    ax.scatter(pts[:, 0], pts[:, 1], s=3, color="red", linewidths=0,
               label=f"best: {hit.label or '?'} ({agent} id {hit.instance_id}, score {hit.score:.2f})")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.legend(loc="upper right", fontsize=8, markerscale=3)
    ax.set_title(f"query: {text!r}\nbest: {hit.caption!r}" + (" (orange numbers: ranks 2+)" if runners_up else ""), fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
