"""Plants (floor plant, potted plant): a pot with foliage or a cactus; shared pot and foliage."""

from __future__ import annotations

import numpy as np

from openmulti_env.world.furniture.base import FurnitureSpec, uniform
from openmulti_env.world.furniture_parts import (
    FOLIAGE, PALETTE, capsule, caption, choice, cylinder, frustum, jitter, material_color, pick_color,
    shade, sphere,
)


def _foliage(parts, rng, cx, cy, zc, spread, r0, r1, n, zspread):
    for _ in range(n):
        r = uniform(rng, r0, r1)
        a, d = uniform(rng, 0, 2 * np.pi), uniform(rng, 0, spread)
        z = zc + uniform(rng, -zspread, zspread)
        parts.append(sphere(r, cx + d * np.cos(a), cy + d * np.sin(a), z,
                            jitter(FOLIAGE[int(rng.integers(len(FOLIAGE)))], rng, 0.08), 1))


def _pot(rng, parts, rb, h, material, col):
    rt = rb * uniform(rng, 1.1, 1.35)
    parts.append(frustum(rb, rt, h, 0, 0, 0, col, 18))
    parts.append(cylinder(rt + 0.008, h * 0.12, 0, 0, h * 0.88, shade(col, 0.92), 18))
    parts.append(cylinder(rt - 0.01, 0.01, 0, 0, h * 0.9, jitter(PALETTE["dark brown"], rng), 18))
    return rt


def build_plant(rng):
    material = choice(rng, ("ceramic", "plastic", "wooden"), (0.6, 0.3, 0.1))
    cname, col = pick_color(rng, ("terracotta", "white", "grey", "black", "cream", "sage green", "teal")) \
        if material == "ceramic" else material_color(rng, material)
    ph, rb = uniform(rng, 0.25, 0.45), uniform(rng, 0.12, 0.19)
    parts = []
    rt = _pot(rng, parts, rb, ph, material, col)
    style = choice(rng, ("tree", "bush"), (0.5, 0.5))
    if style == "tree":
        H = uniform(rng, 1.1, 1.8)
        parts.append(cylinder(0.02, H * 0.7 - ph, 0, 0, ph * 0.9, jitter(PALETTE["brown"], rng), 8))
        crown = (H - ph) * 0.3
        _foliage(parts, rng, 0, 0, H - crown, rt * 1.2, 0.12, 0.2, int(rng.integers(6, 10)), crown * 0.6)
    else:
        _foliage(parts, rng, 0, 0, ph + 0.15, rt * 1.1, 0.15, 0.25, int(rng.integers(5, 9)), 0.12)
    caps = ("a {t} leafy green plant in a {c} {m} pot", "a large potted plant with a {c} {m} planter",
            "an indoor {t} in a {c} {m} flower pot")
    return FurnitureSpec(parts, col, cname, material,
                 caption(rng, caps, c=cname, m=material, t="tree" if style == "tree" else "bushy"), variant=style)


def build_potted_plant(rng):
    material = choice(rng, ("ceramic", "plastic"), (0.75, 0.25))
    cname, col = material_color(rng, material)
    ph, rb = uniform(rng, 0.07, 0.14), uniform(rng, 0.045, 0.08)
    parts = []
    rt = _pot(rng, parts, rb, ph, material, col)
    style = choice(rng, ("leafy", "cactus"), (0.7, 0.3))
    if style == "cactus":
        ch = uniform(rng, 0.1, 0.25)
        g = jitter((0.25, 0.48, 0.22), rng, 0.05)
        parts.append(capsule(rt * 0.5, ch, 0, 0, ph * 0.85, g))
        if rng.random() < 0.6:
            parts.append(capsule(rt * 0.28, ch * 0.4, rt * 0.55, 0, ph * 0.85 + ch * 0.35, g))
    else:
        _foliage(parts, rng, 0, 0, ph + rt * 0.9, rt * 0.7, rt * 0.45, rt * 0.8, int(rng.integers(3, 7)), rt * 0.4)
    caps = ("a small {p} in a {c} {m} pot", "a {c} {m} pot with a little {p}", "a small potted {p}, {c} {m} pot")
    return FurnitureSpec(parts, col, cname, material,
                 caption(rng, caps, c=cname, m=material, p="cactus" if style == "cactus" else "houseplant"),
                 variant=style)
