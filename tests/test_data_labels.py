"""Category names from the data sets' label files, and cam_params.json."""

from __future__ import annotations

import json

import pytest

from mapping.data import DatasetError
from mapping.data.labels import dataset_categories, replica_categories


def test_replica_info_semantic_is_found_in_the_habitat_folder_of_a_vmap_sequence(tmp_path):
    seq = tmp_path / "room_0" / "imap" / "00"
    seq.mkdir(parents=True)
    (tmp_path / "room_0" / "habitat").mkdir()
    (tmp_path / "room_0" / "habitat" / "info_semantic.json").write_text(json.dumps(
        {"objects": [{"id": 3, "class_name": "sofa"}, {"id": 9, "class_name": "wall-plug"}]}))
    categories, path = dataset_categories(seq, "replica")
    assert categories == {3: "sofa", 9: "wall plug"} and path.parent.name == "habitat"
    assert dataset_categories(seq, "nice_slam") == ({}, None)


def test_scannet_aggregation_ids_are_object_id_plus_one_and_the_label_table_maps_raw_names(tmp_path):
    scene = tmp_path / "scene0005_00"
    scene.mkdir()
    (scene / "scene0005_00.aggregation.json").write_text(json.dumps(
        {"segGroups": [{"objectId": 0, "label": "office chair"}, {"objectId": 4, "label": "window"}]}))
    (tmp_path / "scannetv2-labels.combined.tsv").write_text(
        "id\traw_category\tcategory\tcount\nx\toffice chair\tchair\t10\n")
    categories, _ = dataset_categories(scene, "scannet")
    assert categories == {1: "chair", 5: "window"}


def test_broken_label_files_name_the_file(tmp_path):
    bad = tmp_path / "info_semantic.json"
    bad.write_text("{not json")
    with pytest.raises(DatasetError, match="info_semantic.json: cannot read"):
        replica_categories(bad)
    bad.write_text(json.dumps({"objects": [{"id": "x"}]}))
    with pytest.raises(DatasetError, match=r"objects\[0\]"):
        replica_categories(bad)
