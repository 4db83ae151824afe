"""Electronics (monitor, TV on its stand, keyboard, laptop): the objects with screens or keys."""

from __future__ import annotations

import numpy as np

from openmulti_env.world.furniture.base import (
    MARGIN, FurnitureSpec, carcass_parts, door_rects, front_panels, table_legs, support_surface, uniform,
)
from openmulti_env.world.furniture_parts import (
    PALETTE, SCREEN_BLACK, box, caption, choice, cylinder, jitter, material_color, pick_color, rotate_x,
    shade,
)


def build_monitor(rng):
    material = choice(rng, ("plastic", "metal"), (0.7, 0.3))
    cname, col = pick_color(rng, ("black", "dark grey", "white") if material == "plastic" else ("silver", "dark grey", "black"))
    w = uniform(rng, 0.5, 0.72)
    bezel = uniform(rng, 0.008, 0.02)
    h = w * 9 / 16 + 2 * bezel
    th = uniform(rng, 0.02, 0.03)
    lift = uniform(rng, 0.06, 0.14)
    parts = []
    round_base = rng.random() < 0.4
    if round_base:
        parts.append(cylinder(uniform(rng, 0.09, 0.12), 0.015, 0, 0, 0, shade(col, 0.85), 20))
    else:
        parts.append(box(uniform(rng, 0.18, 0.26), uniform(rng, 0.16, 0.2), 0.015, 0, 0, 0, shade(col, 0.85)))
    parts.append(box(0.045, 0.025, lift + h * 0.5, 0, -0.045, 0.01, shade(col, 0.85)))
    ys = -0.045 + 0.0125 + th / 2
    parts.append(box(w, th, h, 0, ys, lift, col))
    parts.append(box(w * 0.5, 0.03, h * 0.45, 0, ys - th / 2 - 0.01, lift + h * 0.2, shade(col, 0.8)))
    parts.append(box(w - 2 * bezel, 0.002, h - 2 * bezel, 0, ys + th / 2 + 0.001, lift + bezel, SCREEN_BLACK))
    inch = int(round(np.hypot(w, w * 9 / 16) / 0.0254))
    caps = ("a {i}-inch {c} {m} computer monitor", "a {c} {m} monitor on a stand", "a {c} flat {m} computer screen")
    return FurnitureSpec(parts, col, cname, material, caption(rng, caps, c=cname, m=material, i=inch), variant=f"{inch}in")


def build_tv(rng):
    material = choice(rng, ("plastic", "metal"), (0.6, 0.4))
    cname, col = pick_color(rng, ("black", "dark grey", "charcoal") if material == "plastic" else ("black", "silver", "dark grey"))
    sname, scol = material_color(rng, "wooden")
    W, D, H = uniform(rng, 1.2, 2.0), uniform(rng, 0.35, 0.45), uniform(rng, 0.4, 0.6)
    stand = choice(rng, ("closed", "open"))
    parts, supports = [], []
    if stand == "closed":
        sp, z0, z1, (tx0, tx1, ty0, ty1) = carcass_parts(rng, W, D, H, scol, choice(rng, ("legs", "plinth")))
        parts += sp
        n = 2 if W < 1.5 else 3
        front_panels(parts, door_rects(-W / 2 + 0.015, W / 2 - 0.015, z0 + 0.01, z1 - 0.01, n), D / 2, scol,
                      jitter(PALETTE["black"], rng), rng, "bar")
    else:
        t, leg = 0.025, uniform(rng, 0.06, 0.14)
        tx0, tx1, ty0, ty1 = -W / 2, W / 2, -D / 2, D / 2
        table_legs(parts, (-W / 2 + 0.04, W / 2 - 0.04), (-D / 2 + 0.04, D / 2 - 0.04), 0, leg + 0.001, shade(scol, 0.6), 0.0, 0.04)
        parts.append(box(W, D, t, 0, 0, leg, scol))
        parts.append(box(W, D, t, 0, 0, H - t, scol))
        for sx in (-1, 1):
            parts.append(box(t, D, H - leg - 2 * t, sx * (W / 2 - t / 2), 0, leg + t, scol))
        zs = (leg + H) / 2
        parts.append(box(W - 2 * t, D, t, 0, 0, zs - t / 2, scol))
        parts.append(box(W - 2 * t, 0.01, H - leg - 2 * t, 0, -D / 2 + 0.005, leg + t, shade(scol, 0.85)))
        supports.append(support_surface(zs + t / 2, -W / 2 + t, W / 2 - t, -D / 2 + 0.01, D / 2, H - t - zs - t / 2))
        supports.append(support_surface(leg + t, -W / 2 + t, W / 2 - t, -D / 2 + 0.01, D / 2, zs - t / 2 - leg - t))
    diag = uniform(rng, 40, 65) * 0.0254
    sw = min(diag * 16 / np.hypot(16, 9), W - 0.12)
    sh = sw * 9 / 16 + 0.02
    st = uniform(rng, 0.035, 0.06)
    yb = ty0 + 0.13
    lift = uniform(rng, 0.05, 0.1)
    parts.append(box(uniform(rng, 0.25, 0.4), 0.2, 0.012, 0, yb, H, shade(col, 0.8)))
    parts.append(box(0.06, 0.03, lift + sh * 0.3, 0, yb - st / 2 - 0.015, H + 0.01, shade(col, 0.8)))
    parts.append(box(sw, st, sh, 0, yb, H + lift, col))
    parts.append(box(sw - 0.02, 0.002, sh - 0.02, 0, yb + st / 2 + 0.001, H + lift + 0.01, SCREEN_BLACK))
    front_y0 = yb + 0.1 + 0.005 + MARGIN
    supports.append(support_surface(H, tx0, tx1, front_y0 - MARGIN, ty1))
    if tx1 - (sw / 2 + 0.005) >= 2 * MARGIN + 0.08:
        for sx in (-1, 1):
            x0, x1 = sorted((sx * (sw / 2 + 0.005), sx * tx1))
            supports.append(support_surface(H, x0, x1, ty0, front_y0 - MARGIN, 1.0))
    inch = int(round(diag / 0.0254))
    caps = ("a {i}-inch {c} {m} flat-screen TV on a {s} wooden stand", "a {c} {m} television on a {s} TV stand",
            "a {c} {m} TV screen standing on a {s} wooden media console")
    return FurnitureSpec(parts, col, cname, material, caption(rng, caps, c=cname, m=material, s=sname, i=inch),
                 supports=supports, variant=f"{inch}in-{stand}")


def build_keyboard(rng):
    material = choice(rng, ("plastic", "metal"), (0.75, 0.25))
    cname, col = pick_color(rng, ("black", "white", "dark grey", "light grey") if material == "plastic" else ("silver", "dark grey"))
    W, D, h = uniform(rng, 0.35, 0.45), uniform(rng, 0.12, 0.15), uniform(rng, 0.015, 0.025)
    parts = [box(W, D, h, 0, 0, 0, col)]
    kcol = jitter(PALETTE[choice(rng, ("black", "dark grey", "white", "light grey"))], rng)
    rows, ncol = 5, 14
    pitch = min((W - 0.03) / ncol, (D - 0.025) / rows)
    ks = pitch * 0.82
    x0, y0 = -pitch * ncol / 2, -pitch * rows / 2
    for r in range(rows):
        y = y0 + pitch * (r + 0.5)
        if r == rows - 1:  # space-bar row nearest the user (+y)
            parts.append(box(ks, ks, 0.008, x0 + pitch * 1.5, y, h, kcol))
            parts.append(box(pitch * 6 - (pitch - ks), ks, 0.008, x0 + pitch * 7, y, h, kcol))
            parts.append(box(ks, ks, 0.008, x0 + pitch * 12.5, y, h, kcol))
            continue
        for c in range(ncol):
            parts.append(box(ks, ks, 0.008, x0 + pitch * (c + 0.5), y, h, kcol))
    caps = ("a {c} {m} computer keyboard", "a {c} {m} keyboard", "a slim {m} typing keyboard in {c}")
    return FurnitureSpec(parts, col, cname, material, caption(rng, caps, c=cname, m=material))


def build_laptop(rng):
    material = choice(rng, ("metal", "plastic"), (0.6, 0.4))
    cname, col = pick_color(rng, ("silver", "dark grey", "gold") if material == "metal" else ("black", "white", "dark grey"))
    W, D, bt = uniform(rng, 0.3, 0.38), uniform(rng, 0.21, 0.25), uniform(rng, 0.013, 0.02)
    lt = uniform(rng, 0.005, 0.008)
    parts = [box(W, D, bt, 0, 0, 0, col)]
    parts.append(box(W - 0.03, D * 0.45, 0.001, 0, -D / 2 + 0.02 + D * 0.225, bt, SCREEN_BLACK))
    parts.append(box(W * 0.32, D * 0.28, 0.001, 0, D / 2 - 0.012 - D * 0.14, bt, shade(col, 0.85)))
    angle = np.deg2rad(uniform(rng, 100, 120))
    lid = box(W, D, lt, 0, 0, bt, shade(col, 0.95))
    disp = box(W - 0.02, D - 0.025, 0.001, 0, 0.002, bt - 0.001, SCREEN_BLACK)  # under the closed lid
    pivot = (0, -D / 2, bt)
    # the closed lid spans y in [-D/2, D/2] above the base; swing it open around the rear hinge so the
    # display (its underside) ends up facing +y
    parts.append(rotate_x(lid, angle, pivot))
    parts.append(rotate_x(disp, angle, pivot))
    caps = ("an open {c} {m} laptop", "a {c} {m} notebook computer", "a {c} laptop with a {m} case, lid open")
    return FurnitureSpec(parts, col, cname, material, caption(rng, caps, c=cname, m=material))
