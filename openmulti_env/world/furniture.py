"""Parametric furniture library for procedural indoor scenes.

``build_furniture(category, rng)`` returns a :class:`FurnitureModel` in its LOCAL frame:

* metres, z up; origin at the centre of the footprint's bounding box on the floor
  (``z = 0`` is the object's bottom, the x/y bounding box is centred on 0);
* the object's front faces +y (sofa seat opens to +y, screens face +y, bookshelf shelves
  open to +y, cabinet doors/handles on the +y face, bed headboard at -y);
* ``mesh`` is the concatenation of ``parts`` (all closed primitives) with per-face colours.

Placement conventions (``FurnitureModel.placement``):

* ``"floor"``        stands anywhere on the floor (chair, table, sofa...);
* ``"wall"``         stands on the floor with its back (-y side) against a wall
                     (bookshelf, cabinet, wardrobe, desk, bed, nightstand, sofa);
* ``"wall_mounted"`` a flat object hung on a wall (door, window_frame, picture).  Its back is at
                     local ``y = -size_y / 2``: put that plane on the wall surface with +y pointing
                     into the room and lift the object by ``mount_height_m`` (height of the
                     object's bottom above the floor: 0 for doors, ~0.8-1.0 for windows,
                     ~1.0-1.45 for pictures, whose centre is then at ~1.45-1.65);
* ``"on_surface"``   small objects (``is_small``) to put on a :class:`SupportSurface`.

Lamps and plants exist in two categories: ``"lamp"`` / ``"plant"`` are floor-standing,
``"table_lamp"`` / ``"potted_plant"`` are small ``on_surface`` objects.  ``"tv"`` is a flat
screen standing on a low TV stand (one object, placement "floor" as specified by the lead; its
supports are the free parts of the stand top and the open stand shelf if any).  Books stand
upright with the spine to +y (as on a shelf); pillows lie flat.  Beds do not contain pillows:
``soft_supports`` gives the free mattress area at the head end (and the seat of sofas and
armchairs) for placing ``pillow`` objects; ordinary ``supports`` never include soft surfaces.

``size_scale`` scales the finished object uniformly about its origin (supports too, but not
``mount_height_m``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import trimesh

from .furniture_parts import (
    FOLIAGE, PALETTE, SCREEN_BLACK, box, box_between, capsule, caption, choice, concat,
    cylinder, frustum, hbar, jitter, lathe, material_color, pick_color, rod, rotate_x, rounded_box,
    shade, sphere, torus,
)

MARGIN = 0.03  # support rectangles are this much smaller than the physical surface


@dataclass
class SupportSurface:
    """A horizontal rectangle where small objects can rest (table top, shelf board)."""
    height_m: float            # z of the surface in the local frame
    half_extent_xy: tuple[float, float]   # rectangle half sizes, centred at center_xy
    center_xy: tuple[float, float] = (0.0, 0.0)
    clearance_m: float = 1.0   # free height above it (shelf spacing), so objects placed there fit


@dataclass
class FurnitureModel:
    category: str
    mesh: trimesh.Trimesh
    parts: list[trimesh.Trimesh]
    color: tuple[float, float, float]
    color_name: str
    material: str
    caption: str
    size_m: tuple[float, float, float]
    supports: list[SupportSurface]
    placement: str
    is_small: bool
    mount_height_m: float = 0.0          # wall_mounted: height of the object's bottom above floor
    soft_supports: list[SupportSurface] = field(default_factory=list)  # mattress / seat for pillows
    variant: str = ""                    # free-form sub-type, e.g. "three-seat", "round", "bar"


@dataclass
class _Spec:
    parts: list
    color: tuple
    color_name: str
    material: str
    caption: str
    supports: list = field(default_factory=list)
    soft_supports: list = field(default_factory=list)
    mount_height_m: float = 0.0
    variant: str = ""


def _u(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(rng.uniform(lo, hi))


def _surface(z: float, x0: float, x1: float, y0: float, y1: float, clearance: float = 1.0,
             margin: float = MARGIN) -> SupportSurface:
    """Support for the physical rectangle [x0,x1]x[y0,y1] at height z, shrunk by ``margin``."""
    return SupportSurface(float(z), (float((x1 - x0) / 2 - margin), float((y1 - y0) / 2 - margin)),
                          (float((x0 + x1) / 2), float((y0 + y1) / 2)), float(clearance))


def _front_panels(parts: list, rects, y_front: float, color, handle_color, rng,
                  handle: str = "bar", gap: float = 0.004) -> None:
    """Doors/drawer fronts on the +y face at ``y_front``: a dark seam backing plus one slightly
    proud panel per rect ``(x0, x1, z0, z1, kind)`` with kind 'drawer', 'door_l' (hinge left,
    handle right), 'door_r' or 'none'."""
    xs0 = min(r[0] for r in rects); xs1 = max(r[1] for r in rects)
    zs0 = min(r[2] for r in rects); zs1 = max(r[3] for r in rects)
    parts.append(box_between((xs0, y_front, zs0), (xs1, y_front + 0.002, zs1), shade(color, 0.35)))
    yp = y_front + 0.002
    for x0, x1, z0, z1, kind in rects:
        parts.append(box_between((x0 + gap / 2, yp, z0 + gap / 2), (x1 - gap / 2, yp + 0.014, z1 - gap / 2), color))
        if kind == "none":
            continue
        yh = yp + 0.014
        w, h = x1 - x0, z1 - z0
        if handle == "knob":
            if kind == "drawer":
                hx, hz = (x0 + x1) / 2, z0 + h * 0.6
            else:
                hx = x1 - 0.05 if kind == "door_l" else x0 + 0.05
                hz = z0 + h * (0.5 if h < 0.9 else 0.45)
            parts.append(rod((hx, yh - 0.001, hz), (hx, yh + 0.022, hz), 0.012, handle_color, 10))
        elif kind == "drawer":
            L = min(0.16, w * 0.45)
            parts.append(box((L), 0.02, 0.012, (x0 + x1) / 2, yh + 0.01, z0 + h * 0.62 - 0.006, handle_color))
        else:
            L = min(0.3, h * 0.35)
            hx = x1 - 0.04 if kind == "door_l" else x0 + 0.04
            hz = z0 + min(h * 0.5, 1.05 - z0 if z0 < 1.0 else h * 0.5)
            hz = float(np.clip(hz, z0 + L / 2 + 0.02, z1 - L / 2 - 0.02))
            parts.append(box(0.012, 0.02, L, hx, yh + 0.01, hz - L / 2, handle_color))


def _door_rects(x0, x1, z0, z1, n):
    w = (x1 - x0) / n
    rects = []
    for i in range(n):
        kind = "door_r" if (n > 1 and i == n - 1) or (n == 3 and i == 1) else "door_l"
        if n == 1:
            kind = "door_l"
        rects.append((x0 + i * w, x0 + (i + 1) * w, z0, z1, kind))
    return rects


def _legs(parts, xs, ys, z0, z1, color, round_r: float = 0.0, square: float = 0.04) -> None:
    for x in xs:
        for y in ys:
            if round_r > 0:
                parts.append(cylinder(round_r, z1 - z0, x, y, z0, color, 12))
            else:
                parts.append(box(square, square, z1 - z0, x, y, z0, color))


# =========================================================================== seating

def _chair(rng):
    material = choice(rng, ("wooden", "metal", "plastic"), (0.6, 0.2, 0.2))
    cname, col = material_color(rng, material)
    sh, w, d = _u(rng, 0.42, 0.48), _u(rng, 0.40, 0.50), _u(rng, 0.40, 0.50)
    st = _u(rng, 0.025, 0.035) if material == "plastic" else _u(rng, 0.03, 0.06)
    top = sh + _u(rng, 0.35, 0.50)
    parts = []
    seat_col = col
    padded = (material == "metal" and rng.random() < 0.6) or (material == "wooden" and rng.random() < 0.3)
    if padded:
        _, seat_col = material_color(rng, "fabric")
    leg_col = shade(col, 0.75)
    if material == "plastic":
        leg_col = jitter(PALETTE[choice(rng, ("silver", "black", "light oak"))], rng)
    r = _u(rng, 0.011, 0.016) if material != "wooden" else 0.0
    lt = _u(rng, 0.03, 0.045)
    ix, iy = w / 2 - 0.025, d / 2 - 0.025
    parts.append(box(w, d, st, 0, 0, sh - st, seat_col))
    _legs(parts, (-ix, ix), (iy,), 0, sh - st, leg_col, r, lt)
    if material == "plastic":
        back = "moulded"
        _legs(parts, (-ix, ix), (-iy,), 0, sh - st, leg_col, r, lt)
        parts.append(box(w, 0.025, top - sh + 0.01, 0, -d / 2 + 0.0125, sh - 0.01, col))
    else:
        back = choice(rng, ("slatted", "solid", "padded") if material == "wooden" else ("solid", "padded"))
        _legs(parts, (-ix, ix), (-iy,), 0, top, leg_col, r, lt)
        inner = 2 * ix - (2 * r if r else lt)
        yb = -iy
        if back == "slatted":
            parts.append(box(inner, 0.02, 0.07, 0, yb, top - 0.08, col))
            n = int(rng.integers(3, 5))
            for i in range(n):
                x = -inner / 2 + inner * (i + 1) / (n + 1)
                parts.append(box(0.025, 0.015, top - 0.08 - sh, x, yb, sh, col))
        else:
            ph = (top - sh) * _u(rng, 0.45, 0.7)
            pc = seat_col if back == "padded" else col
            parts.append(box(inner, 0.03 if back == "padded" else 0.02, ph, 0, yb, top - ph - 0.01, pc))
    caps = ("a {c} {m} chair", "a {m} dining chair in {c}", "a {c} {m} side chair with a {b} backrest",
            "a {c} chair made of {m} parts with four legs" if material != "wooden" else "a {c} {m} kitchen chair")
    return _Spec(parts, col, cname, material, caption(rng, caps, c=cname, m=material, b=back), variant=back)


def _stool(rng):
    material = choice(rng, ("wooden", "metal", "plastic"), (0.5, 0.35, 0.15))
    cname, col = material_color(rng, material)
    kind = choice(rng, ("low", "bar"), (0.5, 0.5))
    H = _u(rng, 0.42, 0.50) if kind == "low" else _u(rng, 0.64, 0.80)
    round_seat = rng.random() < 0.7
    rs = _u(rng, 0.15, 0.20)
    st = _u(rng, 0.03, 0.05)
    parts = []
    if round_seat:
        parts.append(cylinder(rs, st, 0, 0, H - st, col, 20))
    else:
        parts.append(box(2 * rs * 0.9, 2 * rs * 0.9, st, 0, 0, H - st, col))
    n = int(choice(rng, (3, 4), (0.35, 0.65)))
    leg_col = shade(col, 0.75)
    lr = _u(rng, 0.012, 0.02)
    splay = _u(rng, 0.02, 0.06)
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
    return _Spec(parts, col, cname, material,
                 caption(rng, caps, c=cname, m=material, k="bar" if kind == "bar" else "low",
                         shape="round" if round_seat else "square",
                         k2="bar stool" if kind == "bar" else "footstool"), variant=kind)


def _upholstered(rng, n_seats: int, armchair: bool):
    material = choice(rng, ("fabric", "leather", "velvet"), (0.6, 0.25, 0.15))
    cname, col = material_color(rng, material)
    sw = _u(rng, 0.52, 0.62) if armchair else _u(rng, 0.55, 0.68)
    aw = _u(rng, 0.10, 0.22)
    W = n_seats * sw + 2 * aw
    D = _u(rng, 0.72, 0.90) if armchair else _u(rng, 0.80, 0.98)
    has_legs = rng.random() < 0.6
    foot = _u(rng, 0.06, 0.14) if has_legs else 0.0
    base_top = foot + _u(rng, 0.16, 0.22)
    cush = _u(rng, 0.12, 0.17)
    seat_h = base_top + cush
    back_t = _u(rng, 0.15, 0.24)
    back_top = _u(rng, 0.75, 0.95) if not armchair else _u(rng, 0.80, 1.05)
    arm_top = min(_u(rng, 0.55, 0.68), back_top - 0.08)
    parts = []
    body = shade(col, 0.92)
    parts.append(box(W - 2 * aw + 0.02, D, base_top - foot, 0, 0, foot, body))
    for sx in (-1, 1):
        parts.append(box(aw, D, arm_top - foot, sx * (W / 2 - aw / 2), 0, foot, col))
    parts.append(box(W - 2 * aw + 0.02, back_t, back_top - foot, 0, -D / 2 + back_t / 2, foot, col))
    back_cushions = rng.random() < 0.6
    bc_t = _u(rng, 0.10, 0.15) if back_cushions else 0.0
    y_seat0 = -D / 2 + back_t
    light = shade(col, 1.07)
    for i in range(n_seats):
        x = -W / 2 + aw + sw * (i + 0.5)
        parts.append(box(sw - 0.012, D - back_t - 0.01, cush, x, (y_seat0 + D / 2 - 0.01) / 2, base_top, light))
        if back_cushions:
            parts.append(box(sw - 0.012, bc_t, back_top - 0.03 - seat_h, x, y_seat0 + bc_t / 2, seat_h, light))
    if has_legs:
        leg_col = jitter(PALETTE[choice(rng, ("dark brown", "walnut brown", "black", "silver", "light oak"))], rng)
        _legs(parts, (-W / 2 + 0.05, W / 2 - 0.05), (-D / 2 + 0.05, D / 2 - 0.05), 0, foot + 0.001, leg_col,
              round_r=0.02 if rng.random() < 0.5 else 0.0, square=0.04)
    soft = [_surface(seat_h, -W / 2 + aw, W / 2 - aw, y_seat0 + bc_t, D / 2, back_top - seat_h)]
    if armchair:
        caps = ("a {c} {m} armchair", "a comfortable {m} armchair in {c}", "a {c} {m} lounge chair with armrests")
        variant = "armchair"
    else:
        seats = "two-seat" if n_seats == 2 else "three-seat"
        caps = ("a {c} {m} {s} sofa", "a {s} {m} couch in {c}", "a {c} sofa upholstered in {m} with {n} seats"
                if material != "velvet" else "a {c} {m} sofa with {n} seat cushions")
        variant = seats
    return _Spec(parts, col, cname, material,
                 caption(rng, caps, c=cname, m=material, s=variant, n="two" if n_seats == 2 else "three"),
                 soft_supports=soft, variant=variant)


def _sofa(rng):
    return _upholstered(rng, int(choice(rng, (2, 3), (0.45, 0.55))), False)


def _armchair(rng):
    return _upholstered(rng, 1, True)


# =========================================================================== tables

def _table_like(rng, kind: str):
    """kind: 'table' (dining), 'coffee_table'."""
    material = choice(rng, ("wooden", "marble", "glass", "metal"), (0.65, 0.12, 0.13, 0.10))
    cname, col = pick_color(rng, ("clear",)) if material == "glass" else material_color(rng, material)
    if kind == "table":
        H = _u(rng, 0.72, 0.78)
        shape = choice(rng, ("rectangular", "square", "round"), (0.55, 0.2, 0.25))
        if shape == "rectangular":
            W, D = _u(rng, 1.1, 1.8), _u(rng, 0.7, 1.0)
        elif shape == "square":
            W = D = _u(rng, 0.7, 1.0)
        else:
            W = D = _u(rng, 0.8, 1.2)
    else:
        H = _u(rng, 0.35, 0.48)
        shape = choice(rng, ("rectangular", "round"), (0.75, 0.25))
        W, D = (_u(rng, 0.8, 1.3), _u(rng, 0.45, 0.7)) if shape == "rectangular" else (_u(rng, 0.6, 0.9),) * 2
    tt = _u(rng, 0.012, 0.02) if material == "glass" else _u(rng, 0.025, 0.05)
    parts, supports = [], []
    if shape == "round":
        parts.append(cylinder(W / 2, tt, 0, 0, H - tt, col, 24))
        h = W / 2 / np.sqrt(2)
        supports.append(_surface(H, -h, h, -h, h))
    else:
        parts.append(box(W, D, tt, 0, 0, H - tt, col))
        supports.append(_surface(H, -W / 2, W / 2, -D / 2, D / 2))
    if material == "wooden":
        leg_col = shade(col, 0.8)
    else:
        leg_col = jitter(PALETTE[choice(rng, ("black", "silver", "gold", "walnut brown"))], rng)
    round_legs = material in ("glass", "metal") or rng.random() < 0.3
    lr, lt = _u(rng, 0.015, 0.03), _u(rng, 0.04, 0.07)
    if shape == "round":
        ix = iy = W / 2 * 0.5
    else:
        inset = _u(rng, 0.04, 0.1)
        ix, iy = W / 2 - inset, D / 2 - inset
    _legs(parts, (-ix, ix), (-iy, iy), 0, H - tt, leg_col, lr if round_legs else 0.0, lt)
    if material == "wooden" and shape != "round" and kind == "table":
        ah = _u(rng, 0.06, 0.1)
        parts.append(box(2 * ix, 0.02, ah, 0, iy, H - tt - ah, leg_col))
        parts.append(box(2 * ix, 0.02, ah, 0, -iy, H - tt - ah, leg_col))
        parts.append(box(0.02, 2 * iy, ah, ix, 0, H - tt - ah, leg_col))
        parts.append(box(0.02, 2 * iy, ah, -ix, 0, H - tt - ah, leg_col))
    shelf = kind == "coffee_table" and shape == "rectangular" and rng.random() < 0.5
    if shelf:
        zs, sth = _u(rng, 0.08, 0.14), 0.02
        parts.append(box(2 * ix, 2 * iy, sth, 0, 0, zs, shade(col, 0.9) if material != "glass" else leg_col))
        half = (lr if round_legs else lt / 2)
        supports.append(_surface(zs + sth, -ix + half, ix - half, -iy + half, iy - half, H - tt - zs - sth))
    if kind == "table":
        caps = ("a {shape} {c} {m} table", "a {m} dining table in {c}", "a {c} {m} kitchen table with four legs")
    else:
        caps = ("a {c} {m} coffee table", "a low {shape} {m} coffee table in {c}", "a {c} {m} living room table, low and {shape}")
    return _Spec(parts, col, cname, material, caption(rng, caps, c=cname, m=material, shape=shape),
                 supports=supports, variant=shape)


def _table(rng):
    return _table_like(rng, "table")


def _coffee_table(rng):
    return _table_like(rng, "coffee_table")


def _desk(rng):
    material = choice(rng, ("wooden", "metal"), (0.8, 0.2))
    cname, col = material_color(rng, "wooden" if material == "wooden" else "metal")
    W, D, H = _u(rng, 1.0, 1.7), _u(rng, 0.55, 0.8), _u(rng, 0.72, 0.76)
    tt = _u(rng, 0.025, 0.04)
    parts = [box(W, D, tt, 0, 0, H - tt, col)]
    style = choice(rng, ("legs", "panels"), (0.5, 0.5)) if material == "wooden" else "legs"
    frame_col = shade(col, 0.8) if material == "wooden" else jitter(PALETTE[choice(rng, ("black", "silver", "white"))], rng)
    if style == "legs":
        lt = _u(rng, 0.04, 0.06)
        _legs(parts, (-W / 2 + 0.04, W / 2 - 0.04), (-D / 2 + 0.04, D / 2 - 0.04), 0, H - tt, frame_col, 0.0, lt)
    else:
        pt = _u(rng, 0.02, 0.03)
        for sx in (-1, 1):
            parts.append(box(pt, D - 0.02, H - tt, sx * (W / 2 - pt / 2 - 0.005), 0, 0, frame_col))
    mh = _u(rng, 0.25, 0.4)
    parts.append(box(W - 0.1, 0.015, mh, 0, -D / 2 + 0.04, H - tt - mh, frame_col))
    drawers = rng.random() < 0.5
    if drawers:
        bw = _u(rng, 0.35, 0.45)
        x0 = W / 2 - 0.06 - bw
        z0 = 0.05 if style == "legs" else 0.0
        parts.append(box(bw, D - 0.12, H - tt - z0, x0 + bw / 2, -0.02, z0, col))
        n = int(rng.integers(2, 4))
        zz = np.linspace(z0, H - tt, n + 1)
        yf = -0.02 + (D - 0.12) / 2
        _front_panels(parts, [(x0, x0 + bw, zz[i], zz[i + 1], "drawer") for i in range(n)], yf, col,
                      jitter(PALETTE["silver"], rng), rng)
    caps = ("a {c} {m} desk", "a {m} office desk in {c}", "a {c} {m} writing desk{d}")
    return _Spec(parts, col, cname, material,
                 caption(rng, caps, c=cname, m=material, d=" with drawers" if drawers else ""),
                 supports=[_surface(H, -W / 2, W / 2, -D / 2, D / 2)], variant=style)


# =========================================================================== storage

def _carcass(rng, W, D, H, col, base: str):
    """Box body with top board and plinth/legs; returns (parts, body_z0, top_z, top_rect)."""
    parts = []
    top_t = _u(rng, 0.018, 0.03)
    ov = _u(rng, 0.0, 0.015)
    if base == "legs":
        bh = _u(rng, 0.08, 0.16)
        _legs(parts, (-W / 2 + 0.04, W / 2 - 0.04), (-D / 2 + 0.04, D / 2 - 0.04), 0, bh + 0.001, shade(col, 0.6),
              0.015 if rng.random() < 0.5 else 0.0, 0.035)
    elif base == "plinth":
        bh = _u(rng, 0.05, 0.1)
        parts.append(box(W - 0.04, D - 0.04, bh + 0.001, 0, -0.02, 0, shade(col, 0.6)))
    else:
        bh = 0.0
    parts.append(box(W, D, H - top_t - bh, 0, 0, bh, col))
    parts.append(box(W + 2 * ov, D + ov, top_t, 0, ov / 2, H - top_t, shade(col, 1.05)))
    return parts, bh, H - top_t, (-W / 2 - ov, W / 2 + ov, -D / 2, D / 2 + ov)


def _cabinet(rng):
    material = choice(rng, ("wooden", "metal"), (0.8, 0.2))
    cname, col = material_color(rng, material)
    W, D, H = _u(rng, 0.6, 1.6), _u(rng, 0.35, 0.5), _u(rng, 0.6, 1.2)
    parts, z0, z1, (tx0, tx1, ty0, ty1) = _carcass(rng, W, D, H, col, choice(rng, ("legs", "plinth", "none")))
    layout = choice(rng, ("doors", "drawers", "mixed"))
    x0, x1 = -W / 2 + 0.015, W / 2 - 0.015
    n_doors = 1 if W < 0.6 else (2 if W < 1.3 else 3)
    if layout == "doors":
        rects = _door_rects(x0, x1, z0 + 0.01, z1 - 0.01, n_doors)
    elif layout == "drawers":
        n = int(rng.integers(3, 6))
        zz = np.linspace(z0 + 0.01, z1 - 0.01, n + 1)
        cols = 1 if W < 1.0 else 2
        rects = [(x0 + (x1 - x0) * j / cols, x0 + (x1 - x0) * (j + 1) / cols, zz[i], zz[i + 1], "drawer")
                 for i in range(n) for j in range(cols)]
    else:
        zd = z1 - 0.01 - min(0.18, (z1 - z0) * 0.3)
        rects = [(x0 + (x1 - x0) * j / n_doors, x0 + (x1 - x0) * (j + 1) / n_doors, zd, z1 - 0.01, "drawer")
                 for j in range(n_doors)] + _door_rects(x0, x1, z0 + 0.01, zd, n_doors)
    hcol = jitter(PALETTE[choice(rng, ("silver", "black", "gold"))], rng)
    _front_panels(parts, rects, D / 2, col, hcol, rng, choice(rng, ("bar", "knob")))
    noun = {"doors": "cabinet", "drawers": "chest of drawers", "mixed": "sideboard"}[layout]
    caps = ("a {c} {m} {n}", "a {m} storage {n} in {c}", "a {c} {n} made of {m} panels" if material == "metal"
            else "a {c} {m} {n} with {h} handles")
    return _Spec(parts, col, cname, material,
                 caption(rng, caps, c=cname, m=material, n=noun, h="metal"),
                 supports=[_surface(H, tx0, tx1, ty0, ty1)], variant=layout)


def _nightstand(rng):
    material = choice(rng, ("wooden", "metal"), (0.85, 0.15))
    cname, col = material_color(rng, material)
    W, D, H = _u(rng, 0.4, 0.6), _u(rng, 0.35, 0.45), _u(rng, 0.45, 0.65)
    parts, z0, z1, (tx0, tx1, ty0, ty1) = _carcass(rng, W, D, H, col, choice(rng, ("legs", "plinth")))
    supports = [_surface(H, tx0, tx1, ty0, ty1)]
    hcol = jitter(PALETTE[choice(rng, ("silver", "black", "gold"))], rng)
    open_shelf = rng.random() < 0.45
    x0, x1 = -W / 2 + 0.015, W / 2 - 0.015
    if open_shelf:
        # carve the niche by replacing the full body with shell panels
        parts.pop(-2)
        t = 0.018
        zd = z1 - _u(rng, 0.14, 0.2)
        parts.append(box(t, D, z1 - z0, -W / 2 + t / 2, 0, z0, col))
        parts.append(box(t, D, z1 - z0, W / 2 - t / 2, 0, z0, col))
        parts.append(box(W, 0.012, z1 - z0, 0, -D / 2 + 0.006, z0, col))
        parts.append(box(W, D, t, 0, 0, z0, col))
        parts.append(box(W, D, z1 - zd, 0, 0, zd, col))
        supports.append(_surface(z0 + t, -W / 2 + t, W / 2 - t, -D / 2 + 0.012, D / 2, zd - z0 - t))
        rects = [(x0, x1, zd + 0.005, z1 - 0.005, "drawer")]
    else:
        n = int(rng.integers(1, 4))
        zz = np.linspace(z0 + 0.01, z1 - 0.01, n + 1)
        rects = [(x0, x1, zz[i], zz[i + 1], "drawer") for i in range(n)]
    _front_panels(parts, rects, D / 2, col, hcol, rng, choice(rng, ("bar", "knob")))
    caps = ("a {c} {m} nightstand", "a small {m} bedside table in {c}", "a {c} {m} night stand with {d}")
    return _Spec(parts, col, cname, material,
                 caption(rng, caps, c=cname, m=material, d="an open shelf" if open_shelf else "drawers"),
                 supports=supports, variant="open" if open_shelf else "drawers")


def _wardrobe(rng):
    material = choice(rng, ("wooden", "metal"), (0.88, 0.12))
    cname, col = material_color(rng, material)
    W, D, H = _u(rng, 0.8, 2.0), _u(rng, 0.55, 0.65), _u(rng, 1.8, 2.3)
    parts, z0, z1, _ = _carcass(rng, W, D, H, col, choice(rng, ("plinth", "legs", "none")))
    n = 2 if W < 1.3 else 3
    x0, x1 = -W / 2 + 0.015, W / 2 - 0.015
    zb = z0 + 0.01
    rects = []
    if rng.random() < 0.4:
        zb = z0 + 0.01 + _u(rng, 0.2, 0.3)
        rects += [(x0 + (x1 - x0) * j / n, x0 + (x1 - x0) * (j + 1) / n, z0 + 0.01, zb, "drawer") for j in range(n)]
    rects += _door_rects(x0, x1, zb, z1 - 0.01, n)
    hcol = jitter(PALETTE[choice(rng, ("silver", "black", "gold"))], rng)
    _front_panels(parts, rects, D / 2, col, hcol, rng, "bar")
    caps = ("a {c} {m} wardrobe", "a tall {m} wardrobe in {c}", "a {c} {m} closet with {n} doors")
    return _Spec(parts, col, cname, material,
                 caption(rng, caps, c=cname, m=material, n="two" if n == 2 else "three"), variant=f"{n}-door")


def _bookshelf(rng):
    material = choice(rng, ("wooden", "metal"), (0.85, 0.15))
    cname, col = material_color(rng, material)
    W, D, H = _u(rng, 0.6, 1.2), _u(rng, 0.25, 0.4), _u(rng, 0.8, 2.1)
    t = _u(rng, 0.018, 0.03) if material == "wooden" else 0.015
    bt = 0.01
    plinth = _u(rng, 0.03, 0.08)
    parts = []
    parts.append(box(t, D, H, -W / 2 + t / 2, 0, 0, col))
    parts.append(box(t, D, H, W / 2 - t / 2, 0, 0, col))
    parts.append(box(W - 2 * t, bt, H - plinth, 0, -D / 2 + bt / 2, plinth, shade(col, 0.85)))
    parts.append(box(W - 2 * t, t, plinth, 0, D / 2 - 0.02 - t / 2, 0, shade(col, 0.8)))
    parts.append(box(W - 2 * t, D - bt, t, 0, bt / 2, plinth, col))       # bottom board
    parts.append(box(W - 2 * t, D - bt, t, 0, bt / 2, H - t, col))        # top board
    n = max(2, int(round((H - plinth - 2 * t) / _u(rng, 0.28, 0.38))))
    floors = np.linspace(plinth + t, H - t, n + 1)  # bottom of each compartment ... top board bottom
    supports = []
    for i in range(n):
        if i > 0:
            parts.append(box(W - 2 * t, D - bt, t, 0, bt / 2, floors[i] - t, col))
        ceiling = floors[i + 1] - (t if i + 1 < n else 0.0)  # bottom of the next board
        supports.append(_surface(floors[i], -W / 2 + t, W / 2 - t, -D / 2 + bt, D / 2, ceiling - floors[i]))
    if H <= 1.3:
        supports.append(_surface(H, -W / 2, W / 2, -D / 2, D / 2, 1.0))
    caps = ("a {c} {m} bookshelf", "a {tall} {m} bookcase in {c}", "a {c} {m} shelving unit with {n} shelves")
    return _Spec(parts, col, cname, material,
                 caption(rng, caps, c=cname, m=material, tall="tall" if H > 1.5 else "low", n=n),
                 supports=supports, variant=f"{n}-shelf")


# =========================================================================== bed

def _bed(rng):
    kind = choice(rng, ("single", "double", "queen-size", "king-size"), (0.25, 0.35, 0.25, 0.15))
    mw = {"single": (0.9, 1.0), "double": (1.35, 1.45), "queen-size": (1.5, 1.6), "king-size": (1.8, 1.95)}[kind]
    mw = _u(rng, *mw)
    ml, mt = _u(rng, 1.95, 2.05), _u(rng, 0.18, 0.28)
    material = choice(rng, ("wooden", "fabric", "metal"), (0.55, 0.3, 0.15))
    cname, col = material_color(rng, material)
    rail = _u(rng, 0.03, 0.06)
    hb_t = _u(rng, 0.05, 0.1) if material != "metal" else 0.04
    fw, fl = mw + 2 * rail, ml + rail + hb_t
    leg_h = _u(rng, 0.05, 0.15)
    frame_top = _u(rng, 0.25, 0.38)
    parts = [box(fw, fl - hb_t, frame_top - leg_h, 0, hb_t / 2, leg_h, shade(col, 0.95))]
    _legs(parts, (-fw / 2 + 0.04, fw / 2 - 0.04), (fl / 2 - 0.04, -fl / 2 + hb_t + 0.04), 0, leg_h + 0.001,
          shade(col, 0.7), 0.0, 0.05)
    hb_top = _u(rng, 0.9, 1.3)
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
        parts.append(box(fw, 0.04, frame_top + _u(rng, 0.1, 0.25), 0, fl / 2 - 0.02, 0, col))
    mz0 = frame_top - _u(rng, 0.0, 0.05)
    m_top = mz0 + mt
    my0 = -fl / 2 + hb_t
    my1 = fl / 2 - (0.04 if foot_board else rail)
    parts.append(box(mw, my1 - my0, mt, 0, (my0 + my1) / 2, mz0, jitter(PALETTE["white"], rng, 0.02)))
    bname, bcol = material_color(rng, choice(rng, ("cotton", "fabric", "linen")))
    dy0 = my0 + _u(rng, 0.55, 0.65)
    dy1 = my1 + (0.0 if foot_board else 0.03)
    dz0 = max(m_top - 0.2, leg_h + 0.05)
    parts.append(box(mw + 0.06, dy1 - dy0, m_top + 0.04 - dz0, 0, (dy0 + dy1) / 2, dz0, bcol))
    parts.append(box(mw + 0.07, 0.18, 0.012, 0, dy0 + 0.09, m_top + 0.04, jitter(PALETTE["white"], rng, 0.02)))
    soft = [_surface(m_top, -mw / 2, mw / 2, my0, dy0, 1.0)]
    caps = ("a {k} bed with a {c} {m} frame", "a {c} {m} {k} bed with {b} bedding",
            "a {k} bed, {c} {m} headboard and {b} duvet")
    return _Spec(parts, col, cname, material, caption(rng, caps, c=cname, m=material, k=kind, b=bname),
                 soft_supports=soft, variant=kind)


# =========================================================================== lighting, plants

def _shade_color(rng):
    return pick_color(rng, ("white", "cream", "beige", "off-white", "light grey", "mustard yellow", "sage green"))


def _lamp(rng):
    material = choice(rng, ("metal", "wooden"), (0.75, 0.25))
    cname, col = material_color(rng, material) if material == "wooden" else pick_color(
        rng, ("black", "silver", "gold", "white", "dark grey"))
    sname, scol = _shade_color(rng)
    H = _u(rng, 1.4, 1.8)
    sh, rb, rt = _u(rng, 0.25, 0.35), _u(rng, 0.18, 0.25), _u(rng, 0.12, 0.18)
    parts = []
    tripod = material == "wooden" or rng.random() < 0.25
    if tripod:
        spread, zc = _u(rng, 0.25, 0.32), H * 0.55
        for i in range(3):
            a = np.pi / 2 + 2 * np.pi * i / 3
            parts.append(rod((spread * np.cos(a), spread * np.sin(a), 0.015), (0, 0, zc), 0.015, col, 8))
        parts.append(cylinder(0.014, H - sh * 0.6 - zc + 0.02, 0, 0, zc - 0.02, col, 10))
    else:
        parts.append(cylinder(_u(rng, 0.12, 0.17), _u(rng, 0.02, 0.035), 0, 0, 0, shade(col, 0.9), 20))
        parts.append(cylinder(_u(rng, 0.011, 0.016), H - sh * 0.6, 0, 0, 0.01, col, 10))
    parts.append(frustum(rb, rt, sh, 0, 0, H - sh, scol, 20))
    caps = ("a {c} {m} floor lamp with a {s} shade", "a tall {m} standing lamp in {c}",
            "a {c} {m} {t}floor lamp")
    return _Spec(parts, col, cname, material,
                 caption(rng, caps, c=cname, m=material, s=sname, t="tripod " if tripod else ""),
                 variant="tripod" if tripod else "pole")


def _table_lamp(rng):
    material = choice(rng, ("ceramic", "metal", "glass"), (0.5, 0.35, 0.15))
    cname, col = material_color(rng, material) if material != "metal" else pick_color(
        rng, ("black", "silver", "gold", "white"))
    sname, scol = _shade_color(rng)
    parts = []
    if material == "metal":
        bh = _u(rng, 0.015, 0.03)
        parts.append(cylinder(_u(rng, 0.06, 0.09), bh, 0, 0, 0, col, 20))
        stem = _u(rng, 0.2, 0.35)
        parts.append(cylinder(0.008, stem, 0, 0, bh, col, 8))
        body_top = bh + stem
    else:
        r, h = _u(rng, 0.05, 0.09), _u(rng, 0.15, 0.28)
        parts.append(lathe([(r * 0.6, 0), (r, h * 0.3), (r * 0.95, h * 0.65), (r * 0.35, h * 0.92), (0.015, h)],
                           color=col, sections=18))
        parts.append(cylinder(0.006, 0.08, 0, 0, h - 0.005, jitter(PALETTE["silver"], rng), 8))
        body_top = h + 0.075
    sh, rb = _u(rng, 0.14, 0.22), _u(rng, 0.1, 0.17)
    parts.append(frustum(rb, rb * _u(rng, 0.6, 0.85), sh, 0, 0, body_top - sh * 0.35, scol, 20))
    caps = ("a {c} {m} table lamp", "a small {m} bedside lamp in {c} with a {s} shade",
            "a {c} {m} desk lamp with a {s} lampshade")
    return _Spec(parts, col, cname, material, caption(rng, caps, c=cname, m=material, s=sname))


def _foliage(parts, rng, cx, cy, zc, spread, r0, r1, n, zspread):
    for _ in range(n):
        r = _u(rng, r0, r1)
        a, d = _u(rng, 0, 2 * np.pi), _u(rng, 0, spread)
        z = zc + _u(rng, -zspread, zspread)
        parts.append(sphere(r, cx + d * np.cos(a), cy + d * np.sin(a), z,
                            jitter(FOLIAGE[int(rng.integers(len(FOLIAGE)))], rng, 0.08), 1))


def _pot(rng, parts, rb, h, material, col):
    rt = rb * _u(rng, 1.1, 1.35)
    parts.append(frustum(rb, rt, h, 0, 0, 0, col, 18))
    parts.append(cylinder(rt + 0.008, h * 0.12, 0, 0, h * 0.88, shade(col, 0.92), 18))
    parts.append(cylinder(rt - 0.01, 0.01, 0, 0, h * 0.9, jitter(PALETTE["dark brown"], rng), 18))
    return rt


def _plant(rng):
    material = choice(rng, ("ceramic", "plastic", "wooden"), (0.6, 0.3, 0.1))
    cname, col = pick_color(rng, ("terracotta", "white", "grey", "black", "cream", "sage green", "teal")) \
        if material == "ceramic" else material_color(rng, material)
    ph, rb = _u(rng, 0.25, 0.45), _u(rng, 0.12, 0.19)
    parts = []
    rt = _pot(rng, parts, rb, ph, material, col)
    style = choice(rng, ("tree", "bush"), (0.5, 0.5))
    if style == "tree":
        H = _u(rng, 1.1, 1.8)
        parts.append(cylinder(0.02, H * 0.7 - ph, 0, 0, ph * 0.9, jitter(PALETTE["brown"], rng), 8))
        crown = (H - ph) * 0.3
        _foliage(parts, rng, 0, 0, H - crown, rt * 1.2, 0.12, 0.2, int(rng.integers(6, 10)), crown * 0.6)
    else:
        _foliage(parts, rng, 0, 0, ph + 0.15, rt * 1.1, 0.15, 0.25, int(rng.integers(5, 9)), 0.12)
    caps = ("a {t} leafy green plant in a {c} {m} pot", "a large potted plant with a {c} {m} planter",
            "an indoor {t} in a {c} {m} flower pot")
    return _Spec(parts, col, cname, material,
                 caption(rng, caps, c=cname, m=material, t="tree" if style == "tree" else "bushy"), variant=style)


def _potted_plant(rng):
    material = choice(rng, ("ceramic", "plastic"), (0.75, 0.25))
    cname, col = material_color(rng, material)
    ph, rb = _u(rng, 0.07, 0.14), _u(rng, 0.045, 0.08)
    parts = []
    rt = _pot(rng, parts, rb, ph, material, col)
    style = choice(rng, ("leafy", "cactus"), (0.7, 0.3))
    if style == "cactus":
        ch = _u(rng, 0.1, 0.25)
        g = jitter((0.25, 0.48, 0.22), rng, 0.05)
        parts.append(capsule(rt * 0.5, ch, 0, 0, ph * 0.85, g))
        if rng.random() < 0.6:
            parts.append(capsule(rt * 0.28, ch * 0.4, rt * 0.55, 0, ph * 0.85 + ch * 0.35, g))
    else:
        _foliage(parts, rng, 0, 0, ph + rt * 0.9, rt * 0.7, rt * 0.45, rt * 0.8, int(rng.integers(3, 7)), rt * 0.4)
    caps = ("a small {p} in a {c} {m} pot", "a {c} {m} pot with a little {p}", "a small potted {p}, {c} {m} pot")
    return _Spec(parts, col, cname, material,
                 caption(rng, caps, c=cname, m=material, p="cactus" if style == "cactus" else "houseplant"),
                 variant=style)


# =========================================================================== electronics

def _monitor(rng):
    material = choice(rng, ("plastic", "metal"), (0.7, 0.3))
    cname, col = pick_color(rng, ("black", "dark grey", "white") if material == "plastic" else ("silver", "dark grey", "black"))
    w = _u(rng, 0.5, 0.72)
    bezel = _u(rng, 0.008, 0.02)
    h = w * 9 / 16 + 2 * bezel
    th = _u(rng, 0.02, 0.03)
    lift = _u(rng, 0.06, 0.14)
    parts = []
    round_base = rng.random() < 0.4
    if round_base:
        parts.append(cylinder(_u(rng, 0.09, 0.12), 0.015, 0, 0, 0, shade(col, 0.85), 20))
    else:
        parts.append(box(_u(rng, 0.18, 0.26), _u(rng, 0.16, 0.2), 0.015, 0, 0, 0, shade(col, 0.85)))
    parts.append(box(0.045, 0.025, lift + h * 0.5, 0, -0.045, 0.01, shade(col, 0.85)))
    ys = -0.045 + 0.0125 + th / 2
    parts.append(box(w, th, h, 0, ys, lift, col))
    parts.append(box(w * 0.5, 0.03, h * 0.45, 0, ys - th / 2 - 0.01, lift + h * 0.2, shade(col, 0.8)))
    parts.append(box(w - 2 * bezel, 0.002, h - 2 * bezel, 0, ys + th / 2 + 0.001, lift + bezel, SCREEN_BLACK))
    inch = int(round(np.hypot(w, w * 9 / 16) / 0.0254))
    caps = ("a {i}-inch {c} {m} computer monitor", "a {c} {m} monitor on a stand", "a {c} flat {m} computer screen")
    return _Spec(parts, col, cname, material, caption(rng, caps, c=cname, m=material, i=inch), variant=f"{inch}in")


def _tv(rng):
    material = choice(rng, ("plastic", "metal"), (0.6, 0.4))
    cname, col = pick_color(rng, ("black", "dark grey", "charcoal") if material == "plastic" else ("black", "silver", "dark grey"))
    sname, scol = material_color(rng, "wooden")
    W, D, H = _u(rng, 1.2, 2.0), _u(rng, 0.35, 0.45), _u(rng, 0.4, 0.6)
    stand = choice(rng, ("closed", "open"))
    parts, supports = [], []
    if stand == "closed":
        sp, z0, z1, (tx0, tx1, ty0, ty1) = _carcass(rng, W, D, H, scol, choice(rng, ("legs", "plinth")))
        parts += sp
        n = 2 if W < 1.5 else 3
        _front_panels(parts, _door_rects(-W / 2 + 0.015, W / 2 - 0.015, z0 + 0.01, z1 - 0.01, n), D / 2, scol,
                      jitter(PALETTE["black"], rng), rng, "bar")
    else:
        t, leg = 0.025, _u(rng, 0.06, 0.14)
        tx0, tx1, ty0, ty1 = -W / 2, W / 2, -D / 2, D / 2
        _legs(parts, (-W / 2 + 0.04, W / 2 - 0.04), (-D / 2 + 0.04, D / 2 - 0.04), 0, leg + 0.001, shade(scol, 0.6), 0.0, 0.04)
        parts.append(box(W, D, t, 0, 0, leg, scol))
        parts.append(box(W, D, t, 0, 0, H - t, scol))
        for sx in (-1, 1):
            parts.append(box(t, D, H - leg - 2 * t, sx * (W / 2 - t / 2), 0, leg + t, scol))
        zs = (leg + H) / 2
        parts.append(box(W - 2 * t, D, t, 0, 0, zs - t / 2, scol))
        parts.append(box(W - 2 * t, 0.01, H - leg - 2 * t, 0, -D / 2 + 0.005, leg + t, shade(scol, 0.85)))
        supports.append(_surface(zs + t / 2, -W / 2 + t, W / 2 - t, -D / 2 + 0.01, D / 2, H - t - zs - t / 2))
        supports.append(_surface(leg + t, -W / 2 + t, W / 2 - t, -D / 2 + 0.01, D / 2, zs - t / 2 - leg - t))
    diag = _u(rng, 40, 65) * 0.0254
    sw = min(diag * 16 / np.hypot(16, 9), W - 0.12)
    sh = sw * 9 / 16 + 0.02
    st = _u(rng, 0.035, 0.06)
    yb = ty0 + 0.13
    lift = _u(rng, 0.05, 0.1)
    parts.append(box(_u(rng, 0.25, 0.4), 0.2, 0.012, 0, yb, H, shade(col, 0.8)))
    parts.append(box(0.06, 0.03, lift + sh * 0.3, 0, yb - st / 2 - 0.015, H + 0.01, shade(col, 0.8)))
    parts.append(box(sw, st, sh, 0, yb, H + lift, col))
    parts.append(box(sw - 0.02, 0.002, sh - 0.02, 0, yb + st / 2 + 0.001, H + lift + 0.01, SCREEN_BLACK))
    front_y0 = yb + 0.1 + 0.005 + MARGIN
    supports.append(_surface(H, tx0, tx1, front_y0 - MARGIN, ty1))
    if tx1 - (sw / 2 + 0.005) >= 2 * MARGIN + 0.08:
        for sx in (-1, 1):
            x0, x1 = sorted((sx * (sw / 2 + 0.005), sx * tx1))
            supports.append(_surface(H, x0, x1, ty0, front_y0 - MARGIN, 1.0))
    inch = int(round(diag / 0.0254))
    caps = ("a {i}-inch {c} {m} flat-screen TV on a {s} wooden stand", "a {c} {m} television on a {s} TV stand",
            "a {c} {m} TV screen standing on a {s} wooden media console")
    return _Spec(parts, col, cname, material, caption(rng, caps, c=cname, m=material, s=sname, i=inch),
                 supports=supports, variant=f"{inch}in-{stand}")


def _keyboard(rng):
    material = choice(rng, ("plastic", "metal"), (0.75, 0.25))
    cname, col = pick_color(rng, ("black", "white", "dark grey", "light grey") if material == "plastic" else ("silver", "dark grey"))
    W, D, h = _u(rng, 0.35, 0.45), _u(rng, 0.12, 0.15), _u(rng, 0.015, 0.025)
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
    return _Spec(parts, col, cname, material, caption(rng, caps, c=cname, m=material))


def _laptop(rng):
    material = choice(rng, ("metal", "plastic"), (0.6, 0.4))
    cname, col = pick_color(rng, ("silver", "dark grey", "gold") if material == "metal" else ("black", "white", "dark grey"))
    W, D, bt = _u(rng, 0.3, 0.38), _u(rng, 0.21, 0.25), _u(rng, 0.013, 0.02)
    lt = _u(rng, 0.005, 0.008)
    parts = [box(W, D, bt, 0, 0, 0, col)]
    parts.append(box(W - 0.03, D * 0.45, 0.001, 0, -D / 2 + 0.02 + D * 0.225, bt, SCREEN_BLACK))
    parts.append(box(W * 0.32, D * 0.28, 0.001, 0, D / 2 - 0.012 - D * 0.14, bt, shade(col, 0.85)))
    angle = np.deg2rad(_u(rng, 100, 120))
    lid = box(W, D, lt, 0, 0, bt, shade(col, 0.95))
    disp = box(W - 0.02, D - 0.025, 0.001, 0, 0.002, bt - 0.001, SCREEN_BLACK)  # under the closed lid
    pivot = (0, -D / 2, bt)
    # the closed lid spans y in [-D/2, D/2] above the base; swing it open around the rear hinge so the
    # display (its underside) ends up facing +y
    parts.append(rotate_x(lid, angle, pivot))
    parts.append(rotate_x(disp, angle, pivot))
    caps = ("an open {c} {m} laptop", "a {c} {m} notebook computer", "a {c} laptop with a {m} case, lid open")
    return _Spec(parts, col, cname, material, caption(rng, caps, c=cname, m=material))


# =========================================================================== small objects

def _mug(rng):
    material = choice(rng, ("ceramic", "glass", "metal"), (0.8, 0.1, 0.1))
    cname, col = material_color(rng, material) if material != "metal" else pick_color(rng, ("white", "silver", "blue", "red"))
    r, h, wall = _u(rng, 0.035, 0.048), _u(rng, 0.08, 0.11), 0.005
    parts = [lathe([(r * 0.92, 0), (r, 0.006), (r, h), (r - wall, h), (r - wall, 0.012), (0, 0.012)], color=col, sections=20)]
    if rng.random() < 0.5:
        parts.append(cylinder(r - wall - 0.0005, h * _u(rng, 0.6, 0.8), 0, 0, 0.011, jitter((0.22, 0.12, 0.06), rng), 20))
    R, rr = _u(rng, 0.022, 0.03), _u(rng, 0.005, 0.007)
    parts.append(torus(R, rr, (r - wall + rr + R, 0, h * 0.55), shade(col, 0.92), "y", 16, 8))
    small = "small" if r * h < 0.0038 else "large"
    caps = ("a {s} {c} {m} mug", "a {c} {m} coffee mug", "a {c} {m} cup with a handle")
    return _Spec(parts, col, cname, material, caption(rng, caps, c=cname, m=material, s=small))


def _bottle(rng):
    material = choice(rng, ("glass", "plastic"), (0.6, 0.4))
    cname, col = material_color(rng, "glass") if material == "glass" else pick_color(rng, ("clear", "blue", "light blue", "white", "green"))
    kind = choice(rng, ("wine", "water"), (0.5, 0.5) if material == "glass" else (0.1, 0.9))
    r = _u(rng, 0.035, 0.045) if kind == "wine" else _u(rng, 0.03, 0.04)
    bh = _u(rng, 0.17, 0.22) if kind == "wine" else _u(rng, 0.12, 0.2)
    rn, nh = _u(rng, 0.011, 0.015), _u(rng, 0.06, 0.09) if kind == "wine" else _u(rng, 0.02, 0.04)
    sh = 0.06 if kind == "wine" else 0.035
    prof = [(r * 0.95, 0), (r, 0.005), (r, bh), (rn, bh + sh), (rn, bh + sh + nh), (rn * 1.12, bh + sh + nh), (rn * 1.12, bh + sh + nh + 0.004)]
    parts = [lathe(prof, color=col, sections=18)]
    top = bh + sh + nh + 0.004
    ccol = jitter(PALETTE[choice(rng, ("black", "white", "gold", "red", "blue", "silver"))], rng)
    parts.append(cylinder(rn * 1.18, _u(rng, 0.015, 0.03), 0, 0, top - 0.006, ccol, 16))
    if rng.random() < 0.6:
        parts.append(cylinder(r + 0.0008, bh * 0.45, 0, 0, bh * 0.3, jitter(PALETTE[choice(rng, ("white", "cream", "gold", "black"))], rng), 18))
    caps = ("a {c} {m} {k} bottle", "a {k} bottle made of {c} {m}", "a {c} {m} bottle with a cap")
    return _Spec(parts, col, cname, material, caption(rng, caps, c=cname, m=material, k=kind), variant=kind)


def _book(rng):
    material = "paper"
    cname, col = material_color(rng, "paper", 0.05)
    T, D, H = _u(rng, 0.015, 0.06), _u(rng, 0.13, 0.22), _u(rng, 0.18, 0.30)
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
    return _Spec(parts, col, cname, material, caption(rng, caps, c=cname, m=material, t=thick), variant=thick)


def _pillow(rng):
    material = choice(rng, ("fabric", "velvet", "cotton", "linen"))
    cname, col = material_color(rng, material)
    if rng.random() < 0.5:
        sx = sy = _u(rng, 0.38, 0.5)
        noun = "cushion"
    else:
        sx, sy = _u(rng, 0.5, 0.7), _u(rng, 0.32, 0.48)
        noun = "pillow"
    sz = _u(rng, 0.1, 0.18)
    parts = [rounded_box(sx, sy, sz, color=col, squareness=0.3, puff=0.55)]
    caps = ("a soft {c} {m} {n}", "a {c} {n} made of {m}", "a {c} {m} throw {n}")
    return _Spec(parts, col, cname, material, caption(rng, caps, c=cname, m=material, n=noun), variant=noun)


def _vase(rng):
    material = choice(rng, ("ceramic", "glass"), (0.7, 0.3))
    cname, col = material_color(rng, material)
    r, h, w = _u(rng, 0.04, 0.09), _u(rng, 0.15, 0.4), 0.005
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
            a = 2 * np.pi * i / 5 + _u(rng, 0, 0.5)
            tip = (np.cos(a) * top * 1.6, np.sin(a) * top * 1.6, h + _u(rng, 0.08, 0.2))
            parts.append(rod((0, 0, h * 0.5), tip, 0.003, jitter((0.2, 0.45, 0.15), rng), 6))
            fc = PALETTE[choice(rng, ("red", "yellow", "white", "pink", "purple", "orange"))]
            parts.append(sphere(_u(rng, 0.015, 0.03), *tip, jitter(fc, rng), 1))
    caps = ("a {s}{c} {m} vase", "a {c} {m} flower vase{f}", "a decorative {m} vase in {c}")
    return _Spec(parts, col, cname, material,
                 caption(rng, caps, c=cname, m=material, s={"round": "round ", "tall": "tall ", "bottle": "bottle-shaped "}[shape], f=" with flowers" if flowers else ""), variant=shape)


def _trash_bin(rng):
    material = choice(rng, ("plastic", "metal"), (0.55, 0.45))
    cname, col = material_color(rng, material)
    r, h = _u(rng, 0.12, 0.2), _u(rng, 0.3, 0.6)
    rt = r * _u(rng, 1.0, 1.2)
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
    return _Spec(parts, col, cname, material,
                 caption(rng, caps, c=cname, m=material, l=" with a lid" if lid else ""), variant="lid" if lid else "open")


def _box(rng):
    material = choice(rng, ("cardboard", "plastic"), (0.7, 0.3))
    cname, col = material_color(rng, material)
    W, D, H = _u(rng, 0.3, 0.6), _u(rng, 0.25, 0.45), _u(rng, 0.2, 0.45)
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
    return _Spec(parts, col, cname, material, caption(rng, caps, c=cname, m=material, n=noun),
                 variant="cardboard" if material == "cardboard" else "storage")


def _rug(rng):
    material = choice(rng, ("wool", "fabric", "jute"), (0.5, 0.3, 0.2))
    cname, col = material_color(rng, material)
    W, L, h = _u(rng, 1.2, 3.0), _u(rng, 0.8, 2.2), 0.01
    style = choice(rng, ("plain", "bordered", "striped"), (0.3, 0.4, 0.3))
    parts = []
    _, acc = pick_color(rng, ("cream", "beige", "navy blue", "dark red", "charcoal", "white", "mustard yellow", "teal"))
    if style == "plain":
        parts.append(box(W, L, h, 0, 0, 0, col))
    elif style == "bordered":
        b = _u(rng, 0.06, 0.15)
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
    return _Spec(parts, col, cname, material,
                 caption(rng, caps, c=cname, m=material, sz=size, st=st, st2="striped " if style == "striped" else ""),
                 variant=style)


# =========================================================================== wall-mounted

def _door(rng):
    material = choice(rng, ("wooden", "metal"), (0.85, 0.15))
    cname, col = material_color(rng, material)
    W, H, t = _u(rng, 0.8, 0.95), _u(rng, 1.98, 2.1), 0.04
    cw, cd = _u(rng, 0.06, 0.1), t + 0.012
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
    return _Spec(parts, col, cname, material, caption(rng, caps, c=cname, m=material, st=style, h=hname),
                 mount_height_m=0.0, variant=style)


def _window_frame(rng):
    material = choice(rng, ("wooden", "plastic", "metal"), (0.4, 0.35, 0.25))
    if material == "plastic":
        cname, col = pick_color(rng, ("white", "off-white", "dark grey"))
    else:
        cname, col = material_color(rng, material)
    W, H = _u(rng, 0.8, 1.6), _u(rng, 0.9, 1.4)
    fb, fd = _u(rng, 0.05, 0.08), _u(rng, 0.06, 0.1)
    sill_t, sill_d = 0.03, fd + _u(rng, 0.04, 0.09)
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
    return _Spec(parts, col, cname, material, caption(rng, caps, c=cname, m=material, p=panes),
                 mount_height_m=_u(rng, 0.8, 1.0), variant=f"{panes}-pane")


def _picture(rng):
    material = choice(rng, ("wooden", "metal"), (0.7, 0.3))
    cname, col = material_color(rng, material) if material == "wooden" else pick_color(rng, ("black", "silver", "gold", "white"))
    W, H = _u(rng, 0.3, 1.0), _u(rng, 0.3, 0.9)
    fb, fd = _u(rng, 0.02, 0.06), _u(rng, 0.02, 0.04)
    parts = [box(W, fd, fb, 0, fd / 2, 0, col), box(W, fd, fb, 0, fd / 2, H - fb, col),
             box(fb, fd, H - 2 * fb, -W / 2 + fb / 2, fd / 2, fb, col),
             box(fb, fd, H - 2 * fb, W / 2 - fb / 2, fd / 2, fb, col)]
    cd = fd * 0.6
    mat_w = _u(rng, 0.03, 0.08) if rng.random() < 0.5 else 0.0
    parts.append(box(W - 2 * fb + 0.004, cd, H - 2 * fb + 0.004, 0, cd / 2, fb - 0.002, jitter(PALETTE["off-white"], rng, 0.02)))
    ix0, ix1 = -W / 2 + fb + mat_w, W / 2 - fb - mat_w
    iz0, iz1 = fb + mat_w, H - fb - mat_w
    art = choice(rng, ("landscape", "abstract"))
    yc = cd + 0.001
    if art == "landscape":
        zh = iz0 + (iz1 - iz0) * _u(rng, 0.3, 0.55)
        parts.append(box(ix1 - ix0, 0.002, iz1 - zh, (ix0 + ix1) / 2, yc, zh, jitter((0.55, 0.72, 0.88), rng, 0.05)))
        parts.append(box(ix1 - ix0, 0.002, zh - iz0, (ix0 + ix1) / 2, yc, iz0, jitter(FOLIAGE[int(rng.integers(4))], rng, 0.08)))
        sr = min(ix1 - ix0, iz1 - zh) * 0.12
        sx = _u(rng, ix0 + 2 * sr, ix1 - 2 * sr)
        parts.append(rod((sx, yc + 0.001, zh + (iz1 - zh) * 0.65), (sx, yc + 0.003, zh + (iz1 - zh) * 0.65), sr,
                         jitter(PALETTE["yellow"], rng), 12))
    else:
        parts.append(box(ix1 - ix0, 0.002, iz1 - iz0, (ix0 + ix1) / 2, yc, iz0, jitter(PALETTE[choice(rng, ("cream", "white", "beige", "light grey"))], rng)))
        for k in range(int(rng.integers(2, 5))):
            bw, bh = (ix1 - ix0) * _u(rng, 0.15, 0.5), (iz1 - iz0) * _u(rng, 0.15, 0.5)
            x = _u(rng, ix0 + bw / 2, ix1 - bw / 2)
            z = _u(rng, iz0, iz1 - bh)
            c = PALETTE[choice(rng, ("red", "blue", "yellow", "teal", "orange", "black", "navy blue", "pink"))]
            parts.append(box(bw, 0.002, bh, x, yc + 0.0015 * (k + 1), z, jitter(c, rng)))
    centre = _u(rng, 1.45, 1.65)
    caps = ("a framed {a} picture with a {c} {m} frame", "a {a} painting in a {c} {m} frame",
            "a {c} {m} picture frame holding {aa} {a} print")
    return _Spec(parts, col, cname, material,
                 caption(rng, caps, c=cname, m=material, a=art, aa="a" if art == "landscape" else "an"),
                 mount_height_m=max(0.9, centre - H / 2), variant=art)


# =========================================================================== registry

_BUILDERS: dict[str, Callable[[np.random.Generator], _Spec]] = {
    "chair": _chair, "armchair": _armchair, "sofa": _sofa, "stool": _stool,
    "table": _table, "coffee_table": _coffee_table, "desk": _desk,
    "bed": _bed, "nightstand": _nightstand, "cabinet": _cabinet, "wardrobe": _wardrobe, "bookshelf": _bookshelf,
    "lamp": _lamp, "plant": _plant, "tv": _tv, "rug": _rug, "trash_bin": _trash_bin, "box": _box,
    "door": _door, "window_frame": _window_frame, "picture": _picture,
    "table_lamp": _table_lamp, "potted_plant": _potted_plant, "monitor": _monitor, "keyboard": _keyboard,
    "laptop": _laptop, "mug": _mug, "bottle": _bottle, "book": _book, "pillow": _pillow, "vase": _vase,
}

_PLACEMENT: dict[str, str] = {
    "chair": "floor", "armchair": "floor", "sofa": "wall", "stool": "floor", "table": "floor",
    "coffee_table": "floor", "desk": "wall", "bed": "wall", "nightstand": "wall", "cabinet": "wall",
    "wardrobe": "wall", "bookshelf": "wall", "lamp": "floor", "plant": "floor", "tv": "floor", "rug": "floor",
    "trash_bin": "floor", "box": "floor", "door": "wall_mounted", "window_frame": "wall_mounted",
    "picture": "wall_mounted",
}

CATEGORIES: tuple[str, ...] = tuple(_BUILDERS)
SMALL_CATEGORIES: tuple[str, ...] = tuple(c for c in CATEGORIES if c not in _PLACEMENT)


def _move_support(s: SupportSurface, shift: np.ndarray, scale: float) -> SupportSurface:
    return SupportSurface(float((s.height_m + shift[2]) * scale),
                          (float(s.half_extent_xy[0] * scale), float(s.half_extent_xy[1] * scale)),
                          (float((s.center_xy[0] + shift[0]) * scale), float((s.center_xy[1] + shift[1]) * scale)),
                          float(s.clearance_m * scale))


def build_furniture(category: str, rng: np.random.Generator, size_scale: float = 1.0) -> FurnitureModel:
    """Build a randomised instance of ``category`` (see :data:`CATEGORIES`) in its local frame."""
    if category not in _BUILDERS:
        raise ValueError(f"unknown furniture category {category!r}; known categories: {', '.join(CATEGORIES)}")
    spec = _BUILDERS[category](rng)
    parts = [p for p in spec.parts]
    mesh = concat(parts)
    lo, hi = mesh.bounds
    shift = np.array([-(lo[0] + hi[0]) / 2.0, -(lo[1] + hi[1]) / 2.0, -lo[2]])
    s = float(size_scale)
    for p in parts:
        p.apply_translation(shift)
        if s != 1.0:
            p.apply_scale(s)
    mesh.apply_translation(shift)
    if s != 1.0:
        mesh.apply_scale(s)
    mesh.metadata["category"] = category
    placement = _PLACEMENT.get(category, "on_surface")
    return FurnitureModel(
        category=category, mesh=mesh, parts=parts, color=tuple(float(c) for c in spec.color),
        color_name=spec.color_name, material=spec.material, caption=spec.caption,
        size_m=tuple(float(e) for e in mesh.extents),
        supports=[_move_support(x, shift, s) for x in spec.supports], placement=placement,
        is_small=placement == "on_surface", mount_height_m=float(spec.mount_height_m),
        soft_supports=[_move_support(x, shift, s) for x in spec.soft_supports], variant=spec.variant)
