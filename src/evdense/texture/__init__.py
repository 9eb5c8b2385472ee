"""Texturing a mesh from calibrated views, in the spirit of Waechter et al. (ECCV 2014).

1. Candidates: view ``i`` may texture face ``f`` when the face faces it, its three vertices
   project inside the image (``border`` pixels in) and its centroid and (slightly shrunk) corners
   are not behind the view's depth map (the mesh ray-cast from that view). The quality of a
   candidate is the face's projected area in pixels (resolution, distance and obliquity at once).
2. View selection: a Markov random field over the face adjacency; data cost ``1 - q / q_best``,
   Potts cost ``smoothness`` between neighbouring faces with different views; solved by
   alpha-expansion with graph cuts (PyMaxflow).
3. Charts: connected faces with the same view. Each chart's bounding box in its image (plus a
   margin) is copied into an atlas by shelf packing (scaled down uniformly when the atlas would
   exceed ``max_atlas_size``).
4. Seam levelling: an additive colour correction per (vertex, chart), solved by sparse least
   squares so that colours agree along seam edges (sampled along each edge) and the correction
   varies smoothly inside each chart; it is rasterised into the atlas.
5. Faces no view sees get a flat colour (the mean of their vertices' colours) from a palette.

Export: OBJ + MTL + PNG, a vertex-coloured PLY and a GLB. The stage function is
:func:`~evdense.texture.stage.run_texture` (``python -m evdense.texture``).
"""

from evdense.texture.atlas import face_charts, shelf_pack
from evdense.texture.candidates import view_candidates
from evdense.texture.export import read_textured_mesh, write_glb, write_textured_mesh
from evdense.texture.model import TextureConfig, TexturedMesh
from evdense.texture.selection import select_views
from evdense.texture.stage import run_texture
from evdense.texture.texturing import texture_mesh_views

__all__ = [
    "TextureConfig",
    "TexturedMesh",
    "face_charts",
    "read_textured_mesh",
    "run_texture",
    "select_views",
    "shelf_pack",
    "texture_mesh_views",
    "view_candidates",
    "write_glb",
    "write_textured_mesh",
]
