"""From the dense cloud to a surface mesh: screened Poisson, or Delaunay tetrahedra labelled by a
visibility graph cut, then clean-up; the mesh files and cameras the later stages
(:mod:`evdense.refine`, :mod:`evdense.texture`) read (:mod:`~evdense.mesh.views`)."""

from evdense.mesh.stage import MeshConfig, run_mesh

__all__ = ["MeshConfig", "run_mesh"]
