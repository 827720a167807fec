"""shadowmap-service HTTP layer: a thin FastAPI app around :mod:`shadowmap.renderer`.

Validates requests, queues renders to the process's GL thread and encodes the results. See
:mod:`shadowmap.app.main` for the entry points.
"""
