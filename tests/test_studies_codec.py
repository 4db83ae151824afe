"""The codec study's pieces: every named setting is a valid command line and codec, and its table reads rows."""

from __future__ import annotations

from pathlib import Path

from openmulti_env.experiment import experiment
from studies.codec_front import SETTINGS, cell_table, codec_options, run_command


def test_every_named_setting_is_a_codec_the_command_line_takes():
    from openmulti_env.runs.cli import build_parser

    for name in SETTINGS:
        argv = run_command("room1", 3, "always", name, "range", Path("/tmp/x"))
        args = build_parser().parse_args(argv[argv.index("run"):])
        assert args.func.__name__ == "cmd_run"
        pairs = dict(zip(codec_options(name)[0::2], codec_options(name)[1::2]))
        tree = experiment("fast", **{k[2:].replace("-", "_"): v == "true" if v in ("true", "false") else
                                     float(v) if "." in v else int(v) if v.isdigit() else v for k, v in pairs.items()})
        assert tree.team.exchange.codec.active == (name != "float32")


def test_the_table_reads_each_cell_against_float32_always():
    rows = [{"scene": "room1", "seed": 3, "scenario": "unlimited", "policy": "always", "setting": "float32",
             "comp_ratio": 93.0, "mb": 200.0},
            {"scene": "room1", "seed": 3, "scenario": "unlimited", "policy": "always", "setting": "8d10",
             "comp_ratio": 92.5, "mb": 10.0}]
    table = cell_table(rows)
    assert "| room1 s3 | `always` | 8d10 | 92.50 | 10.0 | 5.0 % | -0.50 |" in table


def test_a_messages_bytes_are_cut_into_its_parts_sealed_or_not():
    import numpy as np

    from mapping.team import InstancePayload, ParameterMessage, to_bytes
    from mapping.team.codec import encode_vector
    from studies.message_bytes import wire_parts

    params = np.ones(400, np.float32)
    code, _ = encode_vector(params, 8, 64)
    inst = InstancePayload(1, "object", params, np.zeros(3, np.float32), np.ones(3, np.float32),
                           np.zeros(3, np.float32), 0.5, 0, 0, "a chair", np.ones(8, np.float32), 0.5, None, None, code)
    for lossless in ("none", "zstd"):
        data = to_bytes(ParameterMessage(0, 1, 2, [inst], 1, lossless))
        kind, parts = wire_parts(data)
        assert kind == "params" and parts["params.q"] == 400 and parts["params.scale"] == 7 * 4
        assert sum(parts.values()) == len(data) and ("lossless" in parts) == (lossless == "zstd")


def test_the_pick_is_the_fewest_bytes_within_the_points_on_every_validation_cell():
    from studies.codec_front import pick_setting

    def row(scene, setting, comp, mb):
        return {"scene": scene, "seed": 0, "scenario": "unlimited", "policy": "always", "setting": setting,
                "comp_ratio": comp, "mb": mb}
    rows = [row("a", "float32", 90.0, 100.0), row("a", "8d10", 89.8, 15.0), row("a", "4d5", 89.2, 8.0),
            row("b", "float32", 91.0, 100.0), row("b", "8d10", 90.9, 14.0), row("b", "4d5", 90.8, 7.0)]
    assert pick_setting(rows, 0.5) == "8d10"  # 4d5 is 0.8 below on cell a
    assert pick_setting(rows, 1.0) == "4d5"
    assert pick_setting(rows, 0.1) == "float32"
