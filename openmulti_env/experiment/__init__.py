"""One configuration tree per experiment (``tree``), built as a preset plus overrides (``build``,
``overrides``), written whole and read back (``files``), and the command line generated from it
(``options``)."""

from openmulti_env.experiment.build import check, experiment, resolved_team
from openmulti_env.experiment.files import (CONFIG_NAME, checkpoint_identity, experiment_from_record,
                                            read_checkpoint_identity, read_config, tree_record, write_config)
from openmulti_env.experiment.overrides import ALIASES, ConfigError, apply_overrides
from openmulti_env.experiment.tree import DataSettings, EnvSettings, Experiment, GlobalMapSettings, PerceptionSettings
from mapping.pipeline.settings import RunSettings

__all__ = ["ALIASES", "CONFIG_NAME", "ConfigError", "DataSettings", "EnvSettings", "Experiment", "GlobalMapSettings",
           "PerceptionSettings", "RunSettings", "apply_overrides", "check", "checkpoint_identity", "experiment",
           "experiment_from_record", "read_checkpoint_identity", "read_config", "resolved_team", "tree_record",
           "write_config"]
