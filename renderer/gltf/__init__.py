"""The project's own glTF 2.0 reader: numpy decoding of everything the renderer draws.

Modules: ``reader`` (GLB/JSON container, ``asset`` check, buffer and view bytes), ``accessors``
(component types, normalized integers, interleaving, sparse), ``nodes`` (world matrices over the
node graph), ``primitives`` (triangulation and index checks), ``materials`` (base colour,
textures, alpha), ``skin``, ``morph``, ``extensions`` (one module per extension, registered by
its glTF name) and ``loader`` (the document to the renderer's
:class:`~shadowmap.renderer.scene.Scene` parts). The public entry point is
:func:`shadowmap.renderer.scene.load_scene`.
"""
