"""Which cells of an instance's observed space may hold surface: the rules side by side on one finished run.

Reloads a finished simulated run's team from its checkpoint (``OUT/checkpoints/team.pt``: the networks and
each instance's observed space), meshes every agent's instances without any mask, then keeps the faces each
rule allows and ray casts the result from every 5th of the agent's input poses against its sensor depth
(``mapping.evaluate.depth_check``). The networks are the same under every rule: only meshing differs.

Rules (``RULES``): ``none`` (the whole box, as before issue 44); ``reach1`` (within one cell of a surface
cell: the package's rule, ``ObservedSpace.surface_reach``); ``reach0`` (surface cells only); ``reach1-free``
and ``reach0-free`` (the same without cells a ray saw free).

    .venv/bin/python -m studies.observed_rules runs/demo

(the run must have kept observed spaces: ``MappingConfig.observed_cell_m`` not None).

Figures: docs/observed_space.md#measured
"""

from __future__ import annotations

import argparse

import numpy as np
from scipy.ndimage import binary_dilation

from mapping.evaluate.depth_check import depth_check
from mapping.evaluate.meshing import merge_instance_meshes
from mapping.model.observed import FREE, SURFACE, ObservedSpace
from mapping.model.observed_field import observed_faces
from mapping.perception import shared_text_encoder
from mapping.team import Team
from openmulti_env.experiment import read_config, resolved_team
from openmulti_env.runs.run import map_structure
from openmulti_env.runs.sim_source import SimulatedSource
from openmulti_env.world import World

RULES: dict[str, tuple[int, bool] | None] = {"none": None, "reach1": (1, False), "reach0": (0, False),
                                             "reach1-free": (1, True), "reach0-free": (0, True)}
"""Rule name -> (cells of reach around a surface cell, whether cells seen free are excluded); None: no mask."""


def allowed_cells(space: ObservedSpace, reach: int, without_free: bool) -> np.ndarray:
    """(X, Y, Z) bool: the cells where the rule lets the map hold surface."""
    surface = space.states == SURFACE
    allowed = binary_dilation(surface, np.ones((3, 3, 3), bool), iterations=reach) if reach else surface
    return allowed & (space.states != FREE) if without_free else allowed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run", help="a finished `openmulti run --scene ...` folder")
    args = parser.parse_args()
    tree = read_config(f"{args.run}/config.yaml")
    world = World.build(tree.scene, seed=tree.seed, config=tree.world)
    source = SimulatedSource(world, tree.seed, shared_text_encoder(name=tree.perception.text_encoder), None,
                             tree.perception.segmentation_errors)
    mapping, _ = map_structure(world, tree)
    team = Team(source.streams(), resolved_team(tree, mapping), source.vocabulary(), seed=tree.seed,
                channel=tree.channel, device="cpu")
    team.load(f"{args.run}/checkpoints/team.pt")
    off: dict[str, list[tuple[float, float]]] = {name: [] for name in RULES}
    for index, member in enumerate(team.members):
        spaces = member.mapper.observed.spaces
        member.mapper.observed.spaces = {}  # mesh without any mask ...
        raw = member.mapper.instance_meshes()
        member.mapper.observed.spaces = spaces  # ... then apply each rule to the same meshes
        frames = source.agent_frames(index, 5)
        for name, rule in RULES.items():
            meshes = {}
            for iid, mesh in raw.items():
                kept = mesh if rule is None or iid not in spaces else observed_faces(mesh, spaces[iid],
                                                                                     allowed_cells(spaces[iid], *rule))
                if kept is not None:
                    meshes[iid] = kept
            check = depth_check(merge_instance_meshes(meshes)[0] if meshes else None, frames, stride=4)
            off[name].append((check.off_pct, check.no_surface_pct))
            print(f"agent_{index} {name:<12} off {check.off_pct:6.2f} %  no surface {check.no_surface_pct:6.2f} %",
                  flush=True)
    print(f"\n{'rule':<12} {'mean off %':>10} {'max off %':>10} {'no surface %':>13}")
    for name, values in off.items():
        v = np.array(values)
        print(f"{name:<12} {v[:, 0].mean():>10.2f} {v[:, 0].max():>10.2f} {v[:, 1].mean():>13.2f}")


if __name__ == "__main__":
    main()
