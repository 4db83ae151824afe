"""Real-data loaders on tiny synthetic scenes written to tmp_path (offline, fast)."""

from __future__ import annotations

import re
import warnings

import numpy as np
import pytest
from PIL import Image
from fixtures_datasets import (
    TINY_CAM,
    H,
    W,
    rigid_poses,
    save_png,
    write_nice_slam,
    write_replica,
    write_scannet,
    write_trajectory,
)

from mapping.data import (
    REPLICA_INTRINSICS,
    AgentSequence,
    DatasetError,
    DatasetWarning,
    Intrinsics,
    LazyFrames,
    RGBDDataset,
    detect_layout,
    load_dataset,
    load_nice_slam,
    load_replica,
    load_scannet,
)


def m(text: str) -> str:
    """``pytest.raises(match=...)`` pattern for a literal file name."""
    return re.escape(text)


# --------------------------------------------------------------------------- vMAP Replica


def test_replica_loads_frames_with_dtypes_units_and_ids(tmp_path):
    truth = write_replica(tmp_path)
    ds = load_replica(tmp_path, intrinsics=TINY_CAM)
    assert isinstance(ds, RGBDDataset) and ds.kind == "replica" and len(ds) == 6
    assert ds.intrinsics == Intrinsics(*TINY_CAM)
    for i, f in enumerate(ds):
        assert f.rgb.dtype == np.uint8 and f.rgb.shape == (H, W, 3)
        assert f.depth.dtype == np.float32 and f.depth.shape == (H, W)
        assert f.pose.dtype == np.float64 and f.instance.dtype == np.int32
        np.testing.assert_array_equal(f.rgb, truth.rgb[i])
        np.testing.assert_allclose(f.depth, truth.depth_raw[i] / 1000.0, rtol=1e-6)
        np.testing.assert_allclose(f.pose, truth.poses[i], atol=1e-12)
        np.testing.assert_array_equal(f.instance, truth.instance[i])
        assert f.index == i and f.timestamp == float(i)
        assert f.depth[0, 0] == 0.0  # missing stays 0
    np.testing.assert_allclose(ds.poses, truth.poses, atol=1e-12)


def test_replica_depth_scale_argument(tmp_path):
    truth = write_replica(tmp_path)
    ds = load_replica(tmp_path, intrinsics=TINY_CAM, depth_scale=500.0)
    np.testing.assert_allclose(ds[2].depth, truth.depth_raw[2] / 500.0, rtol=1e-6)
    with pytest.raises(ValueError, match="depth_scale"):
        load_replica(tmp_path, intrinsics=TINY_CAM, depth_scale=0)


def test_replica_intrinsics_forms_and_default(tmp_path):
    write_replica(tmp_path)
    cam = {"W": W, "H": H, "fx": 10.0, "fy": 11.0, "cx": 7.5, "cy": 5.5}  # vMAP config style
    assert load_replica(tmp_path, intrinsics=cam).intrinsics == Intrinsics(*TINY_CAM)
    assert load_replica(tmp_path, intrinsics=Intrinsics(*TINY_CAM)).intrinsics == Intrinsics(*TINY_CAM)
    assert REPLICA_INTRINSICS == Intrinsics(1200, 680, 600.0, 600.0, 599.5, 339.5)
    with pytest.raises(DatasetError, match=m("rgb_0.png") + ".*1200x680"):
        load_replica(tmp_path)  # default camera does not fit 16x12 images


def test_replica_without_instances(tmp_path):
    write_replica(tmp_path, instances=False)
    assert load_replica(tmp_path, intrinsics=TINY_CAM)[0].instance is None
    with pytest.raises(DatasetError, match="semantic_instance"):
        load_replica(tmp_path, intrinsics=TINY_CAM, instances=True)
    write_replica(tmp_path)
    assert load_replica(tmp_path, intrinsics=TINY_CAM, instances=False)[0].instance is None


def test_numeric_sort_of_frame_numbers(tmp_path):
    truth = write_replica(tmp_path, n=12)
    ds = load_replica(tmp_path, intrinsics=TINY_CAM)
    assert ds.indices == list(range(12))
    np.testing.assert_array_equal(ds[10].rgb, truth.rgb[10])  # rgb_10 after rgb_9, not after rgb_1


# --------------------------------------------------------------------------- NICE-SLAM Replica


def test_nice_slam_loads_with_its_depth_scale(tmp_path):
    truth = write_nice_slam(tmp_path)
    ds = load_nice_slam(tmp_path, intrinsics=TINY_CAM)
    assert ds.kind == "nice_slam" and len(ds) == 6 and ds.depth_scale == 6553.5
    f = ds[4]
    assert f.rgb.dtype == np.uint8 and f.rgb.shape == (H, W, 3) and f.instance is None
    np.testing.assert_allclose(f.depth, truth.depth_raw[4] / 6553.5, rtol=1e-6)
    np.testing.assert_allclose(f.pose, truth.poses[4], atol=1e-12)
    with Image.open(tmp_path / "results" / "frame000004.jpg") as im:  # JPEG is lossy: compare decoded
        np.testing.assert_array_equal(f.rgb, np.asarray(im.convert("RGB")))
    with pytest.raises(DatasetError, match="no instance"):
        load_nice_slam(tmp_path, intrinsics=TINY_CAM, instances=True)


# --------------------------------------------------------------------------- ScanNet


def test_scannet_resizes_colour_to_depth_and_reads_ids(tmp_path):
    truth = write_scannet(tmp_path, color_scale=2)
    ds = load_scannet(tmp_path)
    assert ds.kind == "scannet" and len(ds) == 6
    assert ds.intrinsics == Intrinsics(*TINY_CAM)  # from intrinsic_depth.txt at the depth size
    f = ds[3]
    assert f.rgb.shape == (H, W, 3) and f.rgb.dtype == np.uint8
    np.testing.assert_allclose(f.depth, truth.depth_raw[3] / 1000.0, rtol=1e-6)
    np.testing.assert_array_equal(f.instance, truth.instance[3])  # nearest: ids survive the resize
    np.testing.assert_allclose(f.pose, truth.poses[3], atol=1e-12)


def test_scannet_colour_intrinsics_are_scaled_when_depth_intrinsics_missing(tmp_path):
    write_scannet(tmp_path, color_scale=3, depth_intrinsics=False, instances=False)
    ds = load_scannet(tmp_path)
    k = ds.intrinsics
    assert (k.width, k.height) == (W, H)
    np.testing.assert_allclose([k.fx, k.fy, k.cx, k.cy], TINY_CAM[2:])
    assert ds[0].instance is None
    big = Intrinsics(W * 4, H * 4, 40.0, 44.0, 30.0, 22.0)
    assert load_scannet(tmp_path, intrinsics=big).intrinsics == Intrinsics(*TINY_CAM)


def test_scannet_invalid_poses_are_skipped_with_one_warning(tmp_path):
    write_scannet(tmp_path, n=8, invalid=(2, 5))
    with pytest.warns(DatasetWarning, match="skipped 2 frame") as rec:
        ds = load_scannet(tmp_path)
    assert len(rec) == 1
    assert ds.indices == [0, 1, 3, 4, 6, 7] and ds.skipped == [2, 5]
    assert [f.index for f in ds] == ds.indices
    with pytest.raises(DatasetError, match=m("2.txt")):
        load_scannet(tmp_path, invalid_pose="error")
    with pytest.raises(ValueError, match="invalid_pose"):
        load_scannet(tmp_path, invalid_pose="ignore")


def test_scannet_all_invalid_is_an_error(tmp_path):
    write_scannet(tmp_path, n=3, invalid=(0, 1, 2))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DatasetWarning)
        with pytest.raises(DatasetError, match="invalid pose"):
            load_scannet(tmp_path)


def test_scannet_missing_intrinsics_and_bad_pose_file(tmp_path):
    write_scannet(tmp_path, depth_intrinsics=False)
    (tmp_path / "intrinsic" / "intrinsic_color.txt").unlink()
    with pytest.raises(DatasetError, match="intrinsic_depth.txt.*intrinsic_color.txt"):
        load_scannet(tmp_path)
    assert len(load_scannet(tmp_path, intrinsics=TINY_CAM)) == 6
    (tmp_path / "pose" / "4.txt").write_text("1 0 0\n")
    with pytest.raises(DatasetError, match=m("4.txt") + ".*16 numbers"):
        load_scannet(tmp_path, intrinsics=TINY_CAM)


# --------------------------------------------------------------------------- auto detection


@pytest.mark.parametrize(
    "writer, kind", [(write_replica, "replica"), (write_nice_slam, "nice_slam"), (write_scannet, "scannet")]
)
def test_auto_detection(tmp_path, writer, kind):
    writer(tmp_path)
    assert detect_layout(tmp_path) == kind
    kw = {} if kind == "scannet" else {"intrinsics": TINY_CAM}
    ds = load_dataset(tmp_path, **kw)
    assert ds.kind == kind and len(ds) == 6
    assert load_dataset(str(tmp_path), kind=kind, **kw).kind == kind


def test_detection_failure_lists_what_was_looked_for(tmp_path):
    (tmp_path / "rgb").mkdir()
    with pytest.raises(DatasetError, match="traj_w_c.txt") as e:
        load_dataset(tmp_path)
    for marker in ("results/", "traj.txt", "color/", "pose/"):
        assert marker in str(e.value)
    with pytest.raises(DatasetError, match="does not exist"):
        load_dataset(tmp_path / "nope")
    with pytest.raises(ValueError, match="kind"):
        load_dataset(tmp_path, kind="tum")


# --------------------------------------------------------------------------- splits, stride, laziness


@pytest.mark.parametrize("n_agents", [2, 3])
def test_contiguous_split_covers_all_frames_once(tmp_path, n_agents):
    write_replica(tmp_path, n=7)
    ds = load_replica(tmp_path, intrinsics=TINY_CAM)
    parts = ds.split(n_agents)
    assert [p.agent_id for p in parts] == list(range(n_agents))
    assert all(isinstance(p, AgentSequence) and isinstance(p.frames, LazyFrames) for p in parts)
    seen = [f.index for p in parts for f in p]
    assert seen == list(range(7))  # contiguous, in order, no overlap, nothing missing
    assert max(len(p) for p in parts) - min(len(p) for p in parts) <= 1


def test_interleaved_split_and_bad_mode(tmp_path):
    write_replica(tmp_path)
    ds = load_replica(tmp_path, intrinsics=TINY_CAM)
    parts = ds.split(2, mode="interleaved")
    assert [p.frames.indices for p in parts] == [[0, 2, 4], [1, 3, 5]]
    with pytest.raises(ValueError, match="mode"):
        ds.split(2, mode="random")
    with pytest.raises(ValueError):
        ds.split(7)


def test_stride_and_max_frames(tmp_path):
    truth = write_replica(tmp_path, n=10)
    ds = load_replica(tmp_path, intrinsics=TINY_CAM, stride=3)
    assert ds.indices == [0, 3, 6, 9]
    np.testing.assert_allclose(ds[2].pose, truth.poses[6], atol=1e-12)
    assert load_replica(tmp_path, intrinsics=TINY_CAM, stride=2, max_frames=3).indices == [0, 2, 4]
    write_scannet(tmp_path / "sn", n=10, invalid=(3,))
    with pytest.warns(DatasetWarning):
        assert load_scannet(tmp_path / "sn", stride=3, max_frames=2).indices == [0, 6]
    with pytest.raises(ValueError, match="stride"):
        load_replica(tmp_path, intrinsics=TINY_CAM, stride=0)


def test_frames_are_read_lazily(tmp_path):
    write_replica(tmp_path)
    ds = load_replica(tmp_path, intrinsics=TINY_CAM)
    (tmp_path / "rgb" / "rgb_4.png").unlink()  # loading kept paths only
    assert ds[3].index == 3 and len(ds[1:4]) == 3 and ds[1:4].indices == [1, 2, 3]
    assert ds.split(2)[0].poses.shape == (3, 4, 4)
    with pytest.raises(DatasetError, match=m("rgb_4.png")):
        ds[4]


# --------------------------------------------------------------------------- errors


def test_missing_folder(tmp_path):
    write_replica(tmp_path)
    for p in (tmp_path / "depth").iterdir():
        p.unlink()
    (tmp_path / "depth").rmdir()
    with pytest.raises(DatasetError, match=m(str(tmp_path / "depth")) + ".*missing folder"):
        load_replica(tmp_path, intrinsics=TINY_CAM)


def test_corrupt_image_is_reported_at_frame_read(tmp_path):
    write_replica(tmp_path)
    (tmp_path / "depth" / "depth_2.png").write_bytes(b"\x89PNG not really")
    ds = load_replica(tmp_path, intrinsics=TINY_CAM)  # load only checks names and counts
    with pytest.raises(DatasetError, match=m("depth_2.png") + ".*cannot read"):
        ds[2]
    truncated = (tmp_path / "rgb" / "rgb_1.png").read_bytes()[:60]
    (tmp_path / "rgb" / "rgb_1.png").write_bytes(truncated)
    with pytest.raises(DatasetError, match=m("rgb_1.png")):
        ds[1]


def test_mismatched_counts(tmp_path):
    write_replica(tmp_path, n=10)
    (tmp_path / "depth" / "depth_9.png").unlink()
    with pytest.raises(DatasetError, match=m("rgb_9.png") + ".*rgb/ has 10, depth/ has 9"):
        load_replica(tmp_path, intrinsics=TINY_CAM)
    (tmp_path / "rgb" / "rgb_9.png").unlink()
    (tmp_path / "semantic_instance" / "semantic_instance_9.png").unlink()
    write_trajectory(tmp_path / "traj_w_c.txt", rigid_poses(8))
    with pytest.raises(DatasetError, match=m("traj_w_c.txt") + ".*8 poses.*9 frames"):
        load_replica(tmp_path, intrinsics=TINY_CAM)


def test_frame_numbers_must_match_trajectory_lines(tmp_path):
    write_replica(tmp_path, n=4, instances=False)
    for d, pre in (("rgb", "rgb_"), ("depth", "depth_")):
        (tmp_path / d / f"{pre}3.png").rename(tmp_path / d / f"{pre}7.png")
    with pytest.raises(DatasetError, match="frame 3 is missing"):
        load_replica(tmp_path, intrinsics=TINY_CAM)


def test_duplicate_frame_number(tmp_path):
    write_replica(tmp_path)
    (tmp_path / "rgb" / "rgb_01.png").write_bytes((tmp_path / "rgb" / "rgb_1.png").read_bytes())
    with pytest.raises(DatasetError, match="rgb_0?1.png.*also used by"):
        load_replica(tmp_path, intrinsics=TINY_CAM)


def test_trajectory_line_without_16_numbers(tmp_path):
    write_replica(tmp_path)
    lines = (tmp_path / "traj_w_c.txt").read_text().splitlines()
    lines[2] = " ".join(lines[2].split()[:15])
    (tmp_path / "traj_w_c.txt").write_text("\n".join(lines) + "\n")
    with pytest.raises(DatasetError, match=m("traj_w_c.txt:line 3") + ".*got 15"):
        load_replica(tmp_path, intrinsics=TINY_CAM)
    lines[2] = lines[3].replace(lines[3].split()[0], "abc", 1)
    (tmp_path / "traj_w_c.txt").write_text("\n".join(lines) + "\n")
    with pytest.raises(DatasetError, match=m("traj_w_c.txt:line 3") + ".*not a number"):
        load_replica(tmp_path, intrinsics=TINY_CAM)


def test_non_finite_and_non_rigid_replica_poses(tmp_path):
    write_replica(tmp_path)
    poses = rigid_poses(6)
    poses[4, 0, 3] = np.nan
    write_trajectory(tmp_path / "traj_w_c.txt", poses)
    with pytest.raises(DatasetError, match=m("traj_w_c.txt:pose 4") + ".*non-finite"):
        load_replica(tmp_path, intrinsics=TINY_CAM)
    write_trajectory(tmp_path / "traj_w_c.txt", rigid_poses(6).transpose(0, 2, 1))  # column-major
    with pytest.raises(DatasetError, match=m("traj_w_c.txt") + ".*last pose row"):
        load_replica(tmp_path, intrinsics=TINY_CAM)
    for (k, i, j), value, message in (((1, 0, 0), 5.0, "rotation has an entry beyond 1"),  # scaled
                                      ((2, 0, 1), 1e308, "rotation has an entry beyond 1"),  # points overflow
                                      ((3, 1, 1), 0.9, "rotation is not orthonormal"),  # squashed, entries <= 1
                                      ((5, 0, 3), 1e200, "over 100000 m")):
        poses = rigid_poses(6)
        poses[k, i, j] = value
        write_trajectory(tmp_path / "traj_w_c.txt", poses)
        with pytest.raises(DatasetError, match=m(f"traj_w_c.txt:pose {k}") + f".*{message}"):
            load_replica(tmp_path, intrinsics=TINY_CAM)


def test_nice_slam_trajectory_count(tmp_path):
    write_nice_slam(tmp_path)
    write_trajectory(tmp_path / "traj.txt", rigid_poses(5))
    with pytest.raises(DatasetError, match=m("traj.txt") + ".*5 poses.*6 frames"):
        load_nice_slam(tmp_path, intrinsics=TINY_CAM)


def test_wrong_image_sizes(tmp_path):
    write_replica(tmp_path)
    save_png(tmp_path / "depth" / "depth_2.png", np.zeros((H - 2, W), np.uint16))
    save_png(tmp_path / "semantic_instance" / "semantic_instance_3.png", np.zeros((H, W + 1), np.uint8))
    ds = load_replica(tmp_path, intrinsics=TINY_CAM)
    with pytest.raises(DatasetError, match=m("depth_2.png") + f".*{W}x{H - 2}, expected {W}x{H}"):
        ds[2]
    with pytest.raises(DatasetError, match=m("semantic_instance_3.png")):
        ds[3]
    save_png(tmp_path / "depth" / "depth_1.png", np.zeros((H, W, 3), np.uint8))
    with pytest.raises(DatasetError, match=m("depth_1.png") + ".*mode 'RGB'"):
        ds[1]


def test_scannet_depth_size_mismatch_is_reported(tmp_path):
    write_scannet(tmp_path)
    save_png(tmp_path / "depth" / "5.png", np.zeros((H * 2, W * 2), np.uint16))
    ds = load_scannet(tmp_path)
    with pytest.raises(DatasetError, match=re.escape(str(tmp_path / "depth" / "5.png"))):
        ds[5]


def save_float_depth(path, depth):
    """A float depth image (TIFF) under the PNG name the layout expects: Pillow reads images by content."""
    Image.fromarray(depth.astype(np.float32)).save(path, format="TIFF")


@pytest.mark.parametrize("fill", [np.nan, np.inf, -2.0, 0.0])
def test_a_depth_frame_without_a_valid_pixel_is_an_empty_frame_with_a_warning(tmp_path, fill):
    write_replica(tmp_path)
    save_float_depth(tmp_path / "depth" / "depth_2.png", np.full((H, W), fill))
    ds = load_replica(tmp_path, intrinsics=TINY_CAM)
    with pytest.warns(DatasetWarning, match=m(str(tmp_path / "depth" / "depth_2.png")) + ": no valid depth pixel.*"
                      "kept as an empty frame") as caught:
        frame = ds[2]
    assert len(caught) == 1 and not frame.depth.any() and frame.backproject().shape == (0, 3)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        ds[1]  # a frame with depth: no warning


def test_nan_inf_and_negative_depth_pixels_become_missing(tmp_path):
    write_replica(tmp_path)
    depth = np.full((H, W), np.nan)
    depth[: H // 2] = 2500.0  # 2.5 m at the default 1000 units per metre
    depth[0, :3] = np.inf, -np.inf, -7.0
    save_float_depth(tmp_path / "depth" / "depth_2.png", depth)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # also no numpy RuntimeWarning
        frame = load_replica(tmp_path, intrinsics=TINY_CAM)[2]
    assert np.isfinite(frame.depth).all() and (frame.depth >= 0).all()
    np.testing.assert_allclose(frame.depth[frame.depth > 0], 2.5)
    assert (frame.depth > 0).sum() == H // 2 * W - 3
    points = frame.backproject()
    assert len(points) == H // 2 * W - 3 and np.isfinite(points).all()
