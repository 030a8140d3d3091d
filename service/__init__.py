"""cloud2cnc job service: API, job store, artifact store and queue client.

Nothing importable from this package at module level pulls in FastAPI,
torch or the geometry stack, so the worker can share the job store.
"""
