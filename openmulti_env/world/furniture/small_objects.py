"""Small objects (mug, bottle, book, pillow, vase, trash bin, box): single lathed or boxed items."""

from __future__ import annotations

import numpy as np

from openmulti_env.world.furniture.base import FurnitureSpec, uniform
from openmulti_env.world.furniture_parts import (
    PALETTE, box, caption, choice, cylinder, frustum, jitter, lathe, material_color, pick_color, rod,
    rounded_box, shade, sphere, torus,
)


def build_mug(rng):
    material = choice(rng, ("ceramic", "glass", "metal"), (0.8, 0.1, 0.1))
    cname, col = material_color(rng, material) if material != "metal" else pick_color(rng, ("white", "silver", "blue", "red"))
    r, h, wall = uniform(rng, 0.035, 0.048), uniform(rng, 0.08, 0.11), 0.005
    parts = [lathe([(r * 0.92, 0), (r, 0.006), (r, h), (r - wall, h), (r - wall, 0.012), (0, 0.012)], color=col, sections=20)]
    if rng.random() < 0.5:
        parts.append(cylinder(r - wall - 0.0005, h * uniform(rng, 0.6, 0.8), 0, 0, 0.011, jitter((0.22, 0.12, 0.06), rng), 20))
    R, rr = uniform(rng, 0.022, 0.03), uniform(rng, 0.005, 0.007)
    parts.append(torus(R, rr, (r - wall + rr + R, 0, h * 0.55), shade(col, 0.92), "y", 16, 8))
    small = "small" if r * h < 0.0038 else "large"
    caps = ("a {s} {c} {m} mug", "a {c} {m} coffee mug", "a {c} {m} cup with a handle")
    return FurnitureSpec(parts, col, cname, material, caption(rng, caps, c=cname, m=material, s=small))


def build_bottle(rng):
    material = choice(rng, ("glass", "plastic"), (0.6, 0.4))
    cname, col = material_color(rng, "glass") if material == "glass" else pick_color(rng, ("clear", "blue", "light blue", "white", "green"))
    kind = choice(rng, ("wine", "water"), (0.5, 0.5) if material == "glass" else (0.1, 0.9))
    r = uniform(rng, 0.035, 0.045) if kind == "wine" else uniform(rng, 0.03, 0.04)
    bh = uniform(rng, 0.17, 0.22) if kind == "wine" else uniform(rng, 0.12, 0.2)
    rn, nh = uniform(rng, 0.011, 0.015), uniform(rng, 0.06, 0.09) if kind == "wine" else uniform(rng, 0.02, 0.04)
    sh = 0.06 if kind == "wine" else 0.035
    prof = [(r * 0.95, 0), (r, 0.005), (r, bh), (rn, bh + sh), (rn, bh + sh + nh), (rn * 1.12, bh + sh + nh), (rn * 1.12, bh + sh + nh + 0.004)]
    parts = [lathe(prof, color=col, sections=18)]
    top = bh + sh + nh + 0.004
    ccol = jitter(PALETTE[choice(rng, ("black", "white", "gold", "red", "blue", "silver"))], rng)
    parts.append(cylinder(rn * 1.18, uniform(rng, 0.015, 0.03), 0, 0, top - 0.006, ccol, 16))
    if rng.random() < 0.6:
        parts.append(cylinder(r + 0.0008, bh * 0.45, 0, 0, bh * 0.3, jitter(PALETTE[choice(rng, ("white", "cream", "gold", "black"))], rng), 18))
    caps = ("a {c} {m} {k} bottle", "a {k} bottle made of {c} {m}", "a {c} {m} bottle with a cap")
    return FurnitureSpec(parts, col, cname, material, caption(rng, caps, c=cname, m=material, k=kind), variant=kind)


def build_book(rng):
    material = "paper"
    cname, col = material_color(rng, "paper", 0.05)
    T, D, H = uniform(rng, 0.015, 0.06), uniform(rng, 0.13, 0.22), uniform(rng, 0.18, 0.30)
    c = 0.003
    page = jitter(PALETTE["cream"], rng, 0.03)
    parts = [box(c, D, H, -T / 2 + c / 2, 0, 0, col), box(c, D, H, T / 2 - c / 2, 0, 0, col),
             box(T, c + 0.001, H, 0, D / 2 - (c + 0.001) / 2, 0, shade(col, 0.9)),
             box(T - 2 * c + 0.001, D - 0.008, H - 0.008, 0, -0.004 + 0.0005, 0.004, page)]
    bands = int(rng.integers(0, 3))
    bcol = jitter(PALETTE[choice(rng, ("gold", "white", "black", "silver"))], rng)
    for i in range(bands):
        parts.append(box(T * 0.9, 0.002, 0.012, 0, D / 2 + 0.001, H * (0.12 + 0.7 * i), bcol))
    thick = "thick" if T > 0.04 else "thin"
    caps = ("a {t} {c} hardcover book with {m} pages", "a {c} {m} book standing upright",
            "a {c} book bound in {c} cloth with {m} pages")
    return FurnitureSpec(parts, col, cname, material, caption(rng, caps, c=cname, m=material, t=thick), variant=thick)


def build_pillow(rng):
    material = choice(rng, ("fabric", "velvet", "cotton", "linen"))
    cname, col = material_color(rng, material)
    if rng.random() < 0.5:
        sx = sy = uniform(rng, 0.38, 0.5)
        noun = "cushion"
    else:
        sx, sy = uniform(rng, 0.5, 0.7), uniform(rng, 0.32, 0.48)
        noun = "pillow"
    sz = uniform(rng, 0.1, 0.18)
    parts = [rounded_box(sx, sy, sz, color=col, squareness=0.3, puff=0.55)]
    caps = ("a soft {c} {m} {n}", "a {c} {n} made of {m}", "a {c} {m} throw {n}")
    return FurnitureSpec(parts, col, cname, material, caption(rng, caps, c=cname, m=material, n=noun), variant=noun)


def build_vase(rng):
    material = choice(rng, ("ceramic", "glass"), (0.7, 0.3))
    cname, col = material_color(rng, material)
    r, h, w = uniform(rng, 0.04, 0.09), uniform(rng, 0.15, 0.4), 0.005
    shape = choice(rng, ("round", "tall", "bottle"))
    if shape == "round":
        outer = [(r * 0.6, 0), (r, h * 0.35), (r * 0.85, h * 0.75), (r * 0.45, h * 0.92), (r * 0.55, h)]
    elif shape == "tall":
        outer = [(r * 0.7, 0), (r * 0.8, h * 0.2), (r * 0.75, h * 0.8), (r * 0.9, h)]
    else:
        outer = [(r * 0.7, 0), (r, h * 0.3), (r * 0.9, h * 0.55), (r * 0.3, h * 0.75), (r * 0.28, h * 0.95), (r * 0.4, h)]
    inner = [(max(p[0] - w, 0.004), max(p[1], 0.012)) for p in outer[::-1]]
    parts = [lathe(outer + inner + [(0, 0.012)], color=col, sections=18)]
    flowers = rng.random() < 0.35
    if flowers:
        top = outer[-1][0]
        for i in range(int(rng.integers(3, 6))):
            a = 2 * np.pi * i / 5 + uniform(rng, 0, 0.5)
            tip = (np.cos(a) * top * 1.6, np.sin(a) * top * 1.6, h + uniform(rng, 0.08, 0.2))
            parts.append(rod((0, 0, h * 0.5), tip, 0.003, jitter((0.2, 0.45, 0.15), rng), 6))
            fc = PALETTE[choice(rng, ("red", "yellow", "white", "pink", "purple", "orange"))]
            parts.append(sphere(uniform(rng, 0.015, 0.03), *tip, jitter(fc, rng), 1))
    caps = ("a {s}{c} {m} vase", "a {c} {m} flower vase{f}", "a decorative {m} vase in {c}")
    return FurnitureSpec(parts, col, cname, material,
                 caption(rng, caps, c=cname, m=material, s={"round": "round ", "tall": "tall ", "bottle": "bottle-shaped "}[shape], f=" with flowers" if flowers else ""), variant=shape)


def build_trash_bin(rng):
    material = choice(rng, ("plastic", "metal"), (0.55, 0.45))
    cname, col = material_color(rng, material)
    r, h = uniform(rng, 0.12, 0.2), uniform(rng, 0.3, 0.6)
    rt = r * uniform(rng, 1.0, 1.2)
    parts = []
    lid = rng.random() < 0.4
    if lid:
        parts.append(frustum(r, rt, h - 0.03, color=col, sections=20))
        parts.append(cylinder(rt + 0.005, 0.03, 0, 0, h - 0.03, shade(col, 0.85), 20))
        parts.append(box(0.1, 0.06, 0.015, 0, r + 0.02, 0.0, shade(col, 0.6)))
    else:
        w = 0.006
        parts.append(lathe([(r, 0), (rt, h), (rt - w, h), (r - w, 0.01), (0, 0.01)], color=col, sections=20))
        parts.append(torus(rt - w / 2, 0.006, (0, 0, h - 0.004), shade(col, 0.85), "z", 20, 6))
    caps = ("a {c} {m} trash bin", "a {c} {m} waste basket", "a {c} {m} garbage can{l}")
    return FurnitureSpec(parts, col, cname, material,
                 caption(rng, caps, c=cname, m=material, l=" with a lid" if lid else ""), variant="lid" if lid else "open")


def build_box(rng):
    material = choice(rng, ("cardboard", "plastic"), (0.7, 0.3))
    cname, col = material_color(rng, material)
    W, D, H = uniform(rng, 0.3, 0.6), uniform(rng, 0.25, 0.45), uniform(rng, 0.2, 0.45)
    parts = []
    if material == "cardboard":
        parts.append(box(W, D, H, 0, 0, 0, col))
        tape = jitter(PALETTE[choice(rng, ("tan", "beige", "brown"))], rng)
        parts.append(box(0.05, D + 0.002, 0.001, 0, 0, H + 0.0005, shade(tape, 1.15)))
        parts.append(box(0.05, 0.001, 0.06, 0, D / 2 + 0.0005, H - 0.06, shade(tape, 1.15)))
        parts.append(box(0.05, 0.001, 0.06, 0, -D / 2 - 0.0005, H - 0.06, shade(tape, 1.15)))
        noun = "cardboard box"
    else:
        parts.append(box(W * 0.97, D * 0.97, H - 0.03, 0, 0, 0, col))
        lcol = shade(col, 0.8) if rng.random() < 0.5 else jitter(PALETTE["white"], rng)
        parts.append(box(W, D, 0.035, 0, 0, H - 0.035, lcol))
        for sx in (-1, 1):
            parts.append(box(0.02, D * 0.3, 0.025, sx * (W * 0.485 + 0.008), 0, H - 0.09, shade(col, 0.8)))
        noun = "storage box"
    caps = ("a {c} {m} {n}", "a {c} {n} made of {m}", "a closed {c} {m} {n} on the floor") if material == "plastic" \
        else ("a {c} {m} box", "a closed {c} {m} box taped shut", "a {c} {m} moving box on the floor")
    return FurnitureSpec(parts, col, cname, material, caption(rng, caps, c=cname, m=material, n=noun),
                 variant="cardboard" if material == "cardboard" else "storage")
