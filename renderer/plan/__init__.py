"""The render plan: what must run for one scene and request, decided before any GL work.

Pure functions of the scene, the resolved camera and lights, and the request; no GL. The passes
execute the plan, and ``RenderPlan.to_dict()`` is what the result reports.

- :mod:`.geometry`: projections, poses, boxes and planes, cube faces.
- :mod:`.culling`: view culling, flat instances, caster selection.
- :mod:`.context`: the per-request arrays the light fits share.
- :mod:`.fit`: one reach and one fit per kind of shadow map.
- :mod:`.plan`: :class:`RenderPlan`, :class:`LightShadow` and :func:`make_plan`.
"""

from .geometry import CUBE_FACES
from .plan import LightShadow, RenderPlan, make_plan

__all__ = ["CUBE_FACES", "LightShadow", "RenderPlan", "make_plan"]
