"""Mesh primitives several stages share: exact closest points on triangles (`closest`), quad-mesh
topology and face normals (`quads`), and unique rows of integer arrays (`rows`)."""
