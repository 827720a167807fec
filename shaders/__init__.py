"""GLSL sources of the renderer, one file per stage and pass; loaded by :mod:`renderer.shaders`.

- ``light_pass.vert`` / ``light_pass.frag``: render linear light-space depth into a shadow map,
  packed by ``depth_encoding.glsl`` or written to a depth texture.
- ``camera_pass.vert`` / ``camera_pass.frag``: shade the scene, comparing against the maps through
  ``shadow_lookup.glsl``.
- ``fullscreen.vert`` with ``encoding_probe.frag`` / ``compare_probe.frag``: small exact checks of
  the encodings and of the compare, used by the tests.
"""
