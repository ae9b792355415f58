"""Settings, in one place: every GSA_ environment variable the service reads."""

from __future__ import annotations

from pathlib import Path

from pydantic import Field, model_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

from inference.runtime import DEFAULT_MODEL_DIR, DEFAULT_RUN_BATCH  # the shipped models and their run size

MIN_KEY_LENGTH = 16  # an environment key shorter than this is refused at start (issue 46: 7 were taken)


class Settings(BaseSettings):
    """Service settings, read from ``GSA_*`` environment variables (and a ``.env`` file if present).

    ``GSA_DATABASE_URL`` defaults to a SQLite file under ``GSA_DATA_DIR``;
    ``GSA_API_KEYS`` is a comma-separated list of keys accepted besides the stored ones;
    ``GSA_ADMIN_API_KEYS`` likewise, keys with the admin role (they may change the shared default model sets).
    ``GSA_KEY_SECRET`` is the HMAC secret API keys are stored under; when unset it is
    made once and kept in ``GSA_DATA_DIR/key-secret`` (several hosts must share one).
    ``GSA_ORPHAN_GRACE_S``: image files no row refers to are removed at start-up once
    older than this (0 on one host; raise it when hosts share the image folder).
    ``GSA_TARGET_MODEL``: an operator's own target mesh (OBJ or PLY, metres times
    ``GSA_TARGET_SCALE``), offered beside the built-in targets under its file's stem;
    ``GSA_DEFAULT_TARGET`` names the target an estimate fits when it names none.
    ``GSA_JOB_WORKERS``: jobs (``/v1/jobs``) running at once on this host, each in its own process;
    ``GSA_RAY_ADDRESS``: run the work inside jobs (and ``gsa simulate``) on that Ray cluster.
    """

    model_config = SettingsConfigDict(env_prefix="GSA_", env_file=".env", env_ignore_empty=True, extra="ignore")

    data_dir: Path = Path("data")
    database_url: str = ""
    api_keys: str = ""
    admin_api_keys: str = ""
    host: str = "127.0.0.1"
    port: int = 8000
    max_page_size: int = Field(default=100, ge=1, le=10_000)
    max_span_days: float = Field(default=30.0, gt=0, le=30.0)
    max_grid_points: int = Field(default=25_000_000, ge=1)
    plan_timeout_s: float = Field(default=30.0, gt=0, le=3600.0)
    campaign_timeout_s: float = Field(default=120.0, gt=0, le=3600.0)
    plan_memory_mb: float = Field(default=1024.0, gt=0, le=1_000_000.0)
    header_timeout_s: float = Field(default=10.0, gt=0, le=600.0)
    body_timeout_s: float = Field(default=120.0, gt=0, le=3600.0)
    auth_failures_per_minute: int = Field(default=20, ge=1, le=1_000_000)
    keep_alive_timeout_s: float = Field(default=5.0, gt=0, le=600.0)
    shutdown_grace_s: float = Field(default=10.0, ge=0, le=600.0)
    max_connections: int = Field(default=2048, ge=16, le=1_000_000)
    max_epoch_gap_days: float = Field(default=60.0, gt=0, le=36_525.0)
    max_tle_age_days: float = Field(default=30.0, gt=0, le=36_525.0)
    max_request_bytes: int = Field(default=1_000_000, ge=1024)
    max_catalogue_bytes: int = Field(
        default=16 * 1024 * 1024, ge=1024, description="a POST /v1/access-windows body (a catalogue of satellites)"
    )
    access_budget: float = Field(
        default=100_000.0, ge=1.0, description="a catalogue's work at most, in target-station-days"
    )
    max_upload_bytes: int = Field(default=8 * 1024 * 1024, ge=1024)
    max_batch_bytes: int = Field(default=64 * 1024 * 1024, ge=1024)
    max_image_side: int = Field(default=4096, ge=8, le=65_536)
    max_batch_frames: int = Field(default=64, ge=1, le=4096)
    max_decoded_mb: int = Field(default=256, ge=1, le=1_048_576)
    model_dir: Path = DEFAULT_MODEL_DIR
    extra_model_dirs: str = Field(
        default="", description="more model sets, comma-separated folders, each trained on another target"
    )
    ort_threads: int = Field(default=0, ge=0, le=256, description="0: all cores")
    fit_threads: int = Field(
        default=0, ge=0, le=256, description="frames of one batch or pass fitted at once; 0: one a core"
    )
    max_loaded_versions: int = Field(
        default=4, ge=1, le=256, description="adapted model versions kept loaded per process (LRU; ~220 MB each)"
    )
    ort_run_batch: int = Field(default=DEFAULT_RUN_BATCH, ge=1, le=256, description="frames per ONNX Runtime run")
    target_model: Path | None = None
    target_scale: float = Field(default=1.0, gt=0, le=1000.0)
    default_target: str = "tiangong-like"
    key_secret: str = ""
    orphan_grace_s: float = Field(default=0.0, ge=0.0)
    log_level: str = Field(default="info", pattern="^(debug|info|warning|error)$")
    log_json: bool | None = None  # unset: JSON lines unless stderr is a terminal
    job_workers: int = Field(
        default=1, ge=0, le=256, description="jobs running at once on this host (0: none; another host runs them)"
    )
    quota_storage_mb: float = Field(
        default=10_240.0,
        gt=0,
        le=1e9,
        description="what one operator may store (labelled frames, estimates' images, data sets, model versions)",
    )
    quota_queued_jobs: int = Field(
        default=16, ge=1, le=100_000, description="jobs one operator may have queued or running"
    )
    max_adaptation_minutes: float = Field(
        default=120.0, gt=0, le=10_000, description="the longest max_minutes an adaptation may ask for"
    )
    max_adaptation_epochs: int = Field(
        default=200, ge=1, le=100_000, description="the most epochs an adaptation may ask for"
    )
    max_dataset_gb: float = Field(default=20.0, gt=0, le=100_000, description="the largest data set a job may write")
    max_pass_job_frames: int = Field(
        default=512, ge=2, le=100_000, description="frames of a pass sent with Prefer: respond-async (a job)"
    )
    job_simulation_workers: int = Field(
        default=0, ge=0, le=256, description="processes one data-set job simulates with on this host; 0: all cores"
    )
    ray_address: str = Field(
        default="",
        max_length=300,
        description="a Ray cluster for jobs and gsa simulate: HOST:PORT of its head, ray://HOST:PORT, or local",
    )

    @model_validator(mode="after")
    def _default_database(self) -> Settings:
        if not self.database_url:
            self.database_url = f"sqlite:///{(self.data_dir / 'gsa.db').as_posix()}"
        return self

    @model_validator(mode="after")
    def _keys_long_enough(self) -> Settings:
        for name, keys in (("GSA_API_KEYS", self.api_keys), ("GSA_ADMIN_API_KEYS", self.admin_api_keys)):
            short = [k for k in (k.strip() for k in keys.split(",")) if k and len(k) < MIN_KEY_LENGTH]
            if short:
                raise ValueError(
                    f"{name} holds a key of {len(short[0])} characters; each key needs at least {MIN_KEY_LENGTH} "
                    "(a short key is guessed): make one with `gsa keys create` or `openssl rand -hex 16`"
                )
        return self

    @property
    def extra_model_dir_list(self) -> list[Path]:
        return [Path(d.strip()) for d in self.extra_model_dirs.split(",") if d.strip()]

    @property
    def env_api_keys(self) -> list[str]:
        """Every key from the environment, admin keys included."""
        return [k.strip() for k in f"{self.api_keys},{self.admin_api_keys}".split(",") if k.strip()]

    @property
    def env_admin_keys(self) -> list[str]:
        return [k.strip() for k in self.admin_api_keys.split(",") if k.strip()]


def get_settings() -> Settings:
    """Return settings read from the environment now (cheap; tests change the environment)."""
    return Settings()
