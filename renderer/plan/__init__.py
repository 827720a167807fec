"""The render plan: what must run for one scene and request, decided before any GL work.

Pure functions of the scene, the resolved camera and lights, and the request; no GL. The passes
execute the plan, and ``RenderPlan.to_dict()`` is what the result reports. Every step works on
arrays over all instances at once; the instance objects themselves are read once per scene.

- :mod:`.geometry`: projections, poses, boxes and planes, cube faces.
- :mod:`.instances`: a scene's instances as arrays (boxes, flags, planes of flat instances),
  read once per scene and cached by the scene object.
- :mod:`.culling`: view culling, caster selection.
- :mod:`.context`: the per-request arrays the light fits share.
- :mod:`.fit`: one reach and one fit per kind of shadow map.
- :mod:`.plan`: :class:`RenderPlan`, :class:`LightShadow` and :func:`make_plan`.
"""

from .geometry import CUBE_FACES
from .plan import LightShadow, RenderPlan, make_plan

__all__ = ["CUBE_FACES", "LightShadow", "RenderPlan", "make_plan"]
