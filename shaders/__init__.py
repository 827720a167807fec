"""GLSL sources of the renderer, loaded by :mod:`shadowmap.renderer.gl.programs`.

A program is named by its two main files (``*.vert``, ``*.frag``), each starting with ``#version``
and then declaring its variant defines with their defaults (``#define HAS_UV 0``). Shared code
lives in ``chunks/`` and comes in by ``#include "chunks/name.glsl"``; the numbers shared with
Python (encoding and light type ids, ``MAX_LIGHTS``) are defined by the builder, see
:mod:`shadowmap.renderer.shader_constants`.

- ``light_pass.vert`` / ``light_pass.frag``: render linear light-space depth into a shadow map,
  packed by ``chunks/depth_encoding.glsl`` or written to a depth texture.
- ``camera_pass.vert`` / ``camera_pass.frag``: shade the scene (``chunks/lighting.glsl``: sRGB,
  light falloff, depth bias), comparing against the maps through ``chunks/shadow_2d.glsl`` and
  ``chunks/shadow_cube.glsl``, both built on ``chunks/shadow_lookup.glsl``.
- ``fullscreen.vert`` with ``encoding_probe.frag`` / ``compare_probe.frag``: small exact checks of
  the encodings and of the compare, used by the tests.
"""
