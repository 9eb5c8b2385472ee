"""The evaluation's settings: the ``evaluate`` section of the config."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from evdense.config import section_from_dict


@dataclass
class EvalConfig:
    """Settings of the evaluation (config section ``evaluate``)."""

    relative_thresholds: list[float] = field(default_factory=lambda: [0.0025, 0.005, 0.01, 0.02])
    """Distance thresholds of precision, recall and F-score, as fractions of the GT bounding-box
    diagonal."""
    default_threshold: float = 0.01
    """The threshold (one of the above) reported as *the* F-score in tables and plots."""
    curve_thresholds: list[float] = field(
        default_factory=lambda: [round(float(r), 6) for r in np.geomspace(0.001, 0.05, 23)]
    )
    """Thresholds (fractions of the GT diagonal) of the precision/recall/F curves stored beside
    the scores (``geometry.<product>.curve``) and drawn in ``prf_vs_threshold``."""
    num_samples: int = 200_000
    """GT surface samples for completeness (and samples of each reconstructed mesh)."""
    completeness_reference: str = "observed"
    """GT surface that completeness (recall) is measured on: observed (the part seen by at least
    visibility_min_views of visibility_views GT cameras spread along the whole trajectory, the same
    for every image source of a dataset) or full (the whole GT mesh, walls never looked at
    included)."""
    visibility_views: int = 60
    """GT cameras, evenly spaced in time along the trajectory, that define the observed surface."""
    visibility_min_views: int = 2
    """A GT surface point is observed when at least this many of those cameras see it (unoccluded,
    in the image)."""
    crop_margin: float = 0.02
    """Reconstructions are cropped to the GT bounding box grown by this fraction of its diagonal."""
    icp: bool = True
    """Refine the Sim(3) from camera centres with a scaled ICP onto the GT surface."""
    icp_max_distance: float = 0.02
    """ICP correspondence distance, as a fraction of the GT bounding-box diagonal."""
    icp_max_points: int = 200_000
    """ICP runs on a random subset of at most this many cloud points (0 = all): an event-frame
    cloud of 1.7 M points took 53 s in ICP alone, for a transform a subset fixes as well."""
    image_mode: str = "histogram"
    """How frames (of any tone curve) meet GT radiance before MSE, PSNR and SSIM: histogram (GT
    log-mapped to [0, 1], the frame's grey levels matched to its histogram: structure is compared,
    not tone curve) or percentile (each rescaled by its 1st-99th percentiles)."""
    max_image_frames: int = 60
    """At most this many frames (evenly spaced) of a source are compared with GT intensity."""
    heldout_views: int = 10
    """Renders of the textured mesh from this many held-out GT cameras (midway between GT frame
    times, which no conventional or GT frame uses) are compared with GT images."""
    figures: bool = True
    """Draw each dataset's pictures (``results/{dataset}/figures/``, the seed paper's figures and
    the error-coloured views) and its page of textured meshes (``results/{dataset}/meshes.html``)."""

    @classmethod
    def from_dict(cls, d: dict[str, Any] | None) -> EvalConfig:
        return section_from_dict(cls, d, "evaluate")

    def check(self) -> None:
        if self.completeness_reference not in ("observed", "full"):
            raise ValueError(
                "evaluate.completeness_reference: observed or full, "
                f"not {self.completeness_reference!r}"
            )
