"""Meshes of the domain ω: descriptions, gmsh meshing, refinement, sizes, cost estimates."""
