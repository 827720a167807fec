"""The render plan: what must run for one scene and request, decided before any GL work.

Pure functions of the scene, the resolved camera and lights, and the request; no GL. The passes
execute the plan, and ``RenderPlan.to_dict()`` is what the result reports.
"""

from .plan import CUBE_FACES, LightPlan, RenderPlan, make_plan

__all__ = ["CUBE_FACES", "LightPlan", "RenderPlan", "make_plan"]
