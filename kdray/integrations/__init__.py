"""Adapters that put kdray behind libraries users already call.

    kdray.integrations.trimesh.RayMeshIntersector   # mesh.ray = RayMeshIntersector(mesh)

Each adapter is its own module and imports its library only there: importing
`kdray.integrations` imports none of them (docs/integrations.md).
"""
