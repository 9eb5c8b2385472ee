"""Structure from motion on frames folders (evdense.sfm), on our simulator's ground-truth frames."""

from __future__ import annotations

import json
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pycolmap
import pytest
from scipy import ndimage

from evdense.camera import Camera
from evdense.config import validate_config
from evdense.evaluate.align import align_trajectory_to_gt
from evdense.formats.frames import Frame, read_frames
from evdense.poses import read_tum
from evdense.sfm import (
    SfmConfig,
    SfmError,
    read_sfm_trajectory,
    run_sfm,
    select_frames,
    set_options,
)
from evdense.sfm.stage import _calibrated_camera

# Half the DAVIS346 resolution keeps SfM at a few seconds; f = 125 px, ~50 deg horizontal FoV.
SMALL_CAMERA = {"width": 173, "height": 130, "fx": 125.0, "fy": 125.0, "cx": 86.0, "cy": 64.5}


@pytest.fixture(scope="module")
def desk_gt(tmp_path_factory) -> Path:
    """Ground truth of the `desk` preset at 4x speed (1 s, 20 frames at 20 Hz), 173x130."""
    from evdense.sim.groundtruth import write_groundtruth

    cfg = validate_config(
        {
            "datasets": {"desk": {"scene": "desk", "speed": 4}},
            # the camera's 20 frames, not the oracle's minimum of 60
            "simulator": {"render": {"camera": dict(SMALL_CAMERA), "gt_min_frames": 0}},
        }
    )
    out = tmp_path_factory.mktemp("desk") / "gt"
    write_groundtruth(cfg["datasets"]["desk"], cfg["simulator"], out)
    return out


def _centre_errors(sfm_dir: Path, gt_dir: Path):
    t_est, T_est = read_sfm_trajectory(sfm_dir)
    t_gt, T_gt = read_tum(gt_dir / "trajectory.txt")
    return align_trajectory_to_gt(t_est, T_est, t_gt, T_gt)


def _write_frames(folder: Path, images: list[np.ndarray]) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for i, img in enumerate(images):
        iio.imwrite(folder / f"{i:06d}.png", img)
    (folder / "timestamps.txt").write_text(
        "".join(f"{i} {0.05 * i:.6f}\n" for i in range(len(images)))
    )
    return folder


@pytest.fixture
def noise_frames(tmp_path, rng) -> Path:
    """Eight frames of independent blurred noise: plenty of SIFT features, nothing shared."""
    images = []
    for _ in range(8):
        img = ndimage.gaussian_filter(rng.standard_normal((130, 173)), 1.5) * 3 + 0.5
        images.append((np.clip(img, 0, 1) * 255).astype(np.uint8))
    return _write_frames(tmp_path / "noise", images)


# ---- the whole stage on simulated frames -------------------------------------------------------
@pytest.mark.slow
def test_gt_frames_register_with_focal_and_centres_close_to_gt(desk_gt, tmp_path):
    out = tmp_path / "sfm" / "gt"
    stats = run_sfm(desk_gt / "frames", out, {}, num_threads=2)

    n = len(read_frames(desk_gt / "frames"))
    assert stats["num_registered"] == n == 20
    # Estimated intrinsics (SIMPLE_RADIAL, principal point fixed at the centre): f within 2 %.
    assert stats["camera"]["focal_length"] == pytest.approx(SMALL_CAMERA["fx"], rel=0.02)
    assert stats["mean_reprojection_error_px"] < 1.0
    # The method's target: camera centres within 1 % of the path length after Sim(3) alignment.
    # Measured ~0.15 %: SIFT locates points to ~0.2 px at f = 125 px, 1-3 m away, i.e. a few
    # millimetres per camera on a 1.9 m path; 1 % (19 mm) leaves room for RANSAC's randomness
    # while still failing on a wrong focal length or a flipped/partial model.
    ce = _centre_errors(out, desk_gt)
    assert len(ce.errors) == n
    assert ce.rmse < 0.01 * ce.trajectory_length
    assert ce.max < 0.02 * ce.trajectory_length

    # Outputs: binary + text model, database, PLY, stats, selection; nothing half-written left.
    for rel in (
        "sparse/0/cameras.bin",
        "sparse/0/images.bin",
        "sparse/0/points3D.bin",
        "sparse/0_text/cameras.txt",
        "sparse/0_text/images.txt",
        "sparse/0_text/points3D.txt",
        "database.db",
        "points3D.ply",
        "stats.json",
        "selected_frames.txt",
        "trajectory.txt",
    ):
        assert (out / rel).is_file(), rel
    assert not out.with_name("gt.partial").exists()
    rec = pycolmap.Reconstruction(out / "sparse" / "0")
    assert rec.num_reg_images() == n and rec.num_points3D() == stats["num_points3D"] > 100
    on_disk = json.loads((out / "stats.json").read_text())
    assert on_disk["num_registered"] == n
    assert set(on_disk["time_s"]) >= {"extract_s", "match_s", "map_s", "total_s"}


@pytest.mark.slow
def test_fixed_calibration_keeps_intrinsics_exactly(desk_gt, tmp_path):
    out = tmp_path / "sfm_calib"
    stats = run_sfm(desk_gt, out, {"calibration": str(desk_gt / "intrinsics.yaml")}, num_threads=2)
    cam = stats["camera"]
    assert stats["intrinsics_fixed"] and cam["model"] == "PINHOLE"
    # evdense puts the top-left pixel centre at (0, 0), COLMAP at (0.5, 0.5): the round trip is exact
    assert (cam["focal_length_x"], cam["cx"], cam["cy"]) == pytest.approx(
        (125.0, 86.0, 64.5), abs=1e-9
    )
    assert cam["params_colmap"][2:4] == pytest.approx([86.5, 65.0], abs=1e-9)
    assert stats["num_registered"] == 20
    assert _centre_errors(out, desk_gt).rmse_rel < 0.01


@pytest.mark.slow
def test_sequential_matching_with_loop_closure_pairs(desk_gt, tmp_path):
    out = tmp_path / "sfm_seq"
    conf = {
        "matcher": "sequential",
        "pairing": {"overlap": 2, "quadratic_overlap": False},
        "loop_keyframe_every": 5,
        "select": "every_k",
        "select_every_k": 2,
    }
    stats = run_sfm(desk_gt, out, conf, num_threads=2)
    selected = (out / "selected_frames.txt").read_text().split("\n")[1:-1]
    assert [line.split()[1] for line in selected] == [f"{i:06d}.png" for i in range(0, 20, 2)] + [
        "000019.png"
    ]
    assert stats["num_registered"] == stats["num_selected"] == 11

    db = pycolmap.Database.open(out / "database.db")
    try:
        ids = {im.name: im.image_id for im in db.read_all_images()}
        matched = lambda a, b: db.exists_matches(ids[f"{a:06d}.png"], ids[f"{b:06d}.png"])  # noqa: E731
        assert matched(0, 2) and matched(0, 4)  # neighbours within the overlap
        assert matched(0, 10) and matched(0, 19)  # keyframes (selected 0, 5, 10 = frames 0, 10, 19)
        assert not matched(0, 8)  # neither a neighbour nor a keyframe pair
        assert db.num_matched_image_pairs() < 11 * 10 // 2
    finally:
        db.close()


def test_frames_sharing_nothing_raise_a_clear_error(noise_frames, tmp_path):
    out = tmp_path / "sfm_noise"
    with pytest.raises(
        SfmError, match=r"verified pairs .*Diagnostics: .*diagnostics\.json"
    ) as info:
        run_sfm(noise_frames, out, {}, num_threads=2)
    assert not out.exists()
    diag = json.loads(info.value.diagnostics_path.read_text())
    assert diag["registered"] < 3 and diag["selected"] == 8
    assert diag["features_per_image"]["min"] > 100  # features were found; they just match nothing
    assert diag["verified_pairs"] == 0


# ---- options, frames folders, selection (no SfM run) --------------------------------------------
def test_unknown_pycolmap_option_names_the_key_before_writing(noise_frames, tmp_path):
    out = tmp_path / "sfm_bad"
    with pytest.raises(
        ValueError, match=r"sfm\.extraction\.sift\.max_num_featurez.*SiftExtractionOptions"
    ):
        run_sfm(noise_frames, out, {"extraction": {"sift": {"max_num_featurez": 10}}})
    with pytest.raises(ValueError, match=r"sfm: unknown keys \['matchr'\]"):
        run_sfm(noise_frames, out, {"matchr": "exhaustive"})
    with pytest.raises(ValueError, match=r"sfm\.matcher"):
        run_sfm(noise_frames, out, {"matcher": "vocab"})
    with pytest.raises(ValueError, match=r"sfm\.calibration': no such file"):
        run_sfm(noise_frames, out, {"calibration": str(tmp_path / "missing.yaml")})
    assert not out.exists() and not out.with_name("sfm_bad.partial").exists()


def test_set_options_nested_dotted_enum_and_types():
    opts = set_options(
        pycolmap.IncrementalPipelineOptions(),
        {
            "mapper": {"init_min_tri_angle": 8, "image_selection_method": "MAX_VISIBLE_POINTS_NUM"},
            "triangulation.min_angle": 2.0,
            "ba_global_max_num_iterations": 30.0,  # integral float from YAML is accepted
            "multiple_models": "false",  # as handed by snakemake --config
            "min_num_matches": "20",
        },
        "sfm.mapping",
    )
    assert opts.mapper.init_min_tri_angle == 8.0
    assert (
        opts.mapper.image_selection_method == pycolmap.ImageSelectionMethod.MAX_VISIBLE_POINTS_NUM
    )
    assert opts.triangulation.min_angle == 2.0
    assert opts.ba_global_max_num_iterations == 30 and opts.multiple_models is False
    assert opts.min_num_matches == 20
    with pytest.raises(
        ValueError, match=r"sfm\.mapping\.mapper\.image_selection_method.*not one of"
    ):
        set_options(opts, {"mapper": {"image_selection_method": "BEST"}}, "sfm.mapping")
    with pytest.raises(ValueError, match=r"sfm\.mapping\.ba_global_max_num_iterations.*integer"):
        set_options(opts, {"ba_global_max_num_iterations": 2.5}, "sfm.mapping")
    with pytest.raises(
        ValueError, match=r"sfm\.mapping\.min_num_matches': cannot set 'many' \(str\); expected int"
    ):
        set_options(opts, {"min_num_matches": "many"}, "sfm.mapping")
    with pytest.raises(ValueError, match=r"sfm\.mapping\.min_num_matches.*not a group"):
        set_options(opts, {"min_num_matches": {"x": 1}}, "sfm.mapping")


def test_select_frames_every_k_count_and_change(tmp_path):
    # frames 0-4 identical, 5-9 a different pattern: change keeps 0, 5 and the last
    a = np.zeros((32, 32), np.uint8)
    b = np.full((32, 32), 200, np.uint8)
    folder = _write_frames(tmp_path / "f", [a] * 5 + [b] * 5)
    frames = read_frames(folder)
    pick = lambda **kw: [f.index for f in select_frames(frames, folder, SfmConfig(**kw))]  # noqa: E731
    assert pick(select="all") == list(range(10))
    assert pick(select="every_k", select_every_k=4) == [0, 4, 8, 9]
    assert pick(select="count", select_count=4) == [0, 3, 6, 9]
    assert pick(select="count", select_count=50) == list(range(10))
    assert pick(select="change", select_min_change=0.1) == [0, 5, 9]
    assert isinstance(frames[0], Frame)


def test_calibration_is_rescaled_to_the_frames(tmp_path):
    path = tmp_path / "calib.yaml"
    Camera(346, 260, 250.0, 250.0, 172.5, 129.5).write_yaml(path)
    cam = _calibrated_camera(SfmConfig(calibration=str(path)), 173, 130)
    assert (cam.width, cam.height, cam.fx, cam.cx, cam.cy) == (173, 130, 125.0, 86.0, 64.5)
    with pytest.raises(ValueError, match="different aspect ratio"):
        _calibrated_camera(SfmConfig(calibration=str(path)), 173, 173)


def test_real_davis_calibration_goes_to_colmap_opencv(anchors):
    from evdense.sfm.stage import _pycolmap_options

    calib = anchors / "data" / "davis346_vins_calib.yaml"
    opts = _pycolmap_options(SfmConfig(calibration=str(calib)), threads=1, width=346, height=260)
    params = [float(v) for v in opts.reader.camera_params.split(",")]
    assert opts.reader.camera_model == "OPENCV" and len(params) == 8
    assert params[:4] == pytest.approx([613.4558737, 613.1606796, 188.7985559, 132.7913205])
    assert params[4:] == pytest.approx([-0.2301223585, 0.1027225282, -0.0019158233, 0.0036228524])
    # fixed intrinsics: neither bundle adjustment nor pose estimation may change them
    assert opts.fixed_intrinsics and not opts.mapping.ba_refine_focal_length
    assert not opts.mapping.mapper.abs_pose_refine_focal_length
    opts = _pycolmap_options(
        SfmConfig(calibration=str(calib), refine_intrinsics=True), threads=1, width=346, height=260
    )
    assert opts.mapping.ba_refine_focal_length and opts.mapping.ba_refine_extra_params


def test_recorded_failure_keeps_its_diagnostics_inside_and_no_partial(tmp_path):
    import json

    from evdense.sfm import SfmError, sfm_failed, write_failed_sfm

    out = tmp_path / "sfm" / "events"
    work = out.with_name("events.partial")
    (work / "mapper").mkdir(parents=True)
    (work / "diagnostics.json").write_text(json.dumps({"verified_pairs": 3}))
    err = SfmError(f"2 of 40 frames registered. Diagnostics: {work / 'diagnostics.json'}",
                   work / "diagnostics.json")  # fmt: skip
    write_failed_sfm(out, err)
    assert sfm_failed(out) and not work.exists()
    assert sorted(p.name for p in out.iterdir()) == ["diagnostics.json", "stats.json"]
    stats = json.loads((out / "stats.json").read_text())
    assert str(out / "diagnostics.json") in stats["error"] and ".partial" not in stats["error"]
    assert json.loads((out / "diagnostics.json").read_text()) == {"verified_pairs": 3}
    assert [p.name for p in out.parent.iterdir()] == ["events"]
