"""From the dense cloud to a textured mesh: surface reconstruction (screened Poisson, or Delaunay
tetrahedra labelled by a visibility graph cut), clean-up, photometric refinement, texturing, and
renders of meshes and clouds."""

from evdense.mesh.stage import MeshConfig, mesh_surface, refine_mesh, texture_mesh

__all__ = ["MeshConfig", "mesh_surface", "refine_mesh", "texture_mesh"]
