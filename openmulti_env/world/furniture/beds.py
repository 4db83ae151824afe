"""Beds (single to king-size): frame, headboard, mattress, duvet; alone as the one with bedding."""

from __future__ import annotations

from openmulti_env.world.furniture.base import FurnitureSpec, table_legs, support_surface, uniform
from openmulti_env.world.furniture_parts import (
    PALETTE, box, caption, choice, cylinder, hbar, jitter, material_color, shade,
)


def build_bed(rng):
    kind = choice(rng, ("single", "double", "queen-size", "king-size"), (0.25, 0.35, 0.25, 0.15))
    mw = {"single": (0.9, 1.0), "double": (1.35, 1.45), "queen-size": (1.5, 1.6), "king-size": (1.8, 1.95)}[kind]
    mw = uniform(rng, *mw)
    ml, mt = uniform(rng, 1.95, 2.05), uniform(rng, 0.18, 0.28)
    material = choice(rng, ("wooden", "fabric", "metal"), (0.55, 0.3, 0.15))
    cname, col = material_color(rng, material)
    rail = uniform(rng, 0.03, 0.06)
    hb_t = uniform(rng, 0.05, 0.1) if material != "metal" else 0.04
    fw, fl = mw + 2 * rail, ml + rail + hb_t
    leg_h = uniform(rng, 0.05, 0.15)
    frame_top = uniform(rng, 0.25, 0.38)
    parts = [box(fw, fl - hb_t, frame_top - leg_h, 0, hb_t / 2, leg_h, shade(col, 0.95))]
    table_legs(parts, (-fw / 2 + 0.04, fw / 2 - 0.04), (fl / 2 - 0.04, -fl / 2 + hb_t + 0.04), 0, leg_h + 0.001,
          shade(col, 0.7), 0.0, 0.05)
    hb_top = uniform(rng, 0.9, 1.3)
    yh = -fl / 2 + hb_t / 2
    if material == "metal":
        for sx in (-1, 1):
            parts.append(cylinder(0.02, hb_top, sx * (fw / 2 - 0.02), yh, 0, col, 12))
        for zz in (hb_top - 0.05, frame_top + 0.05):
            parts.append(hbar(fw - 0.04, 0.015, 0, yh, zz, col))
        nb = int(rng.integers(4, 8))
        for i in range(nb):
            x = -fw / 2 + 0.02 + (fw - 0.04) * (i + 1) / (nb + 1)
            parts.append(cylinder(0.008, hb_top - frame_top - 0.1, x, yh, frame_top + 0.05, col, 8))
    else:
        parts.append(box(fw, hb_t, hb_top, 0, yh, 0, col))
    foot_board = material == "wooden" and rng.random() < 0.4
    if foot_board:
        parts.append(box(fw, 0.04, frame_top + uniform(rng, 0.1, 0.25), 0, fl / 2 - 0.02, 0, col))
    mz0 = frame_top - uniform(rng, 0.0, 0.05)
    m_top = mz0 + mt
    my0 = -fl / 2 + hb_t
    my1 = fl / 2 - (0.04 if foot_board else rail)
    parts.append(box(mw, my1 - my0, mt, 0, (my0 + my1) / 2, mz0, jitter(PALETTE["white"], rng, 0.02)))
    bname, bcol = material_color(rng, choice(rng, ("cotton", "fabric", "linen")))
    dy0 = my0 + uniform(rng, 0.55, 0.65)
    dy1 = my1 + (0.0 if foot_board else 0.03)
    dz0 = max(m_top - 0.2, leg_h + 0.05)
    parts.append(box(mw + 0.06, dy1 - dy0, m_top + 0.04 - dz0, 0, (dy0 + dy1) / 2, dz0, bcol))
    parts.append(box(mw + 0.07, 0.18, 0.012, 0, dy0 + 0.09, m_top + 0.04, jitter(PALETTE["white"], rng, 0.02)))
    soft = [support_surface(m_top, -mw / 2, mw / 2, my0, dy0, 1.0)]
    caps = ("a {k} bed with a {c} {m} frame", "a {c} {m} {k} bed with {b} bedding",
            "a {k} bed, {c} {m} headboard and {b} duvet")
    return FurnitureSpec(parts, col, cname, material, caption(rng, caps, c=cname, m=material, k=kind, b=bname),
                 soft_supports=soft, variant=kind)
