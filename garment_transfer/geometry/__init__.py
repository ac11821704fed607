"""Geometry: triangle meshes and what is computed on them, with no notion of bodies being fitted or
models being learned. Meshes and OBJ files (``Mesh``, ``read_obj``, ``write_obj``), exact closest points and
signed distance (``TriangleSurface``), deformation gradients, the embedding of a garment's per-triangle field on
the body and back, garment vertices bound to the body (``bind``, ``carry``), the Poisson solve that rebuilds a
mesh from gradients (``PoissonSolver``), the penetration fix, exact intersection counts, and the crossing pass
(``clearance``), all under every reading of a mesh's polygons (``readings``: both splits of a quad). Everything
here works on arrays; every other layer builds on it.
"""

from .binding import Binding, bind, carry, follow_nearest_vertex
from .clearance import separate
from .embedding import body_scale, body_to_cloth, cloth_to_body, embed, unembed
from .gradients import deformation_gradients
from .intersections import crossings, intersection_report, minimum_distance, self_intersections
from .mesh import (
                   Mesh,
                   common_polygons,
                   connected_pieces,
                   faces_hash,
                   faces_split,
                   faces_turned,
                   mesh_from_polygons,
                   mesh_from_triangles,
                   require_same_topology,
                   same_mesh,
                   triangle_normals,
                   triangulate,
                   turned_around,
                   vertex_areas,
                   vertex_normals,
)
from .mdd import is_mdd, is_mdd_name, read_mdd, write_mdd
from .obj import obj_text, read_obj, write_obj
from .pc2 import is_pc2, read_pc2, write_pc2
from .penetration import fix_penetration, vertex_adjacency
from .poisson import PoissonSolver
from .proximity import TriangleSurface, as_same_mesh, closest_on_triangles, common_mesh, facing_outward, one_mesh
from .readings import Readings, readings_of
from .self_check import SelfCheck

__all__ = ["Mesh", "mesh_from_polygons", "mesh_from_triangles", "triangulate", "require_same_topology", "same_mesh",
           "faces_turned", "faces_split", "common_polygons", "turned_around", "as_same_mesh", "one_mesh", "common_mesh",
           "facing_outward", "connected_pieces", "triangle_normals",
           "vertex_normals", "vertex_areas", "faces_hash", "read_obj", "write_obj", "obj_text",
           "read_pc2", "write_pc2", "is_pc2", "read_mdd", "write_mdd", "is_mdd", "is_mdd_name", "TriangleSurface",
           "closest_on_triangles",
           "deformation_gradients",
           "body_scale",
           "body_to_cloth", "cloth_to_body", "embed", "unembed", "Binding", "bind", "carry", "follow_nearest_vertex",
           "PoissonSolver", "fix_penetration", "vertex_adjacency", "crossings", "self_intersections",
           "minimum_distance", "intersection_report", "separate", "Readings", "readings_of", "SelfCheck"]
