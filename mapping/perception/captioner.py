"""Simulated dense captioner (TAP stand-in): varied captions from an instance's metadata.

A real captioner describes the same object differently from frame to frame ("a red wooden chair",
"chair", "the seat in red"). This one draws the phrasing per (seed, agent, frame, instance, piece),
so the captions of one instance vary over time and agents while saying only what the metadata
supports: category (with synonyms), colour word, material word, and the scene's own caption.

A semantic error (decided by the error model, persistent per instance) is a caption of a plausible
wrong category: a visually confusable one (chair -> stool, table -> desk, pillow -> sofa, rug -> floor
...) or, for categories without such a partner, another non-structure category of the scene.
"""

from __future__ import annotations

from typing import Protocol, Sequence

import numpy as np

from mapping.perception.types import InstanceInfo

# Nouns a captioner would use for each simulator category; the first is the canonical one.
SYNONYMS: dict[str, tuple[str, ...]] = {
    "chair": ("chair", "side chair", "seat"),
    "armchair": ("armchair", "lounge chair", "easy chair"),
    "sofa": ("sofa", "couch", "settee"),
    "stool": ("stool", "backless stool"),
    "table": ("table", "dining table"),
    "coffee_table": ("coffee table", "low table"),
    "desk": ("desk", "writing desk", "work desk"),
    "bed": ("bed", "double bed"),
    "nightstand": ("nightstand", "bedside table", "night table"),
    "cabinet": ("cabinet", "cupboard", "sideboard"),
    "wardrobe": ("wardrobe", "closet", "armoire"),
    "bookshelf": ("bookshelf", "bookcase", "shelving unit"),
    "lamp": ("floor lamp", "lamp", "standing lamp"),
    "plant": ("plant", "houseplant", "indoor plant"),
    "tv": ("tv", "television", "flat-screen tv"),
    "rug": ("rug", "carpet", "mat"),
    "trash_bin": ("trash bin", "trash can", "waste bin"),
    "box": ("box", "storage box"),
    "door": ("door",),
    "window_frame": ("window", "window frame"),
    "picture": ("picture", "painting", "framed picture"),
    "table_lamp": ("table lamp", "desk lamp", "lamp"),
    "potted_plant": ("potted plant", "small plant", "plant pot"),
    "monitor": ("monitor", "computer monitor", "screen"),
    "keyboard": ("keyboard", "computer keyboard"),
    "laptop": ("laptop", "laptop computer", "notebook computer"),
    "mug": ("mug", "cup", "coffee mug"),
    "bottle": ("bottle", "water bottle"),
    "book": ("book", "hardcover book"),
    "pillow": ("pillow", "cushion", "throw pillow"),
    "vase": ("vase", "flower vase"),
    "wall": ("wall",),
    "floor": ("floor",),
    "ceiling": ("ceiling",),
}

# Categories a segmenter plausibly mistakes each category for (semantic errors).
CONFUSABLE: dict[str, tuple[str, ...]] = {
    "chair": ("stool", "armchair"), "armchair": ("sofa", "chair"), "sofa": ("armchair", "bed"),
    "stool": ("chair", "table"), "table": ("desk", "coffee_table"), "coffee_table": ("table", "stool"),
    "desk": ("table", "cabinet"), "bed": ("sofa",), "nightstand": ("cabinet", "table"),
    "cabinet": ("wardrobe", "nightstand", "bookshelf"), "wardrobe": ("cabinet", "door"),
    "bookshelf": ("cabinet", "wardrobe"), "lamp": ("table_lamp", "plant"), "plant": ("potted_plant",),
    "tv": ("monitor", "picture"), "rug": ("floor",), "trash_bin": ("box", "vase"), "box": ("trash_bin", "cabinet"),
    "door": ("wardrobe", "wall"), "window_frame": ("picture", "door"), "picture": ("window_frame", "tv"),
    "table_lamp": ("lamp", "vase"), "potted_plant": ("plant", "vase"), "monitor": ("tv", "laptop"),
    "keyboard": ("laptop", "book"), "laptop": ("keyboard", "monitor"), "mug": ("bottle", "vase"),
    "bottle": ("vase", "mug"), "book": ("box",), "pillow": ("sofa", "bed"), "vase": ("bottle", "mug"),
}

UNKNOWN_CAPTION = "an object"

_CANONICAL_WEIGHT = 0.5  # share of captions using the category's canonical noun
_SCENE_CAPTION_WEIGHT = 0.2  # share of (true-category) captions that repeat the scene's own caption

# Phrasings; {n} noun, {c} colour word, {m} material word. Each is used only when its fields exist.
TEMPLATES: tuple[str, ...] = (
    "{n}", "a {n}", "the {n}", "a {c} {n}", "{c} {n}", "a {m} {n}", "a {c} {m} {n}",
    "a {n} in {c}", "a {m} {n} in {c}", "the {c} {n}", "a {c} colored {n}",
)


class Captioner(Protocol):
    """What the oracle segmenter needs from a captioner."""

    def caption(self, info: InstanceInfo, agent: int, frame_index: int, category: str | None = None,
                variant: int = 0) -> str:
        """Caption of one mask of ``info`` (``category`` overrides the true one for a semantic error)."""
        ...


def noun_for(category: str) -> str:
    """Canonical noun of a category ("coffee_table" -> "coffee table")."""
    return SYNONYMS.get(category, (category.replace("_", " ").strip(),))[0]


def wrong_category(category: str, rng: np.random.Generator, scene_categories: Sequence[str] = ()) -> str:
    """A plausible wrong category for a semantic error.

    A confusable partner of ``category`` when one is known, else another non-structure category of
    the scene, else "object".
    """
    options = [c for c in CONFUSABLE.get(category, ()) if c != category]
    if not options:
        options = sorted({c for c in scene_categories if c != category and c not in ("wall", "floor", "ceiling")})
    if not options:
        return "object"
    return options[int(rng.integers(len(options)))]


class TemplateCaptioner:
    """Captions from metadata with seeded, varied phrasings and per-category synonyms.

    Args:
        seed: with (agent, frame, instance, variant) it fixes every phrasing choice.
    """

    def __init__(self, seed: int = 0):
        self.seed = int(seed)

    def caption(self, info: InstanceInfo, agent: int, frame_index: int, category: str | None = None,
                variant: int = 0) -> str:
        """Caption of one mask of ``info`` seen by ``agent`` in frame ``frame_index``.

        Args:
            info: the instance under the mask.
            agent: agent index (>= 0).
            frame_index: the frame's index (>= 0).
            category: a wrong category to describe instead of ``info.category`` (semantic error).
            variant: piece number when one instance has several masks in the frame.
        """
        rng = np.random.default_rng([self.seed, int(agent), int(frame_index), int(info.instance_id),
                                     int(variant), 5])
        true_category = category is None or category == info.category
        if true_category and info.caption and rng.random() < _SCENE_CAPTION_WEIGHT:
            return info.caption
        cat = info.category if category is None else category
        nouns = SYNONYMS.get(cat, (noun_for(cat),))
        noun = nouns[0]
        if len(nouns) > 1 and rng.random() >= _CANONICAL_WEIGHT:
            noun = nouns[1 + int(rng.integers(len(nouns) - 1))]
        fields = {"n": noun, "c": info.color_name.strip(), "m": info.material.strip()}
        usable = [t for t in TEMPLATES if all(fields[k] or "{" + k + "}" not in t for k in ("c", "m"))]
        text = usable[int(rng.integers(len(usable)))].format(**fields)
        return fix_article(" ".join(text.split()))


def fix_article(text: str) -> str:
    """Replace "a" by "an" before a vowel sound (simple first-letter rule)."""
    words = text.split(" ")
    for i in range(len(words) - 1):
        if words[i].lower() in ("a", "an") and words[i + 1]:
            an = words[i + 1][0].lower() in "aeiou"
            words[i] = ("An" if an else "A") if words[i][0].isupper() else ("an" if an else "a")
    return " ".join(words)
