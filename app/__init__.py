"""shadowmap-service HTTP layer: a thin FastAPI app around :mod:`renderer`.

Validates requests, queues renders to the process's GL thread and encodes the results. See
:mod:`app.main` for the entry points.
"""
