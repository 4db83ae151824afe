"""The dataclasses and the helpers several families use (legs, fronts, carcass), so none imports another."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import trimesh

from openmulti_env.world.furniture_parts import box, box_between, cylinder, rod, shade

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
class FurnitureSpec:
    parts: list
    color: tuple
    color_name: str
    material: str
    caption: str
    supports: list = field(default_factory=list)
    soft_supports: list = field(default_factory=list)
    mount_height_m: float = 0.0
    variant: str = ""


def uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(rng.uniform(lo, hi))


def support_surface(z: float, x0: float, x1: float, y0: float, y1: float, clearance: float = 1.0,
             margin: float = MARGIN) -> SupportSurface:
    """Support for the physical rectangle [x0,x1]x[y0,y1] at height z, shrunk by ``margin``."""
    return SupportSurface(float(z), (float((x1 - x0) / 2 - margin), float((y1 - y0) / 2 - margin)),
                          (float((x0 + x1) / 2), float((y0 + y1) / 2)), float(clearance))


def front_panels(parts: list, rects, y_front: float, color, handle_color, rng,
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


def door_rects(x0, x1, z0, z1, n):
    w = (x1 - x0) / n
    rects = []
    for i in range(n):
        kind = "door_r" if (n > 1 and i == n - 1) or (n == 3 and i == 1) else "door_l"
        if n == 1:
            kind = "door_l"
        rects.append((x0 + i * w, x0 + (i + 1) * w, z0, z1, kind))
    return rects


def table_legs(parts, xs, ys, z0, z1, color, round_r: float = 0.0, square: float = 0.04) -> None:
    for x in xs:
        for y in ys:
            if round_r > 0:
                parts.append(cylinder(round_r, z1 - z0, x, y, z0, color, 12))
            else:
                parts.append(box(square, square, z1 - z0, x, y, z0, color))


def carcass_parts(rng, W, D, H, col, base: str):
    """Box body with top board and plinth/legs; returns (parts, body_z0, top_z, top_rect)."""
    parts = []
    top_t = uniform(rng, 0.018, 0.03)
    ov = uniform(rng, 0.0, 0.015)
    if base == "legs":
        bh = uniform(rng, 0.08, 0.16)
        table_legs(parts, (-W / 2 + 0.04, W / 2 - 0.04), (-D / 2 + 0.04, D / 2 - 0.04), 0, bh + 0.001, shade(col, 0.6),
              0.015 if rng.random() < 0.5 else 0.0, 0.035)
    elif base == "plinth":
        bh = uniform(rng, 0.05, 0.1)
        parts.append(box(W - 0.04, D - 0.04, bh + 0.001, 0, -0.02, 0, shade(col, 0.6)))
    else:
        bh = 0.0
    parts.append(box(W, D, H - top_t - bh, 0, 0, bh, col))
    parts.append(box(W + 2 * ov, D + ov, top_t, 0, ov / 2, H - top_t, shade(col, 1.05)))
    return parts, bh, H - top_t, (-W / 2 - ov, W / 2 + ov, -D / 2, D / 2 + ov)
