"""cloud2cnc job-state core, shared by the API (`service`) and the workers (`worker`).

Settings (`config`), the job database (`db`) and its transitions (`jobs`), the content-addressed
artifact store (`store`), the queue client (`queue`), job parameters (`params`) and the stage
registry (`stages`). Nothing here imports FastAPI, the worker's stage implementations, torch or the
geometry stack.
"""
