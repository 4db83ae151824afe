"""Seating (chair, stool, sofa, armchair): one family, sofa and armchair share the upholstery."""

from __future__ import annotations

import numpy as np

from openmulti_env.world.furniture.base import FurnitureSpec, table_legs, support_surface, uniform
from openmulti_env.world.furniture_parts import (
    PALETTE, box, caption, choice, cylinder, jitter, material_color, rod, shade, torus,
)


def build_chair(rng):
    material = choice(rng, ("wooden", "metal", "plastic"), (0.6, 0.2, 0.2))
    cname, col = material_color(rng, material)
    sh, w, d = uniform(rng, 0.42, 0.48), uniform(rng, 0.40, 0.50), uniform(rng, 0.40, 0.50)
    st = uniform(rng, 0.025, 0.035) if material == "plastic" else uniform(rng, 0.03, 0.06)
    top = sh + uniform(rng, 0.35, 0.50)
    parts = []
    seat_col = col
    padded = (material == "metal" and rng.random() < 0.6) or (material == "wooden" and rng.random() < 0.3)
    if padded:
        _, seat_col = material_color(rng, "fabric")
    leg_col = shade(col, 0.75)
    if material == "plastic":
        leg_col = jitter(PALETTE[choice(rng, ("silver", "black", "light oak"))], rng)
    r = uniform(rng, 0.011, 0.016) if material != "wooden" else 0.0
    lt = uniform(rng, 0.03, 0.045)
    ix, iy = w / 2 - 0.025, d / 2 - 0.025
    parts.append(box(w, d, st, 0, 0, sh - st, seat_col))
    table_legs(parts, (-ix, ix), (iy,), 0, sh - st, leg_col, r, lt)
    if material == "plastic":
        back = "moulded"
        table_legs(parts, (-ix, ix), (-iy,), 0, sh - st, leg_col, r, lt)
        parts.append(box(w, 0.025, top - sh + 0.01, 0, -d / 2 + 0.0125, sh - 0.01, col))
    else:
        back = choice(rng, ("slatted", "solid", "padded") if material == "wooden" else ("solid", "padded"))
        table_legs(parts, (-ix, ix), (-iy,), 0, top, leg_col, r, lt)
        inner = 2 * ix - (2 * r if r else lt)
        yb = -iy
        if back == "slatted":
            parts.append(box(inner, 0.02, 0.07, 0, yb, top - 0.08, col))
            n = int(rng.integers(3, 5))
            for i in range(n):
                x = -inner / 2 + inner * (i + 1) / (n + 1)
                parts.append(box(0.025, 0.015, top - 0.08 - sh, x, yb, sh, col))
        else:
            ph = (top - sh) * uniform(rng, 0.45, 0.7)
            pc = seat_col if back == "padded" else col
            parts.append(box(inner, 0.03 if back == "padded" else 0.02, ph, 0, yb, top - ph - 0.01, pc))
    caps = ("a {c} {m} chair", "a {m} dining chair in {c}", "a {c} {m} side chair with a {b} backrest",
            "a {c} chair made of {m} parts with four legs" if material != "wooden" else "a {c} {m} kitchen chair")
    return FurnitureSpec(parts, col, cname, material, caption(rng, caps, c=cname, m=material, b=back), variant=back)


def build_stool(rng):
    material = choice(rng, ("wooden", "metal", "plastic"), (0.5, 0.35, 0.15))
    cname, col = material_color(rng, material)
    kind = choice(rng, ("low", "bar"), (0.5, 0.5))
    H = uniform(rng, 0.42, 0.50) if kind == "low" else uniform(rng, 0.64, 0.80)
    round_seat = rng.random() < 0.7
    rs = uniform(rng, 0.15, 0.20)
    st = uniform(rng, 0.03, 0.05)
    parts = []
    if round_seat:
        parts.append(cylinder(rs, st, 0, 0, H - st, col, 20))
    else:
        parts.append(box(2 * rs * 0.9, 2 * rs * 0.9, st, 0, 0, H - st, col))
    n = int(choice(rng, (3, 4), (0.35, 0.65)))
    leg_col = shade(col, 0.75)
    lr = uniform(rng, 0.012, 0.02)
    splay = uniform(rng, 0.02, 0.06)
    top_r = rs * 0.65
    ang0 = np.pi / 4 if n == 4 else np.pi / 2
    for i in range(n):
        a = ang0 + 2 * np.pi * i / n
        c, s = np.cos(a), np.sin(a)
        parts.append(rod(((top_r + splay) * c, (top_r + splay) * s, lr), (top_r * c, top_r * s, H - st), lr, leg_col, 10))
    if kind == "bar":
        zr = H * 0.35
        rr = top_r + splay * (1 - zr / H)
        parts.append(torus(rr, 0.009, (0, 0, zr), leg_col, "z", 16, 6))
    caps = ("a {c} {m} {k} stool", "a {m} stool in {c}", "a {shape} {c} {m} {k2}")
    return FurnitureSpec(parts, col, cname, material,
                 caption(rng, caps, c=cname, m=material, k="bar" if kind == "bar" else "low",
                         shape="round" if round_seat else "square",
                         k2="bar stool" if kind == "bar" else "footstool"), variant=kind)


def _upholstered(rng, n_seats: int, armchair: bool):
    material = choice(rng, ("fabric", "leather", "velvet"), (0.6, 0.25, 0.15))
    cname, col = material_color(rng, material)
    sw = uniform(rng, 0.52, 0.62) if armchair else uniform(rng, 0.55, 0.68)
    aw = uniform(rng, 0.10, 0.22)
    W = n_seats * sw + 2 * aw
    D = uniform(rng, 0.72, 0.90) if armchair else uniform(rng, 0.80, 0.98)
    has_legs = rng.random() < 0.6
    foot = uniform(rng, 0.06, 0.14) if has_legs else 0.0
    base_top = foot + uniform(rng, 0.16, 0.22)
    cush = uniform(rng, 0.12, 0.17)
    seat_h = base_top + cush
    back_t = uniform(rng, 0.15, 0.24)
    back_top = uniform(rng, 0.75, 0.95) if not armchair else uniform(rng, 0.80, 1.05)
    arm_top = min(uniform(rng, 0.55, 0.68), back_top - 0.08)
    parts = []
    body = shade(col, 0.92)
    parts.append(box(W - 2 * aw + 0.02, D, base_top - foot, 0, 0, foot, body))
    for sx in (-1, 1):
        parts.append(box(aw, D, arm_top - foot, sx * (W / 2 - aw / 2), 0, foot, col))
    parts.append(box(W - 2 * aw + 0.02, back_t, back_top - foot, 0, -D / 2 + back_t / 2, foot, col))
    back_cushions = rng.random() < 0.6
    bc_t = uniform(rng, 0.10, 0.15) if back_cushions else 0.0
    y_seat0 = -D / 2 + back_t
    light = shade(col, 1.07)
    for i in range(n_seats):
        x = -W / 2 + aw + sw * (i + 0.5)
        parts.append(box(sw - 0.012, D - back_t - 0.01, cush, x, (y_seat0 + D / 2 - 0.01) / 2, base_top, light))
        if back_cushions:
            parts.append(box(sw - 0.012, bc_t, back_top - 0.03 - seat_h, x, y_seat0 + bc_t / 2, seat_h, light))
    if has_legs:
        leg_col = jitter(PALETTE[choice(rng, ("dark brown", "walnut brown", "black", "silver", "light oak"))], rng)
        table_legs(parts, (-W / 2 + 0.05, W / 2 - 0.05), (-D / 2 + 0.05, D / 2 - 0.05), 0, foot + 0.001, leg_col,
              round_r=0.02 if rng.random() < 0.5 else 0.0, square=0.04)
    soft = [support_surface(seat_h, -W / 2 + aw, W / 2 - aw, y_seat0 + bc_t, D / 2, back_top - seat_h)]
    if armchair:
        caps = ("a {c} {m} armchair", "a comfortable {m} armchair in {c}", "a {c} {m} lounge chair with armrests")
        variant = "armchair"
    else:
        seats = "two-seat" if n_seats == 2 else "three-seat"
        caps = ("a {c} {m} {s} sofa", "a {s} {m} couch in {c}", "a {c} sofa upholstered in {m} with {n} seats"
                if material != "velvet" else "a {c} {m} sofa with {n} seat cushions")
        variant = seats
    return FurnitureSpec(parts, col, cname, material,
                 caption(rng, caps, c=cname, m=material, s=variant, n="two" if n_seats == 2 else "three"),
                 soft_supports=soft, variant=variant)


def build_sofa(rng):
    return _upholstered(rng, int(choice(rng, (2, 3), (0.45, 0.55))), False)


def build_armchair(rng):
    return _upholstered(rng, 1, True)
