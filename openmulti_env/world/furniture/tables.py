"""Tables (dining table, coffee table, desk): a top on legs or panels, the top a support."""

from __future__ import annotations

import numpy as np

from openmulti_env.world.furniture.base import FurnitureSpec, front_panels, table_legs, support_surface, uniform
from openmulti_env.world.furniture_parts import (
    PALETTE, box, caption, choice, cylinder, jitter, material_color, pick_color, shade,
)


def _table_like(rng, kind: str):
    """kind: 'table' (dining), 'coffee_table'."""
    material = choice(rng, ("wooden", "marble", "glass", "metal"), (0.65, 0.12, 0.13, 0.10))
    cname, col = pick_color(rng, ("clear",)) if material == "glass" else material_color(rng, material)
    if kind == "table":
        H = uniform(rng, 0.72, 0.78)
        shape = choice(rng, ("rectangular", "square", "round"), (0.55, 0.2, 0.25))
        if shape == "rectangular":
            W, D = uniform(rng, 1.1, 1.8), uniform(rng, 0.7, 1.0)
        elif shape == "square":
            W = D = uniform(rng, 0.7, 1.0)
        else:
            W = D = uniform(rng, 0.8, 1.2)
    else:
        H = uniform(rng, 0.35, 0.48)
        shape = choice(rng, ("rectangular", "round"), (0.75, 0.25))
        W, D = (uniform(rng, 0.8, 1.3), uniform(rng, 0.45, 0.7)) if shape == "rectangular" else (uniform(rng, 0.6, 0.9),) * 2
    tt = uniform(rng, 0.012, 0.02) if material == "glass" else uniform(rng, 0.025, 0.05)
    parts, supports = [], []
    if shape == "round":
        parts.append(cylinder(W / 2, tt, 0, 0, H - tt, col, 24))
        h = W / 2 / np.sqrt(2)
        supports.append(support_surface(H, -h, h, -h, h))
    else:
        parts.append(box(W, D, tt, 0, 0, H - tt, col))
        supports.append(support_surface(H, -W / 2, W / 2, -D / 2, D / 2))
    if material == "wooden":
        leg_col = shade(col, 0.8)
    else:
        leg_col = jitter(PALETTE[choice(rng, ("black", "silver", "gold", "walnut brown"))], rng)
    round_legs = material in ("glass", "metal") or rng.random() < 0.3
    lr, lt = uniform(rng, 0.015, 0.03), uniform(rng, 0.04, 0.07)
    if shape == "round":
        ix = iy = W / 2 * 0.5
    else:
        inset = uniform(rng, 0.04, 0.1)
        ix, iy = W / 2 - inset, D / 2 - inset
    table_legs(parts, (-ix, ix), (-iy, iy), 0, H - tt, leg_col, lr if round_legs else 0.0, lt)
    if material == "wooden" and shape != "round" and kind == "table":
        ah = uniform(rng, 0.06, 0.1)
        parts.append(box(2 * ix, 0.02, ah, 0, iy, H - tt - ah, leg_col))
        parts.append(box(2 * ix, 0.02, ah, 0, -iy, H - tt - ah, leg_col))
        parts.append(box(0.02, 2 * iy, ah, ix, 0, H - tt - ah, leg_col))
        parts.append(box(0.02, 2 * iy, ah, -ix, 0, H - tt - ah, leg_col))
    shelf = kind == "coffee_table" and shape == "rectangular" and rng.random() < 0.5
    if shelf:
        zs, sth = uniform(rng, 0.08, 0.14), 0.02
        parts.append(box(2 * ix, 2 * iy, sth, 0, 0, zs, shade(col, 0.9) if material != "glass" else leg_col))
        half = (lr if round_legs else lt / 2)
        supports.append(support_surface(zs + sth, -ix + half, ix - half, -iy + half, iy - half, H - tt - zs - sth))
    if kind == "table":
        caps = ("a {shape} {c} {m} table", "a {m} dining table in {c}", "a {c} {m} kitchen table with four legs")
    else:
        caps = ("a {c} {m} coffee table", "a low {shape} {m} coffee table in {c}", "a {c} {m} living room table, low and {shape}")
    return FurnitureSpec(parts, col, cname, material, caption(rng, caps, c=cname, m=material, shape=shape),
                 supports=supports, variant=shape)


def build_table(rng):
    return _table_like(rng, "table")


def build_coffee_table(rng):
    return _table_like(rng, "coffee_table")


def build_desk(rng):
    material = choice(rng, ("wooden", "metal"), (0.8, 0.2))
    cname, col = material_color(rng, "wooden" if material == "wooden" else "metal")
    W, D, H = uniform(rng, 1.0, 1.7), uniform(rng, 0.55, 0.8), uniform(rng, 0.72, 0.76)
    tt = uniform(rng, 0.025, 0.04)
    parts = [box(W, D, tt, 0, 0, H - tt, col)]
    style = choice(rng, ("legs", "panels"), (0.5, 0.5)) if material == "wooden" else "legs"
    frame_col = shade(col, 0.8) if material == "wooden" else jitter(PALETTE[choice(rng, ("black", "silver", "white"))], rng)
    if style == "legs":
        lt = uniform(rng, 0.04, 0.06)
        table_legs(parts, (-W / 2 + 0.04, W / 2 - 0.04), (-D / 2 + 0.04, D / 2 - 0.04), 0, H - tt, frame_col, 0.0, lt)
    else:
        pt = uniform(rng, 0.02, 0.03)
        for sx in (-1, 1):
            parts.append(box(pt, D - 0.02, H - tt, sx * (W / 2 - pt / 2 - 0.005), 0, 0, frame_col))
    mh = uniform(rng, 0.25, 0.4)
    parts.append(box(W - 0.1, 0.015, mh, 0, -D / 2 + 0.04, H - tt - mh, frame_col))
    drawers = rng.random() < 0.5
    if drawers:
        bw = uniform(rng, 0.35, 0.45)
        x0 = W / 2 - 0.06 - bw
        z0 = 0.05 if style == "legs" else 0.0
        parts.append(box(bw, D - 0.12, H - tt - z0, x0 + bw / 2, -0.02, z0, col))
        n = int(rng.integers(2, 4))
        zz = np.linspace(z0, H - tt, n + 1)
        yf = -0.02 + (D - 0.12) / 2
        front_panels(parts, [(x0, x0 + bw, zz[i], zz[i + 1], "drawer") for i in range(n)], yf, col,
                      jitter(PALETTE["silver"], rng), rng)
    caps = ("a {c} {m} desk", "a {m} office desk in {c}", "a {c} {m} writing desk{d}")
    return FurnitureSpec(parts, col, cname, material,
                 caption(rng, caps, c=cname, m=material, d=" with drawers" if drawers else ""),
                 supports=[support_surface(H, -W / 2, W / 2, -D / 2, D / 2)], variant=style)
