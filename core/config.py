"""Settings for the API, the worker and the CLI: one object, read from the environment."""

from __future__ import annotations

import functools
import os
from pathlib import Path
from typing import Annotated

from pydantic import AliasChoices, Field, field_validator
from pydantic_settings import BaseSettings, NoDecode, SettingsConfigDict


class Settings(BaseSettings):
    """Every knob an operator can turn; each field names its environment variable."""

    model_config = SettingsConfigDict(extra="ignore", populate_by_name=True)

    data_dir: Path = Field(
        default=Path("cloud2cnc-data"),
        validation_alias=AliasChoices("CLOUD2CNC_DATA_DIR", "data_dir"),
        description="Artifacts, uploads, the SQLite database and the filesystem broker live here.",
    )
    database_url: str | None = Field(
        default=None,
        validation_alias=AliasChoices("DATABASE_URL", "database_url"),
        description="SQLAlchemy URL of the job database; SQLite under the data directory when unset.",
    )
    celery_broker_url: str = Field(
        default="filesystem://",
        validation_alias=AliasChoices("CELERY_BROKER_URL", "celery_broker_url"),
        description="Celery broker; filesystem:// keeps the queue under the data directory.",
    )
    api_key: str | None = Field(
        default=None,
        validation_alias=AliasChoices("CLOUD2CNC_API_KEY", "api_key"),
        description="When set, every /v1 route requires it in the X-API-Key header.",
    )
    max_upload_mb: float = Field(
        default=512.0, gt=0,
        validation_alias=AliasChoices("CLOUD2CNC_MAX_UPLOAD_MB", "max_upload_mb"),
    )
    min_points: int = Field(
        default=100, ge=1,
        validation_alias=AliasChoices("CLOUD2CNC_MIN_POINTS", "min_points"),
    )
    max_points: int = Field(
        default=20_000_000, ge=1,
        validation_alias=AliasChoices("CLOUD2CNC_MAX_POINTS", "max_points"),
    )
    stage_lease_s: float = Field(
        default=60.0, gt=0,
        validation_alias=AliasChoices("CLOUD2CNC_STAGE_LEASE_S", "stage_lease_s"),
        description="A running stage renews its lease every lease/4 s; once it lapses the reconciler re-queues it.",
    )
    reconcile_interval_s: float = Field(
        default=10.0, gt=0,
        validation_alias=AliasChoices("CLOUD2CNC_RECONCILE_INTERVAL_S", "reconcile_interval_s"),
    )
    max_stage_attempts: int = Field(
        default=3, ge=1,
        validation_alias=AliasChoices("CLOUD2CNC_MAX_STAGE_ATTEMPTS", "max_stage_attempts"),
    )
    stage_time_limit_s: float | None = Field(
        default=None, gt=0,
        validation_alias=AliasChoices("CLOUD2CNC_STAGE_TIME_LIMIT_S", "stage_time_limit_s"),
        description="Hard limit of every stage; unset: each stage's own (core.stages). The soft limit that "
                    "fails a stage cleanly is 95 % of it.",
    )
    stage_time_limits: Annotated[dict[str, float], NoDecode] = Field(
        default_factory=dict,
        validation_alias=AliasChoices("CLOUD2CNC_STAGE_TIME_LIMITS", "stage_time_limits"),
        description='Hard limits of single stages, s, as "fit=2400,plan=1200"; they win over '
                    "CLOUD2CNC_STAGE_TIME_LIMIT_S for the stages they name.",
    )
    worker_max_memory_mb: int = Field(
        default=4096, ge=64,
        validation_alias=AliasChoices("CLOUD2CNC_WORKER_MAX_MEMORY_MB", "worker_max_memory_mb"),
        description="A worker child is replaced after a task once its resident memory passes this.",
    )
    blas_threads: int = Field(
        default=1, ge=1,
        validation_alias=AliasChoices("CLOUD2CNC_BLAS_THREADS", "blas_threads"),
    )
    stage_processes: int = Field(
        default=0, ge=0,
        validation_alias=AliasChoices("CLOUD2CNC_STAGE_PROCESSES", "stage_processes"),
        description="Processes a stage forks for its independent pieces (fit's patches); 0: the CPUs the "
                    "worker may use, shared among its concurrent tasks (`CLOUD2CNC_CONCURRENCY`).",
    )
    worker_nice: int = Field(
        default=10, ge=0, le=19,
        validation_alias=AliasChoices("CLOUD2CNC_WORKER_NICE", "worker_nice"),
        description="Niceness `cloud2cnc serve` adds to its embedded worker (and so to every process of a "
                    "stage), so the API answers promptly while a stage computes on the same CPUs; 0: same "
                    "priority as the API.",
    )
    redis_prefix: str = Field(
        default="",
        validation_alias=AliasChoices("CLOUD2CNC_REDIS_PREFIX", "redis_prefix"),
        description="Prepended to every Redis key and channel the queue uses (kombu's global_keyprefix), so "
                    "deployments or test runs sharing one Redis database keep apart.",
    )
    stage_plugins: str = Field(
        default="",
        validation_alias=AliasChoices("CLOUD2CNC_STAGE_PLUGINS", "stage_plugins"),
        description="Comma-separated modules whose STAGES are appended to the pipeline (tests use it).",
    )
    warm_up: bool = Field(
        default=True,
        validation_alias=AliasChoices("CLOUD2CNC_WARM_UP", "warm_up"),
        description="A worker compiles the geometry kernels before it takes work (`worker.warmup`): about a "
                    "minute on two cores the first time this code runs on a machine, under a second after.",
    )
    pipeline: str = Field(
        default="",
        validation_alias=AliasChoices("CLOUD2CNC_PIPELINE", "pipeline"),
        description="Comma-separated stages a job runs (empty: all of them, in DESIGN order).",
    )

    @field_validator("stage_time_limits", mode="before")
    @classmethod
    def _parse_stage_time_limits(cls, value):
        """"fit=2400,plan=1200" (what an environment variable holds) as a mapping; a mapping as it is."""
        if not isinstance(value, str):
            return value
        limits = {}
        for item in filter(None, (part.strip() for part in value.split(","))):
            name, _, seconds = (x.strip() for x in item.partition("="))
            try:
                limits[name] = float(seconds)
            except ValueError:
                limits[name] = 0.0
            if not name or not limits[name] > 0:
                raise ValueError(f"CLOUD2CNC_STAGE_TIME_LIMITS takes stage=seconds pairs with seconds > 0, "
                                 f"separated by commas; got {item!r}")
        return limits

    def time_limit_s(self, stage: str, own_s: float) -> float:
        """The hard limit of stage `stage` (its own limit `own_s`): this stage's setting, else every stage's,
        else its own."""
        if stage in self.stage_time_limits:
            return float(self.stage_time_limits[stage])
        return float(self.stage_time_limit_s) if self.stage_time_limit_s is not None else float(own_s)

    @property
    def max_upload_bytes(self) -> int:
        return int(self.max_upload_mb * 1024 * 1024)

    @property
    def resolved_database_url(self) -> str:
        if self.database_url:
            url = self.database_url
            # Operators paste postgres:// URLs; SQLAlchemy wants the driver spelled out.
            for prefix in ("postgres://", "postgresql://"):
                if url.startswith(prefix):
                    return "postgresql+psycopg://" + url[len(prefix):]
            return url
        return f"sqlite:///{(self.data_dir / 'jobs.db').resolve()}"

    @property
    def artifacts_dir(self) -> Path:
        return self.data_dir / "artifacts"

    @property
    def uploads_dir(self) -> Path:
        return self.data_dir / "uploads"

    @property
    def broker_dir(self) -> Path:
        return self.data_dir / "broker"


@functools.lru_cache
def get_settings() -> Settings:
    """The process-wide settings; tests clear the cache after changing the environment."""
    return Settings()


def stage_processes(configured: int | None) -> int:
    """Processes one stage may fork: `configured` when set (> 0), else the CPUs this process may run on,
    divided among the worker's concurrent tasks."""
    if configured:
        return int(configured)
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return max(1, cpus // max(1, int(os.environ.get("CLOUD2CNC_CONCURRENCY", "1") or 1)))


def set_thread_limits(settings: Settings) -> None:
    """Threads of BLAS/OpenMP (`blas_threads`) and of the compiled drop-cutter (`stage_processes`), set in
    the environment unless already set; call it before numpy loads. Parallel pieces of a stage run in
    processes (`cam.map_forked`), each of which would otherwise start a BLAS thread per CPU."""
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, str(settings.blas_threads))
    os.environ.setdefault("NUMBA_NUM_THREADS", str(stage_processes(settings.stage_processes)))
