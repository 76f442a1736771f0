"""Deployment settings (pydantic-settings) and the limits the API enforces.

Settings are read from the environment (prefix ``TEACHREPEAT_``) or passed explicitly, then
handed to :func:`server.app.create_app`; nothing is built at import time.
"""

from __future__ import annotations

import ipaddress
from pathlib import Path
from typing import Any

from pydantic import Field, SecretStr, model_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

from server.ratelimit import RateLimits

DEFAULT_DATA_DIR = Path("data")
"""Relative to the working directory the server is started in."""


class Settings(BaseSettings):
    """Everything that differs between deployments. Environment: ``TEACHREPEAT_<NAME>``."""

    # hide_input_in_errors: an error of the whole model (the TLS pair check) would otherwise
    # print every setting, the admin token from the environment included
    model_config = SettingsConfigDict(
        env_prefix="TEACHREPEAT_", extra="ignore", hide_input_in_errors=True
    )

    db: Path = Field(
        default=DEFAULT_DATA_DIR / "teachrepeat.sqlite",
        description="SQLite database file; created with its folder when missing. With "
        "`database_url` set to PostgreSQL, its folder still holds the admin token file and "
        "the recordings.",
    )
    database_url: SecretStr | None = Field(
        default=None,
        description="The database as a URL: `postgresql://USER:PASSWORD@HOST:PORT/NAME` for "
        "a PostgreSQL server shared by several server processes or machines (docs/scale.md), "
        "or `sqlite:///PATH` (the same as `db`). None = the SQLite file `db`. Its password is "
        "never printed or logged; prefer the environment (TEACHREPEAT_DATABASE_URL) to the "
        "command line, which other users of the machine can read.",
    )
    admin_token: SecretStr | None = Field(
        default=None,
        description="Bearer token for admin endpoints. When unset, `serve` generates one and "
        "writes it next to the database (mode 0600); it is never logged.",
    )
    host: str = Field(default="127.0.0.1", description="Interface the API binds to.")
    port: int = Field(default=8000, ge=0, le=65535, description="API port; 0 = any free port.")
    tls_cert: Path | None = Field(
        default=None,
        description="PEM certificate to serve the API over HTTPS with (`teachrepeat cert` makes "
        "a self-signed one for a home); needs `tls_key`. None = plain HTTP.",
    )
    tls_key: Path | None = Field(
        default=None,
        description="PEM private key of `tls_cert`, unencrypted (keep it mode 0600).",
    )
    dashboard_port: int | None = Field(
        default=8080, ge=0, le=65535, description="Dashboard port; 0 = any free port; None = off."
    )
    dashboard_login: bool | None = Field(
        default=None,
        description="Whether the dashboard asks for a household login and then shows only that "
        "household (web/gate.py). None = automatic: it does on any host that is not loopback "
        "(127.0.0.0/8, ::1, localhost). True: also on loopback. False: never; refused off "
        "loopback. The loopback default is one dashboard showing every household to whoever "
        "can reach 127.0.0.1, as before logins existed.",
    )
    workers: int = Field(
        default=0,
        ge=0,
        le=64,
        description="Server processes behind HAProxy with robot affinity (docs/scale.md): "
        "`serve` then launches them, HAProxy in front on `host`:`port`, and restarts a "
        "process that dies. 0 = this process serves alone (no HAProxy); 1 = one process "
        "behind HAProxy (the baseline a benchmark compares with).",
    )
    worker_name: str | None = Field(
        default=None,
        max_length=32,
        pattern=r"^[A-Za-z0-9_-]+$",
        description="This process's name among several behind HAProxy (set by `serve "
        "--workers`); answered in /health and in the X-Teachrepeat-Worker header of every "
        "response. None = not one of several.",
    )
    concurrent_steps: int = Field(
        default=1,
        ge=1,
        le=64,
        description="Navigation steps (features, belief, command) computed at once over "
        "all robots; the others wait their turn. A step is CPU work that partly holds the GIL, "
        "so more at once mostly contend for it: at 20 robots, one at a time served 170 "
        "frames/s where up to 40 at once served 128 (docs/reliability.md).",
    )
    navigation: dict[str, Any] = Field(
        default_factory=dict,
        description="Overrides of the navigation settings (server.navigation.NavigationParams, "
        'dotted names for nested ones), JSON in the environment: {"dock_second_axis": false, '
        '"motion.unstick_s": 6}. Unknown names and wrong types stop the server at start.',
    )
    record: bool = Field(
        default=False,
        description="Record every teaching tour and navigation task to an MCAP file in "
        "`record_dir` (docs/recording.md). A task's own `record` (POST .../goto, "
        ".../teach/start) overrides it for that task.",
    )
    record_dir: Path | None = Field(
        default=None,
        description="Folder of the recordings, one sub-folder per household. None = "
        "`recordings` beside the database.",
    )
    record_keep_files: int = Field(
        default=200,
        ge=1,
        description="Most recordings kept (all households together); when a recording ends, "
        "the oldest finished ones are deleted until there are no more.",
    )
    record_keep_mb: float = Field(
        default=2000.0,
        gt=0,
        description="Most megabytes of recordings kept (all households together); the oldest "
        "finished ones are deleted first.",
    )
    record_file_mb: float = Field(
        default=500.0,
        gt=0,
        description="A recording takes no more frames past this size, megabytes (a task that "
        "runs for hours); it says so in its log and ends with the task.",
    )
    teleop_max_v: float = Field(
        default=0.3,
        gt=0,
        le=5.0,
        description="Speed limit of a robot driven by hand (dashboard arrows and keys, POST "
        "/robots/{robot}/teleop), m/s: faster commands are clamped to it.",
    )
    teleop_max_w: float = Field(
        default=1.0,
        gt=0,
        le=20.0,
        description="Turn-rate limit of a robot driven by hand, rad/s.",
    )
    spin_w: float = Field(
        default=0.6,
        gt=0,
        le=20.0,
        description="How fast a streaming robot turns at a newly named place to photograph "
        "it, rad/s (one turn in 10.5 s at the default).",
    )
    max_image_bytes: int = Field(
        default=4 * 1024 * 1024, gt=0, description="Largest accepted image body, bytes."
    )
    max_image_pixels: int = Field(
        default=4096 * 3072, gt=0, description="Largest accepted width x height, pixels."
    )
    max_image_side: int = Field(default=8192, gt=0, description="Largest accepted width or height.")
    min_image_side: int = Field(default=16, gt=0, description="Smallest accepted width or height.")
    max_location_name: int = Field(default=64, gt=0, description="Longest location name, chars.")
    audit_days: float = Field(
        default=365.0,
        gt=0,
        description="Days an audit entry is kept; older ones are deleted (checked hourly).",
    )
    login_hours: float = Field(
        default=12.0, gt=0, le=24 * 90, description="Hours a household login stays valid."
    )
    rate_token_per_s: float = Field(
        default=RateLimits.token_per_s, gt=0, description="Sustained requests/s per token."
    )
    rate_token_burst: float = Field(
        default=RateLimits.token_burst, ge=1, description="Requests at once per token."
    )
    rate_address_per_s: float = Field(
        default=RateLimits.address_per_s, gt=0, description="Sustained requests/s per address."
    )
    rate_address_burst: float = Field(
        default=RateLimits.address_burst, ge=1, description="Requests at once per address."
    )
    failed_auth_per_s: float = Field(
        default=RateLimits.failed_auth_per_s,
        gt=0,
        description="Failed authentications forgiven per second and address.",
    )
    failed_auth_burst: float = Field(
        default=RateLimits.failed_auth_burst,
        ge=1,
        description="Failed authentications from one address before its requests wait (429).",
    )

    def database(self) -> Path | str:
        """What the server opens (:class:`server.storage.repo.Repo`): the PostgreSQL URL, or
        the SQLite file ``db``."""
        return self.database_url.get_secret_value() if self.database_url is not None else self.db

    def database_shown(self) -> str:
        """The database as it may be printed: a URL's password masked."""
        from server.storage.database import masked

        return masked(self.database())

    def recordings_dir(self) -> Path:
        """Where recordings go: ``record_dir``, or ``recordings`` beside the database."""
        return self.record_dir if self.record_dir is not None else self.db.parent / "recordings"

    def rate_limits(self) -> RateLimits:
        return RateLimits(
            token_per_s=self.rate_token_per_s,
            token_burst=self.rate_token_burst,
            address_per_s=self.rate_address_per_s,
            address_burst=self.rate_address_burst,
            failed_auth_per_s=self.failed_auth_per_s,
            failed_auth_burst=self.failed_auth_burst,
        )

    def dashboard_needs_login(self) -> bool:
        """Whether the dashboard is served behind the login (see ``dashboard_login``).
        Raises ValueError for ``dashboard_login`` false on a host that is not loopback."""
        loopback = is_loopback(self.host)
        if self.dashboard_login is False and not loopback:
            raise ValueError(
                f"dashboard_login is off, but host {self.host} is not a loopback address: "
                "anyone who can reach it would see and drive every household's robots. Leave "
                "dashboard_login unset (a household login is then required), serve on "
                "127.0.0.1, or turn the dashboard off with --dashboard-port -1"
            )
        return not loopback if self.dashboard_login is None else self.dashboard_login

    @model_validator(mode="after")
    def _database(self) -> Settings:
        """A ``sqlite:///`` URL is the file ``db``; any other URL must be PostgreSQL's."""
        from server.storage.database import POSTGRES_SCHEMES, SQLITE_SCHEME, masked, sqlite_path

        if self.database_url is None:
            return self
        url = self.database_url.get_secret_value()
        if url.startswith(SQLITE_SCHEME):
            self.db = Path(sqlite_path(url))
            self.database_url = None
        elif not url.startswith(POSTGRES_SCHEMES):
            raise ValueError(
                f"database_url {masked(url.split('://', 1)[0] + '://...')} is neither "
                "postgresql://USER:PASSWORD@HOST:PORT/NAME nor sqlite:///PATH; fix "
                "--database-url (or TEACHREPEAT_DATABASE_URL), or leave it out for the SQLite "
                "file --db"
            )
        return self

    @model_validator(mode="after")
    def _tls_pair(self) -> Settings:
        """HTTPS needs the certificate and its key: both or neither."""
        if (self.tls_cert is None) != (self.tls_key is None):
            given, missing = ("cert", "key") if self.tls_key is None else ("key", "cert")
            raise ValueError(
                f"TLS needs both a certificate and its key: tls_{given} is set but not "
                f"tls_{missing}; set --tls-{missing} (or TEACHREPEAT_TLS_{missing.upper()}) "
                f"too, or neither for plain HTTP"
            )
        return self


def is_loopback(host: str) -> bool:
    """Whether ``host`` names only this machine: ``localhost``, 127.0.0.0/8 or ::1 (``0.0.0.0``
    and ``::`` are every interface, not loopback; any other name may be reachable)."""
    if host.strip().lower().rstrip(".") == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False
