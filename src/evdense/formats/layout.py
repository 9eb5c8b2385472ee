"""Where each product of a run lives: the one spelling of the results layout.

The workflow (``workflow/rules/*.smk``) names its rule inputs and outputs with it, and the Python
code that looks for products (``evdense reconstruct``, the benchmarks) finds them with it. The
methods take a dataset and an image source; given the wildcards ``"{dataset}"``, ``"{source}"``
they return Snakemake patterns.

Image sources: ``<method>_<window>_b<bins>`` (frames from events, in ``frames/<source>/``),
``conventional`` (``conventional/frames/``) and ``gt``, the oracle (``gt/frames/``).
"""

from __future__ import annotations

from dataclasses import dataclass

FIXED_SOURCES = {"gt": "gt", "oracle": "gt", "conventional": "conventional"}
"""Sources whose frames live inside another product's folder (the GT folder, the conventional
camera's folder), with that folder's name."""


@dataclass(frozen=True)
class Layout:
    """The results layout under ``root`` (``results`` in a workflow's working directory)."""

    root: str = "results"

    def dataset(self, dataset: str) -> str:
        return f"{self.root}/{dataset}"

    def stage(self, dataset: str, stage: str) -> str:
        """The folder of a stage's products, one entry per source (``sfm``, ``mvs``, ``mesh``,
        ``eval``): for listing the sources a run made."""
        return f"{self.root}/{dataset}/{stage}"

    def events(self, dataset: str) -> str:
        """The canonical event file."""
        return f"{self.root}/{dataset}/events/events.h5"

    def gt(self, dataset: str) -> str:
        """The ground-truth folder (mesh, trajectory, intrinsics, frames)."""
        return f"{self.root}/{dataset}/gt"

    def source_images(self, dataset: str, source: str) -> str:
        """The rule output that holds a source's frames (``gt/`` and ``conventional/`` hold a
        ``frames/`` folder; an event source's output is its frames folder)."""
        if source in FIXED_SOURCES:
            return f"{self.root}/{dataset}/{FIXED_SOURCES[source]}"
        return f"{self.root}/{dataset}/frames/{source}"

    def frames(self, dataset: str, source: str) -> str:
        """The folder of PNG frames + ``timestamps.txt`` of a source."""
        base = self.source_images(dataset, source)
        return f"{base}/frames" if source in FIXED_SOURCES else base

    def sfm(self, dataset: str, source: str) -> str:
        """The SfM folder (``sparse/0``, ``trajectory.txt``, ``stats.json``)."""
        return f"{self.root}/{dataset}/sfm/{source}"

    def mvs(self, dataset: str, source: str) -> str:
        """The dense workspace."""
        return f"{self.root}/{dataset}/mvs/{source}"

    def dense_cloud(self, dataset: str, source: str) -> str:
        return f"{self.mvs(dataset, source)}/fused.ply"

    def mesh_dir(self, dataset: str, source: str, method: str) -> str:
        return f"{self.root}/{dataset}/mesh/{source}/{method}"

    def mesh_products(self, dataset: str, source: str, method: str) -> tuple[str, str, str]:
        """The mesh, the refined mesh and the textured OBJ of a source and meshing method."""
        d = self.mesh_dir(dataset, source, method)
        return f"{d}/mesh.ply", f"{d}/refined.ply", f"{d}/textured/mesh.obj"

    def metrics(self, dataset: str, source: str) -> str:
        """The evaluation of a source."""
        return f"{self.root}/{dataset}/eval/{source}/metrics.json"

    def figures(self, dataset: str) -> str:
        """The dataset's pictures."""
        return f"{self.root}/{dataset}/figures"

    def mesh_page(self, dataset: str) -> str:
        """The dataset's page of textured meshes."""
        return f"{self.root}/{dataset}/meshes.html"
