"""The ``sfm`` config section (:class:`SfmConfig`) and the error of a failed SfM."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from evdense.config import section_from_dict

SELECT_METHODS = ("all", "every_k", "count", "change")
MATCHERS = ("exhaustive", "sequential")
CAMERA_MODELS = ("SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV")
DEVICES = ("auto", "cpu", "cuda")
COLMAP_LOG_LEVELS = ("INFO", "WARNING", "ERROR")


@dataclass
class SfmConfig:
    """Settings of structure from motion (the ``sfm`` config section)."""

    select: str = "count"
    """Frames given to SfM: all, every_k (every select_every_k-th), count (select_count evenly
    spaced) or change (a new frame when the image changed by select_min_change). The first and last
    frames are always kept; the list is written to selected_frames.txt."""
    select_every_k: int = 1
    """select=every_k: keep every k-th frame (the last frame is always kept)."""
    select_count: int = 60
    """select=count: number of evenly spaced frames to keep (all when the folder has fewer)."""
    select_min_change: float = 0.05
    """select=change: keep a frame when its mean absolute difference to the last kept frame
    (grey levels in [0, 1], at 1/4 resolution) exceeds this."""
    max_features: int = 1024
    """SIFT features per image (pycolmap keeps whole scale levels, so a few more can come out);
    matching time grows with its square. Sets extraction.sift.max_num_features."""
    camera_model: str = "SIMPLE_RADIAL"
    """COLMAP camera model estimated when no calibration is given (one camera shared by all frames)."""
    calibration: str | None = "auto"
    """Intrinsics from a file instead of estimating them: a path (our YAML, VINS YAML, COLMAP
    cameras.txt); `dataset` for the dataset's own (a recording's calibration, gt/intrinsics.yaml for
    a synthetic scene); `auto` (default) for a recording's own calibration when it carries one or
    its dataset names one, and estimated intrinsics otherwise (synthetic scenes, recordings without
    calibration); null to always estimate. Rescaled to the frame size when the aspect ratio
    matches."""
    refine_intrinsics: bool = False
    """With a calibration, refine focal length and distortion in bundle adjustment (false keeps them
    fixed)."""
    matcher: str = "exhaustive"
    """exhaustive (all pairs, as in the method) or sequential (neighbours in time, for long sequences)."""
    loop_closure: bool = True
    """matcher=sequential: also match all pairs of keyframes (every ``loop_keyframe_every``-th
    selected frame), which closes loops without a vocabulary tree."""
    loop_keyframe_every: int = 5
    """matcher=sequential with loop_closure: keyframe spacing in selected frames."""
    device: str = "auto"
    """SIFT extraction and matching device: auto (CUDA when pycolmap was built with it), cpu, cuda."""
    num_threads: int = -1
    """CPU threads when the stage runs outside Snakemake (-1 = all cores); the rule passes its
    `threads`."""
    seed: int = 0
    """Random seed of RANSAC and the mapper (pycolmap.set_random_seed)."""
    min_registered_fraction: float = 0.25
    """Fewer registered frames than this fraction of the selected ones is an error (with a
    diagnostics JSON)."""
    min_registered_images: int = 3
    """Fewer registered frames than this is an error (SfmError)."""
    colmap_log_level: str = "WARNING"
    """Lowest level of COLMAP's own log lines (INFO, WARNING, ERROR); they go to stderr."""
    on_failure: str = "record"
    """When too few frames register: error (the job fails, with a diagnostics JSON), or record (the
    output folder is marked failed and the sweep goes on; MVS, meshing and evaluation then record an
    empty result, scored as F-score 0)."""
    extraction: dict[str, Any] = field(default_factory=dict)
    """Attributes of pycolmap.FeatureExtractionOptions, nested dicts for sub-options (e.g. {sift:
    {peak_threshold: 0.004}})."""
    matching: dict[str, Any] = field(default_factory=dict)
    """Attributes of pycolmap.FeatureMatchingOptions (e.g. {sift: {max_ratio: 0.8}, guided_matching: true})."""
    verification: dict[str, Any] = field(default_factory=dict)
    """Attributes of pycolmap.TwoViewGeometryOptions, the RANSAC geometric verification (e.g.
    {min_num_inliers: 15, ransac: {max_error: 4.0}})."""
    pairing: dict[str, Any] = field(default_factory=dict)
    """Attributes of pycolmap.ExhaustivePairingOptions or SequentialPairingOptions, by matcher (e.g.
    {overlap: 10})."""
    mapping: dict[str, Any] = field(default_factory=dict)
    """Attributes of pycolmap.IncrementalPipelineOptions, incremental mapping and bundle adjustment
    (e.g. {mapper: {init_min_tri_angle: 8}})."""

    @classmethod
    def from_dict(cls, d: dict[str, Any] | None) -> SfmConfig:
        """Build from a config section; unknown keys raise ``ValueError`` naming them."""
        return section_from_dict(cls, d, "sfm")

    @property
    def calibration_file(self) -> str | None:
        """The calibration file in use, or None when the intrinsics are estimated."""
        return None if self.calibration in (None, "", "auto") else self.calibration

    def check(self) -> None:
        """Raise ``ValueError`` naming the key of the first invalid value."""
        for key, allowed in (
            ("select", SELECT_METHODS),
            ("matcher", MATCHERS),
            ("camera_model", CAMERA_MODELS),
            ("device", DEVICES),
            ("colmap_log_level", COLMAP_LOG_LEVELS),
            ("on_failure", ("error", "record")),
        ):
            if getattr(self, key) not in allowed:
                raise ValueError(
                    f"config key 'sfm.{key}': {getattr(self, key)!r} is not one of {list(allowed)}"
                )
        for key in ("select_every_k", "select_count", "loop_keyframe_every", "max_features"):
            if int(getattr(self, key)) < 1:
                raise ValueError(f"config key 'sfm.{key}': must be >= 1, got {getattr(self, key)}")
        if self.calibration == "dataset":
            raise ValueError(
                "config key 'sfm.calibration': 'dataset' is resolved to a file by the workflow rule; "
                "give a file path when calling run_sfm directly"
            )
        if self.calibration_file and not Path(self.calibration_file).is_file():
            raise ValueError(f"config key 'sfm.calibration': no such file {self.calibration}")
        if not 0 <= self.min_registered_fraction <= 1:
            raise ValueError(
                f"config key 'sfm.min_registered_fraction': must be in [0, 1], got {self.min_registered_fraction}"
            )


class SfmError(RuntimeError):
    """SfM registered too few frames; the message says why and where the diagnostics JSON is."""

    def __init__(self, message: str, diagnostics_path: Path | None = None):
        super().__init__(message)
        self.diagnostics_path = diagnostics_path
