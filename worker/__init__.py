"""cloud2cnc worker: the Celery app and its task (`celery_app`, `tasks`), the body of a stage run
against the job database (`runner`), the in-process pipeline (`local`) and the stage implementations
(`stages`). It never imports `service` (the HTTP API).
"""
