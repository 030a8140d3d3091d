"""cloud2cnc worker: the Celery app, thin stage tasks and the in-process pipeline runner."""
