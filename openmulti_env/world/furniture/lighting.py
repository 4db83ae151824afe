"""Lighting (floor lamp, table lamp): a stand under a shade; the two share the shade colours."""

from __future__ import annotations

import numpy as np

from openmulti_env.world.furniture.base import FurnitureSpec, uniform
from openmulti_env.world.furniture_parts import (
    PALETTE, caption, choice, cylinder, frustum, jitter, lathe, material_color, pick_color, rod, shade,
)


def _shade_color(rng):
    return pick_color(rng, ("white", "cream", "beige", "off-white", "light grey", "mustard yellow", "sage green"))


def build_lamp(rng):
    material = choice(rng, ("metal", "wooden"), (0.75, 0.25))
    cname, col = material_color(rng, material) if material == "wooden" else pick_color(
        rng, ("black", "silver", "gold", "white", "dark grey"))
    sname, scol = _shade_color(rng)
    H = uniform(rng, 1.4, 1.8)
    sh, rb, rt = uniform(rng, 0.25, 0.35), uniform(rng, 0.18, 0.25), uniform(rng, 0.12, 0.18)
    parts = []
    tripod = material == "wooden" or rng.random() < 0.25
    if tripod:
        spread, zc = uniform(rng, 0.25, 0.32), H * 0.55
        for i in range(3):
            a = np.pi / 2 + 2 * np.pi * i / 3
            parts.append(rod((spread * np.cos(a), spread * np.sin(a), 0.015), (0, 0, zc), 0.015, col, 8))
        parts.append(cylinder(0.014, H - sh * 0.6 - zc + 0.02, 0, 0, zc - 0.02, col, 10))
    else:
        parts.append(cylinder(uniform(rng, 0.12, 0.17), uniform(rng, 0.02, 0.035), 0, 0, 0, shade(col, 0.9), 20))
        parts.append(cylinder(uniform(rng, 0.011, 0.016), H - sh * 0.6, 0, 0, 0.01, col, 10))
    parts.append(frustum(rb, rt, sh, 0, 0, H - sh, scol, 20))
    caps = ("a {c} {m} floor lamp with a {s} shade", "a tall {m} standing lamp in {c}",
            "a {c} {m} {t}floor lamp")
    return FurnitureSpec(parts, col, cname, material,
                 caption(rng, caps, c=cname, m=material, s=sname, t="tripod " if tripod else ""),
                 variant="tripod" if tripod else "pole")


def build_table_lamp(rng):
    material = choice(rng, ("ceramic", "metal", "glass"), (0.5, 0.35, 0.15))
    cname, col = material_color(rng, material) if material != "metal" else pick_color(
        rng, ("black", "silver", "gold", "white"))
    sname, scol = _shade_color(rng)
    parts = []
    if material == "metal":
        bh = uniform(rng, 0.015, 0.03)
        parts.append(cylinder(uniform(rng, 0.06, 0.09), bh, 0, 0, 0, col, 20))
        stem = uniform(rng, 0.2, 0.35)
        parts.append(cylinder(0.008, stem, 0, 0, bh, col, 8))
        body_top = bh + stem
    else:
        r, h = uniform(rng, 0.05, 0.09), uniform(rng, 0.15, 0.28)
        parts.append(lathe([(r * 0.6, 0), (r, h * 0.3), (r * 0.95, h * 0.65), (r * 0.35, h * 0.92), (0.015, h)],
                           color=col, sections=18))
        parts.append(cylinder(0.006, 0.08, 0, 0, h - 0.005, jitter(PALETTE["silver"], rng), 8))
        body_top = h + 0.075
    sh, rb = uniform(rng, 0.14, 0.22), uniform(rng, 0.1, 0.17)
    parts.append(frustum(rb, rb * uniform(rng, 0.6, 0.85), sh, 0, 0, body_top - sh * 0.35, scol, 20))
    caps = ("a {c} {m} table lamp", "a small {m} bedside lamp in {c} with a {s} shade",
            "a {c} {m} desk lamp with a {s} lampshade")
    return FurnitureSpec(parts, col, cname, material, caption(rng, caps, c=cname, m=material, s=sname))
