"""kdray: exact depth, normal, barycentric and triangle-id images of meshes.

    import kdray
    mesh = kdray.load("scene.obj")
    tree = kdray.build(mesh.vertices, mesh.faces)
    tracer = kdray.Tracer(tree)
    hits = tracer.trace(origins, directions)
"""
