"""shadowmap-service HTTP layer: a thin FastAPI app around :mod:`shadowmap.renderer`.

Validates requests, queues renders to a supervised worker process (one GL context each), which
renders and encodes them. See
:mod:`shadowmap.app.main` for the entry points.
"""
