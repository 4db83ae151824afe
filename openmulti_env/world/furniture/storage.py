"""Storage (cabinet, nightstand, wardrobe, bookshelf): wall bodies with doors, drawers, shelves."""

from __future__ import annotations

import numpy as np

from openmulti_env.world.furniture.base import FurnitureSpec, carcass_parts, door_rects, front_panels, support_surface, uniform
from openmulti_env.world.furniture_parts import PALETTE, box, caption, choice, jitter, material_color, shade


def build_cabinet(rng):
    material = choice(rng, ("wooden", "metal"), (0.8, 0.2))
    cname, col = material_color(rng, material)
    W, D, H = uniform(rng, 0.6, 1.6), uniform(rng, 0.35, 0.5), uniform(rng, 0.6, 1.2)
    parts, z0, z1, (tx0, tx1, ty0, ty1) = carcass_parts(rng, W, D, H, col, choice(rng, ("legs", "plinth", "none")))
    layout = choice(rng, ("doors", "drawers", "mixed"))
    x0, x1 = -W / 2 + 0.015, W / 2 - 0.015
    n_doors = 1 if W < 0.6 else (2 if W < 1.3 else 3)
    if layout == "doors":
        rects = door_rects(x0, x1, z0 + 0.01, z1 - 0.01, n_doors)
    elif layout == "drawers":
        n = int(rng.integers(3, 6))
        zz = np.linspace(z0 + 0.01, z1 - 0.01, n + 1)
        cols = 1 if W < 1.0 else 2
        rects = [(x0 + (x1 - x0) * j / cols, x0 + (x1 - x0) * (j + 1) / cols, zz[i], zz[i + 1], "drawer")
                 for i in range(n) for j in range(cols)]
    else:
        zd = z1 - 0.01 - min(0.18, (z1 - z0) * 0.3)
        rects = [(x0 + (x1 - x0) * j / n_doors, x0 + (x1 - x0) * (j + 1) / n_doors, zd, z1 - 0.01, "drawer")
                 for j in range(n_doors)] + door_rects(x0, x1, z0 + 0.01, zd, n_doors)
    hcol = jitter(PALETTE[choice(rng, ("silver", "black", "gold"))], rng)
    front_panels(parts, rects, D / 2, col, hcol, rng, choice(rng, ("bar", "knob")))
    noun = {"doors": "cabinet", "drawers": "chest of drawers", "mixed": "sideboard"}[layout]
    caps = ("a {c} {m} {n}", "a {m} storage {n} in {c}", "a {c} {n} made of {m} panels" if material == "metal"
            else "a {c} {m} {n} with {h} handles")
    return FurnitureSpec(parts, col, cname, material,
                 caption(rng, caps, c=cname, m=material, n=noun, h="metal"),
                 supports=[support_surface(H, tx0, tx1, ty0, ty1)], variant=layout)


def build_nightstand(rng):
    material = choice(rng, ("wooden", "metal"), (0.85, 0.15))
    cname, col = material_color(rng, material)
    W, D, H = uniform(rng, 0.4, 0.6), uniform(rng, 0.35, 0.45), uniform(rng, 0.45, 0.65)
    parts, z0, z1, (tx0, tx1, ty0, ty1) = carcass_parts(rng, W, D, H, col, choice(rng, ("legs", "plinth")))
    supports = [support_surface(H, tx0, tx1, ty0, ty1)]
    hcol = jitter(PALETTE[choice(rng, ("silver", "black", "gold"))], rng)
    open_shelf = rng.random() < 0.45
    x0, x1 = -W / 2 + 0.015, W / 2 - 0.015
    if open_shelf:
        # carve the niche by replacing the full body with shell panels
        parts.pop(-2)
        t = 0.018
        zd = z1 - uniform(rng, 0.14, 0.2)
        parts.append(box(t, D, z1 - z0, -W / 2 + t / 2, 0, z0, col))
        parts.append(box(t, D, z1 - z0, W / 2 - t / 2, 0, z0, col))
        parts.append(box(W, 0.012, z1 - z0, 0, -D / 2 + 0.006, z0, col))
        parts.append(box(W, D, t, 0, 0, z0, col))
        parts.append(box(W, D, z1 - zd, 0, 0, zd, col))
        supports.append(support_surface(z0 + t, -W / 2 + t, W / 2 - t, -D / 2 + 0.012, D / 2, zd - z0 - t))
        rects = [(x0, x1, zd + 0.005, z1 - 0.005, "drawer")]
    else:
        n = int(rng.integers(1, 4))
        zz = np.linspace(z0 + 0.01, z1 - 0.01, n + 1)
        rects = [(x0, x1, zz[i], zz[i + 1], "drawer") for i in range(n)]
    front_panels(parts, rects, D / 2, col, hcol, rng, choice(rng, ("bar", "knob")))
    caps = ("a {c} {m} nightstand", "a small {m} bedside table in {c}", "a {c} {m} night stand with {d}")
    return FurnitureSpec(parts, col, cname, material,
                 caption(rng, caps, c=cname, m=material, d="an open shelf" if open_shelf else "drawers"),
                 supports=supports, variant="open" if open_shelf else "drawers")


def build_wardrobe(rng):
    material = choice(rng, ("wooden", "metal"), (0.88, 0.12))
    cname, col = material_color(rng, material)
    W, D, H = uniform(rng, 0.8, 2.0), uniform(rng, 0.55, 0.65), uniform(rng, 1.8, 2.3)
    parts, z0, z1, _ = carcass_parts(rng, W, D, H, col, choice(rng, ("plinth", "legs", "none")))
    n = 2 if W < 1.3 else 3
    x0, x1 = -W / 2 + 0.015, W / 2 - 0.015
    zb = z0 + 0.01
    rects = []
    if rng.random() < 0.4:
        zb = z0 + 0.01 + uniform(rng, 0.2, 0.3)
        rects += [(x0 + (x1 - x0) * j / n, x0 + (x1 - x0) * (j + 1) / n, z0 + 0.01, zb, "drawer") for j in range(n)]
    rects += door_rects(x0, x1, zb, z1 - 0.01, n)
    hcol = jitter(PALETTE[choice(rng, ("silver", "black", "gold"))], rng)
    front_panels(parts, rects, D / 2, col, hcol, rng, "bar")
    caps = ("a {c} {m} wardrobe", "a tall {m} wardrobe in {c}", "a {c} {m} closet with {n} doors")
    return FurnitureSpec(parts, col, cname, material,
                 caption(rng, caps, c=cname, m=material, n="two" if n == 2 else "three"), variant=f"{n}-door")


def build_bookshelf(rng):
    material = choice(rng, ("wooden", "metal"), (0.85, 0.15))
    cname, col = material_color(rng, material)
    W, D, H = uniform(rng, 0.6, 1.2), uniform(rng, 0.25, 0.4), uniform(rng, 0.8, 2.1)
    t = uniform(rng, 0.018, 0.03) if material == "wooden" else 0.015
    bt = 0.01
    plinth = uniform(rng, 0.03, 0.08)
    parts = []
    parts.append(box(t, D, H, -W / 2 + t / 2, 0, 0, col))
    parts.append(box(t, D, H, W / 2 - t / 2, 0, 0, col))
    parts.append(box(W - 2 * t, bt, H - plinth, 0, -D / 2 + bt / 2, plinth, shade(col, 0.85)))
    parts.append(box(W - 2 * t, t, plinth, 0, D / 2 - 0.02 - t / 2, 0, shade(col, 0.8)))
    parts.append(box(W - 2 * t, D - bt, t, 0, bt / 2, plinth, col))       # bottom board
    parts.append(box(W - 2 * t, D - bt, t, 0, bt / 2, H - t, col))        # top board
    n = max(2, int(round((H - plinth - 2 * t) / uniform(rng, 0.28, 0.38))))
    floors = np.linspace(plinth + t, H - t, n + 1)  # bottom of each compartment ... top board bottom
    supports = []
    for i in range(n):
        if i > 0:
            parts.append(box(W - 2 * t, D - bt, t, 0, bt / 2, floors[i] - t, col))
        ceiling = floors[i + 1] - (t if i + 1 < n else 0.0)  # bottom of the next board
        supports.append(support_surface(floors[i], -W / 2 + t, W / 2 - t, -D / 2 + bt, D / 2, ceiling - floors[i]))
    if H <= 1.3:
        supports.append(support_surface(H, -W / 2, W / 2, -D / 2, D / 2, 1.0))
    caps = ("a {c} {m} bookshelf", "a {tall} {m} bookcase in {c}", "a {c} {m} shelving unit with {n} shelves")
    return FurnitureSpec(parts, col, cname, material,
                 caption(rng, caps, c=cname, m=material, tall="tall" if H > 1.5 else "low", n=n),
                 supports=supports, variant=f"{n}-shelf")
