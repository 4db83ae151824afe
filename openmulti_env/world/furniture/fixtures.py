"""Fixtures (rug, door, window frame, picture): flat items laid on the floor or hung on a wall."""

from __future__ import annotations

from openmulti_env.world.furniture.base import FurnitureSpec, uniform
from openmulti_env.world.furniture_parts import (
    FOLIAGE, PALETTE, box, caption, choice, jitter, material_color, pick_color, rod, shade,
)


def build_rug(rng):
    material = choice(rng, ("wool", "fabric", "jute"), (0.5, 0.3, 0.2))
    cname, col = material_color(rng, material)
    W, L, h = uniform(rng, 1.2, 3.0), uniform(rng, 0.8, 2.2), 0.01
    style = choice(rng, ("plain", "bordered", "striped"), (0.3, 0.4, 0.3))
    parts = []
    _, acc = pick_color(rng, ("cream", "beige", "navy blue", "dark red", "charcoal", "white", "mustard yellow", "teal"))
    if style == "plain":
        parts.append(box(W, L, h, 0, 0, 0, col))
    elif style == "bordered":
        b = uniform(rng, 0.06, 0.15)
        parts.append(box(W - 2 * b, L - 2 * b, h, 0, 0, 0, col))
        parts.append(box(W, b, h, 0, L / 2 - b / 2, 0, acc))
        parts.append(box(W, b, h, 0, -L / 2 + b / 2, 0, acc))
        parts.append(box(b, L - 2 * b, h, W / 2 - b / 2, 0, 0, acc))
        parts.append(box(b, L - 2 * b, h, -W / 2 + b / 2, 0, 0, acc))
    else:
        n = int(rng.integers(5, 12))
        for i in range(n):
            parts.append(box(W / n, L, h, -W / 2 + W * (i + 0.5) / n, 0, 0, col if i % 2 == 0 else acc))
    size = "large" if W * L > 3.0 else "small"
    caps = ("a {sz} {c} {m} rug", "a {c} {m} area rug{st}", "a {st2}{c} {m} carpet on the floor")
    st = {"plain": "", "bordered": " with a border", "striped": " with stripes"}[style]
    return FurnitureSpec(parts, col, cname, material,
                 caption(rng, caps, c=cname, m=material, sz=size, st=st, st2="striped " if style == "striped" else ""),
                 variant=style)


def build_door(rng):
    material = choice(rng, ("wooden", "metal"), (0.85, 0.15))
    cname, col = material_color(rng, material)
    W, H, t = uniform(rng, 0.8, 0.95), uniform(rng, 1.98, 2.1), 0.04
    cw, cd = uniform(rng, 0.06, 0.1), t + 0.012
    ccol = shade(col, 0.9) if rng.random() < 0.5 else jitter(PALETTE["white"], rng, 0.02)
    y0 = 0.0  # back plane (touches the wall)
    parts = [box(W, t, H, 0, y0 + t / 2, 0, col)]
    parts.append(box(cw, cd, H + cw, -W / 2 - cw / 2, y0 + cd / 2, 0, ccol))
    parts.append(box(cw, cd, H + cw, W / 2 + cw / 2, y0 + cd / 2, 0, ccol))
    parts.append(box(W, cd, cw, 0, y0 + cd / 2, H, ccol))
    style = choice(rng, ("panelled", "flush"), (0.55, 0.45))
    if style == "panelled":
        rows = int(rng.integers(2, 4))
        mx, mz = 0.12, 0.12
        ph = (H - 2 * mz - (rows - 1) * 0.1) / rows
        for c in (0, 1):
            for r_ in range(rows):
                pw = (W - 2 * mx - 0.1) / 2
                x = -W / 2 + mx + pw / 2 + c * (pw + 0.1)
                parts.append(box(pw, 0.006, ph, x, y0 + t + 0.003, mz + r_ * (ph + 0.1), shade(col, 0.93)))
    hcol = jitter(PALETTE[choice(rng, ("silver", "gold", "black"))], rng)
    hx, hz = W / 2 - 0.07, 1.0
    parts.append(rod((hx, y0 + t - 0.001, hz), (hx, y0 + t + 0.012, hz), 0.027, hcol, 12))  # rosette
    parts.append(box(0.12, 0.015, 0.018, hx - 0.05, y0 + t + 0.045, hz - 0.009, hcol))
    parts.append(rod((hx, y0 + t + 0.01, hz), (hx, y0 + t + 0.053, hz), 0.009, hcol, 8))
    caps = ("a {c} {m} door", "a {st} {m} interior door in {c}",
            "a {c} {m} door with a {h} handle")
    hname = "silver" if hcol[2] > 0.5 and hcol[0] > 0.5 else ("gold" if hcol[0] > 0.5 else "black")
    return FurnitureSpec(parts, col, cname, material, caption(rng, caps, c=cname, m=material, st=style, h=hname),
                 mount_height_m=0.0, variant=style)


def build_window_frame(rng):
    material = choice(rng, ("wooden", "plastic", "metal"), (0.4, 0.35, 0.25))
    if material == "plastic":
        cname, col = pick_color(rng, ("white", "off-white", "dark grey"))
    else:
        cname, col = material_color(rng, material)
    W, H = uniform(rng, 0.8, 1.6), uniform(rng, 0.9, 1.4)
    fb, fd = uniform(rng, 0.05, 0.08), uniform(rng, 0.06, 0.1)
    sill_t, sill_d = 0.03, fd + uniform(rng, 0.04, 0.09)
    parts = [box(W + 0.1, sill_d, sill_t, 0, sill_d / 2, 0, shade(col, 0.95))]
    z0 = sill_t
    parts.append(box(W, fd, fb, 0, fd / 2, z0, col))
    parts.append(box(W, fd, fb, 0, fd / 2, z0 + H - fb, col))
    parts.append(box(fb, fd, H - 2 * fb, -W / 2 + fb / 2, fd / 2, z0 + fb, col))
    parts.append(box(fb, fd, H - 2 * fb, W / 2 - fb / 2, fd / 2, z0 + fb, col))
    n_v = 1 if W < 1.0 else int(rng.integers(1, 3))
    transom = rng.random() < 0.4
    mb = fb * 0.7
    for i in range(1, n_v + 1):
        x = -W / 2 + W * i / (n_v + 1)
        parts.append(box(mb, fd * 0.8, H - 2 * fb, x, fd * 0.4, z0 + fb, col))
    if transom:
        zt = z0 + H * 0.7
        parts.append(box(W - 2 * fb, fd * 0.8, mb, 0, fd * 0.4, zt, col))
    glass = jitter((0.70, 0.82, 0.90), rng, 0.02)
    parts.append(box(W - 2 * fb + 0.01, 0.006, H - 2 * fb + 0.01, 0, fd * 0.3, z0 + fb - 0.005, glass))
    panes = (n_v + 1) * (2 if transom else 1)
    caps = ("a {c} {m} window frame", "a window with a {c} {m} frame", "a {c} {m} {p}-pane window")
    return FurnitureSpec(parts, col, cname, material, caption(rng, caps, c=cname, m=material, p=panes),
                 mount_height_m=uniform(rng, 0.8, 1.0), variant=f"{panes}-pane")


def build_picture(rng):
    material = choice(rng, ("wooden", "metal"), (0.7, 0.3))
    cname, col = material_color(rng, material) if material == "wooden" else pick_color(rng, ("black", "silver", "gold", "white"))
    W, H = uniform(rng, 0.3, 1.0), uniform(rng, 0.3, 0.9)
    fb, fd = uniform(rng, 0.02, 0.06), uniform(rng, 0.02, 0.04)
    parts = [box(W, fd, fb, 0, fd / 2, 0, col), box(W, fd, fb, 0, fd / 2, H - fb, col),
             box(fb, fd, H - 2 * fb, -W / 2 + fb / 2, fd / 2, fb, col),
             box(fb, fd, H - 2 * fb, W / 2 - fb / 2, fd / 2, fb, col)]
    cd = fd * 0.6
    mat_w = uniform(rng, 0.03, 0.08) if rng.random() < 0.5 else 0.0
    parts.append(box(W - 2 * fb + 0.004, cd, H - 2 * fb + 0.004, 0, cd / 2, fb - 0.002, jitter(PALETTE["off-white"], rng, 0.02)))
    ix0, ix1 = -W / 2 + fb + mat_w, W / 2 - fb - mat_w
    iz0, iz1 = fb + mat_w, H - fb - mat_w
    art = choice(rng, ("landscape", "abstract"))
    yc = cd + 0.001
    if art == "landscape":
        zh = iz0 + (iz1 - iz0) * uniform(rng, 0.3, 0.55)
        parts.append(box(ix1 - ix0, 0.002, iz1 - zh, (ix0 + ix1) / 2, yc, zh, jitter((0.55, 0.72, 0.88), rng, 0.05)))
        parts.append(box(ix1 - ix0, 0.002, zh - iz0, (ix0 + ix1) / 2, yc, iz0, jitter(FOLIAGE[int(rng.integers(4))], rng, 0.08)))
        sr = min(ix1 - ix0, iz1 - zh) * 0.12
        sx = uniform(rng, ix0 + 2 * sr, ix1 - 2 * sr)
        parts.append(rod((sx, yc + 0.001, zh + (iz1 - zh) * 0.65), (sx, yc + 0.003, zh + (iz1 - zh) * 0.65), sr,
                         jitter(PALETTE["yellow"], rng), 12))
    else:
        parts.append(box(ix1 - ix0, 0.002, iz1 - iz0, (ix0 + ix1) / 2, yc, iz0, jitter(PALETTE[choice(rng, ("cream", "white", "beige", "light grey"))], rng)))
        for k in range(int(rng.integers(2, 5))):
            bw, bh = (ix1 - ix0) * uniform(rng, 0.15, 0.5), (iz1 - iz0) * uniform(rng, 0.15, 0.5)
            x = uniform(rng, ix0 + bw / 2, ix1 - bw / 2)
            z = uniform(rng, iz0, iz1 - bh)
            c = PALETTE[choice(rng, ("red", "blue", "yellow", "teal", "orange", "black", "navy blue", "pink"))]
            parts.append(box(bw, 0.002, bh, x, yc + 0.0015 * (k + 1), z, jitter(c, rng)))
    centre = uniform(rng, 1.45, 1.65)
    caps = ("a framed {a} picture with a {c} {m} frame", "a {a} painting in a {c} {m} frame",
            "a {c} {m} picture frame holding {aa} {a} print")
    return FurnitureSpec(parts, col, cname, material,
                 caption(rng, caps, c=cname, m=material, a=art, aa="a" if art == "landscape" else "an"),
                 mount_height_m=max(0.9, centre - H / 2), variant=art)
