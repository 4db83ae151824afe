"""Every method of the paper's tables as a configuration of the same code.

One frozen ``Method`` per name: the options of ``openmulti_env.runs.run.run`` (policy, consistency
algorithm, Cross Rendering, instance-level or global map, point-cloud sharing). All of them run the
same agents, channel, front end and evaluation; only these options differ, so a difference in the
tables is the method's. Every agent uses the simulator's ground-truth poses, so Di-NeRF*'s
"ground-truth poses" holds for every method here.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

from mapping.team.global_map import GLOBAL_ENCODING_SCALE, GLOBAL_FORMS


@dataclass(frozen=True)
class Method:
    """A named preset of team options (keyword arguments of ``openmulti_env.runs.run.run``)."""

    name: str
    paper: str
    """The paper's column name."""
    description: str
    policy: str = "always"
    consistency: str = "consensus"
    cross_rendering: bool = True
    global_map: bool = False
    share_point_clouds: bool = False
    alignment: str = "paper"
    agents: int | None = None
    """Fixed number of agents (None: the table's)."""
    missing_edges: str = "skip"
    """DiNNO and DSGD with a vector that did not arrive this round (``ConsistencyConfig.missing_edges``)."""
    global_form: str = "equal_compute"
    """A global map's form (``mapping.team.global_map.GLOBAL_FORMS``): MACIM's ``published`` scene SDF or the
    ``equal_compute`` occupancy network."""

    def __post_init__(self) -> None:
        if self.global_form not in GLOBAL_FORMS:
            raise ValueError(f"method {self.name}: unknown global_form {self.global_form!r}; choose one of {GLOBAL_FORMS}")

    def run_options(self) -> dict:
        """The keyword arguments of ``run`` this method sets."""
        options = {"policy": self.policy, "consistency": self.consistency, "cross_rendering": self.cross_rendering,
                   "global_map": self.global_map, "share_point_clouds": self.share_point_clouds,
                   "alignment": self.alignment}
        if self.consistency in ("dinno", "dsgd"):  # only theirs: the other methods' rows keep their keys
            options["missing_edges"] = self.missing_edges
        if self.global_map and self.global_form == "published":  # MACIM's settings travel with the form
            options["global_form"] = "published"
        elif self.global_map:  # the global network's encoding (a library default) decides its rows too
            options["global_encoding_scale"] = GLOBAL_ENCODING_SCALE
        return options

    def as_dict(self) -> dict:
        return asdict(self)


METHODS: dict[str, Method] = {m.name: m for m in (
    Method("single", "Single", "each of the N agents maps its own data alone, no communication",
           policy="never", consistency="none", cross_rendering=False),
    Method("dsgd_instance", "DSGD_I", "instance-level map, DSGD mixing (Metropolis weights) instead of the "
           "consistency loss, no Cross Rendering", consistency="dsgd", cross_rendering=False),
    Method("dinno_instance", "DiNNO_I", "instance-level map, DiNNO's ADMM updates instead of the consistency "
           "loss, no Cross Rendering", consistency="dinno", cross_rendering=False),
    Method("dinerf_global", "Di-NeRF*", "MACIM's published scene SDF per agent (network, samples, losses, "
           "iteration budget) with DiNNO's ADMM updates, ground-truth poses", consistency="dinno",
           cross_rendering=False, global_map=True, global_form="published"),
    Method("dinerf_global_stale", "Di-NeRF*, stale edges", "Di-NeRF* whose ADMM uses the last vector held "
           "from a peer when this round's did not arrive (Table V's other choice for a missing edge)",
           consistency="dinno", cross_rendering=False, global_map=True, missing_edges="last", global_form="published"),
    Method("macim_global", "MACIM", "MACIM's published scene SDF per agent (network, samples, losses, iteration "
           "budget) with its consistency loss (eq. 12, rho 0.3)", consistency="consensus", cross_rendering=False,
           global_map=True, global_form="published"),
    Method("dinerf_global_equal_compute", "Di-NeRF*, equal compute", "one width-128 occupancy network per agent "
           "with the instance-level map's per-step FLOPs, DiNNO's ADMM updates, ground-truth poses",
           consistency="dinno", cross_rendering=False, global_map=True),
    Method("macim_global_equal_compute", "MACIM, equal compute", "one width-128 occupancy network per agent with "
           "the instance-level map's per-step FLOPs and the consistency loss (eq. 12)", consistency="consensus",
           cross_rendering=False, global_map=True),
    Method("openmulti_no_cross", "w/o Cross Rendering", "OpenMulti without Cross Rendering Supervision (eq. 13)",
           consistency="consensus", cross_rendering=False),
    Method("openmulti_global", "w/o instance-level", "OpenMulti's optimisation (eq. 12 + 13) on a global map",
           consistency="consensus", cross_rendering=True, global_map=True),
    Method("openmulti", "OpenMulti", "instance-level map, consistency loss (eq. 12) and Cross Rendering (eq. 13)",
           consistency="consensus", cross_rendering=True),
    # beyond Table I: the rows of other tables
    Method("pointcloud_sharing", "Point clouds", "each agent sends its observed points (2 cm voxels) instead of "
           "parameters; receivers learn nothing from them (Table VI's bytes)", share_point_clouds=True,
           consistency="none", cross_rendering=False),
    Method("openmulti_no_alignment", "OpenMulti, no alignment", "OpenMulti with every arrived instance adopted "
           "as new (alignment none; Table II's semantic comparison)", alignment="none"),
    Method("single_agent", "Single agent (all frames)", "one agent follows every region's path and maps every "
           "frame (Table III)", policy="never", consistency="none", cross_rendering=False, agents=1),
)}

TABLE_I_METHODS = ("single", "dsgd_instance", "dinno_instance", "dinerf_global", "macim_global",
                   "openmulti_no_cross", "openmulti_global", "openmulti")
"""The DESIGN.md method names, in Table I's order (the ablations last)."""
EQUAL_COMPUTE_METHODS = ("dinerf_global_equal_compute", "macim_global_equal_compute")
"""The global baselines as a width-128 occupancy network with the instance-level map's per-step FLOPs: Table I
shows them beside the published forms, Table IV's "neither" row is the MACIM one."""


def get_method(name: str) -> Method:
    """The method called ``name`` (ValueError listing the known ones)."""
    if name not in METHODS:
        raise ValueError(f"unknown method {name!r}; known methods: {', '.join(METHODS)}")
    return METHODS[name]
