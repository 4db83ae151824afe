"""Frames and per-agent sequences; loaders for Replica (vMAP and NICE-SLAM layouts) and ScanNet."""

from mapping.data.files import DatasetError, DatasetWarning
from mapping.data.frame import (AgentSequence, Frame, Intrinsics, backproject_depth, backproject_pixels,
                                split_contiguous)
from mapping.data.dataset import LazyFrames, RGBDDataset
from mapping.data.loaders import detect_layout, load_dataset
from mapping.data.replica import REPLICA_INTRINSICS, load_nice_slam, load_replica
from mapping.data.scannet import load_scannet

__all__ = [
    "AgentSequence",
    "DatasetError",
    "DatasetWarning",
    "Frame",
    "Intrinsics",
    "LazyFrames",
    "REPLICA_INTRINSICS",
    "RGBDDataset",
    "backproject_depth",
    "backproject_pixels",
    "detect_layout",
    "load_dataset",
    "load_nice_slam",
    "load_replica",
    "load_scannet",
    "split_contiguous",
]
