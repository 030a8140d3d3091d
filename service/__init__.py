"""cloud2cnc HTTP API: FastAPI routes, request and response schemas, problem details, the dashboard.

The job state it reads and changes lives in `core`; it never imports `worker`, torch or the
geometry stack.
"""
