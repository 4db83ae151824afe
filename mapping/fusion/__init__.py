"""Cross-frame fusion of one agent's masks into instances (OpenObj's coarse clustering and fine merge)."""

from mapping.fusion.clustering import CoarseConfig, MaskSet, coarse_clusters, edge_scores
from mapping.fusion.fuse import FusionConfig, fuse_frames, observe_masks
from mapping.fusion.merge import FineConfig, fine_merge, voxel_downsample

__all__ = ["CoarseConfig", "FineConfig", "FusionConfig", "MaskSet", "coarse_clusters", "edge_scores", "fine_merge",
           "fuse_frames", "observe_masks", "voxel_downsample"]
