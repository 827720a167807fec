"""The two GL passes: the light pass renders each light's shadow map, the camera pass shades the
visible objects against them."""

from .. import gl as _gl  # noqa: F401  (selects the GL platform before PyOpenGL loads)
