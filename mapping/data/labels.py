"""Category names of a data set's instance ids, from the label files the data sets ship.

- Replica: ``info_semantic.json`` (``objects[*].id`` -> ``class_name``), next to the sequence or in a
  parent folder's ``habitat/`` (vMAP keeps sequences in ``room_0/imap/00`` and the file in
  ``room_0/habitat/``).
- ScanNet: ``<scene>.aggregation.json`` or ``<scene>_vh_clean.aggregation.json`` (``segGroups[*]``:
  ``objectId`` -> ``label``; the ids in ``instance-filt/`` are ``objectId + 1``), with the raw labels
  mapped through ``scannetv2-labels.combined.tsv`` (``raw_category`` -> ``category``) when that table
  is in the scene folder or its parent.

These names become the instances' captions and the vocabulary of zero-shot labelling.
"""

from __future__ import annotations

import csv
from pathlib import Path

from mapping.data.files import DatasetError
from mapping.safe_parse import ParseError, load_json

REPLICA_LABEL_FILE = "info_semantic.json"
SCANNET_LABEL_TABLE = "scannetv2-labels.combined.tsv"


def _read_json(path: Path) -> dict:
    try:
        data = load_json(path)
    except (OSError, ParseError) as e:
        raise DatasetError(f"{path}: cannot read label file ({e})") from None
    if not isinstance(data, dict):
        raise DatasetError(f"{path}: label file must hold a JSON object")
    return data


def find_replica_label_file(root: Path) -> Path | None:
    """``info_semantic.json`` of a Replica sequence: in ``root``, or ``habitat/`` of up to two parents."""
    candidates = [root / REPLICA_LABEL_FILE]
    for parent in list(root.parents)[:2]:
        candidates += [parent / REPLICA_LABEL_FILE, parent / "habitat" / REPLICA_LABEL_FILE]
    return next((p for p in candidates if p.is_file()), None)


def replica_categories(path: Path) -> dict[int, str]:
    """Instance id -> class name of a Replica ``info_semantic.json``."""
    data = _read_json(path)
    objects = data.get("objects")
    if not isinstance(objects, list):
        raise DatasetError(f"{path}: expected an 'objects' list of {{'id', 'class_name'}}")
    out = {}
    for k, obj in enumerate(objects):
        try:
            out[int(obj["id"])] = str(obj["class_name"]).replace("-", " ").replace("_", " ")
        except (KeyError, TypeError, ValueError):
            raise DatasetError(f"{path}: objects[{k}] needs an integer 'id' and a 'class_name'") from None
    return out


def find_scannet_aggregation(root: Path) -> Path | None:
    """``<scene>.aggregation.json`` (or the ``_vh_clean`` variant) of a ScanNet scene folder."""
    for name in (f"{root.name}.aggregation.json", f"{root.name}_vh_clean.aggregation.json"):
        if (root / name).is_file():
            return root / name
    found = sorted(root.glob("*.aggregation.json"))
    return found[0] if found else None


def _scannet_table(root: Path) -> dict[str, str]:
    for folder in (root, root.parent):
        path = folder / SCANNET_LABEL_TABLE
        if path.is_file():
            try:
                with path.open(newline="") as f:
                    return {row["raw_category"]: row["category"] for row in csv.DictReader(f, delimiter="\t")}
            except (OSError, KeyError, csv.Error) as e:
                raise DatasetError(f"{path}: cannot read label table ({e})") from None
    return {}


def scannet_categories(path: Path) -> dict[int, str]:
    """Instance id (``objectId + 1``, as in ``instance-filt/``) -> category of a ScanNet aggregation file."""
    data = _read_json(path)
    groups = data.get("segGroups")
    if not isinstance(groups, list):
        raise DatasetError(f"{path}: expected a 'segGroups' list of {{'objectId', 'label'}}")
    table = _scannet_table(path.parent)
    out = {}
    for k, group in enumerate(groups):
        try:
            raw = str(group["label"])
            out[int(group["objectId"]) + 1] = table.get(raw, raw)
        except (KeyError, TypeError, ValueError):
            raise DatasetError(f"{path}: segGroups[{k}] needs an integer 'objectId' and a 'label'") from None
    return out


def dataset_categories(root: Path, kind: str) -> tuple[dict[int, str], Path | None]:
    """Instance id -> category for a scene folder of layout ``kind``, and the file read (or None)."""
    root = Path(root)
    if kind == "replica":
        path = find_replica_label_file(root)
        return (replica_categories(path), path) if path else ({}, None)
    if kind == "scannet":
        path = find_scannet_aggregation(root)
        return (scannet_categories(path), path) if path else ({}, None)
    return {}, None
