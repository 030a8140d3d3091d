"""The Celery application and the client side of the queue: a job is a chain of stage tasks.

The same configuration serves the API (which only sends) and the worker
(which also runs the tasks, registered in `worker.tasks`). Messages carry a
job id and a stage name, never data.
"""

from __future__ import annotations

from typing import Iterable

from celery import Celery, chain

from core.config import Settings

TASK_NAME = "cloud2cnc.run_stage"
QUEUE = "cloud2cnc"


def celery_config(settings: Settings) -> dict:
    from core.stages import DEFAULT_STAGE_LIMIT_S

    # Each stage's task carries its own limit (enqueue_job); this is the fallback and the redelivery bound.
    hard = max(settings.stage_time_limit_s or 0.0, *settings.stage_time_limits.values(), DEFAULT_STAGE_LIMIT_S)
    conf = {
        "broker_url": settings.celery_broker_url,
        "task_default_queue": QUEUE,
        "task_ignore_result": True,
        "result_backend": None,
        "task_serializer": "json",
        "accept_content": ["json"],
        # Long CPU stages: ack after the stage, one message per child, redeliver when a child dies.
        "task_acks_late": True,
        "task_reject_on_worker_lost": True,
        "worker_prefetch_multiplier": 1,
        "task_time_limit": hard,
        "task_soft_time_limit": hard * 0.95,
        "worker_max_memory_per_child": settings.worker_max_memory_mb * 1024,
        "worker_hijack_root_logger": False,
        "broker_connection_retry_on_startup": True,
        "broker_transport_options": {
            # Redis redelivers an unacked message after this; it must outlast the longest stage.
            "visibility_timeout": int(hard * 2 + 60),
        },
    }
    on_redis = settings.celery_broker_url.startswith(("redis://", "rediss://", "redis+socket://"))
    if settings.redis_prefix and on_redis:
        # Every key and channel kombu touches (queues, bindings, unacked hash, pidbox) under one prefix.
        conf["broker_transport_options"]["global_keyprefix"] = settings.redis_prefix
    if settings.celery_broker_url.startswith("filesystem://"):
        folder = settings.broker_dir.resolve()
        for sub in ("queue", "processed", "control"):
            (folder / sub).mkdir(parents=True, exist_ok=True)
        conf["broker_transport_options"] = {
            "data_folder_in": str(folder / "queue"),
            "data_folder_out": str(folder / "queue"),
            "processed_folder": str(folder / "processed"),
            "control_folder": str(folder / "control"),
            "store_processed": False,
        }
    return conf


_APPS: dict[str, Celery] = {}


def get_celery(settings: Settings) -> Celery:
    """One Celery app per distinct settings object and process."""
    key = settings.model_dump_json()
    if key not in _APPS:
        app = Celery("cloud2cnc")
        app.conf.update(celery_config(settings))
        _APPS[key] = app
    return _APPS[key]


def enqueue_chain(app: Celery, job_id: str, stages: Iterable[tuple[str, str, float]]) -> None:
    """Send the chain `stage1 | stage2 | ...` for a job; items are (stage name, task id, hard limit in s).

    The soft limit, 95 % of the hard one, lets the stage fail with a message before it is killed.
    """
    sigs = [app.signature(TASK_NAME, args=(job_id, name), immutable=True, queue=QUEUE)
            .set(task_id=task_id, time_limit=limit_s, soft_time_limit=limit_s * 0.95)
            for name, task_id, limit_s in stages]
    if not sigs:
        return
    chain(*sigs).apply_async() if len(sigs) > 1 else sigs[0].apply_async()


def enqueue_stages(app: Celery, settings: Settings, job_id: str, stages: Iterable[tuple[str, str]]) -> None:
    """`enqueue_chain` for (stage name, task id) pairs, with each stage's own time limit."""
    from core.stages import load_stages, time_limit_s

    specs = {s.name: s for s in load_stages(settings.stage_plugins, settings.pipeline)}
    enqueue_chain(app, job_id, [(name, task_id, time_limit_s(specs[name], settings))
                                for name, task_id in stages])


def revoke(app: Celery, task_ids: list[str]) -> None:
    """Best effort: drop queued stage messages; the task also checks the job before it runs."""
    if task_ids:
        try:
            app.control.revoke(task_ids)
        except Exception:  # noqa: BLE001 — revoke is an optimisation, cancel is enforced in the DB
            pass
