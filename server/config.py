"""Deployment settings (pydantic-settings) and the limits the API enforces.

Settings are read from the environment (prefix ``TEACHREPEAT_``) or passed explicitly, then
handed to :func:`server.app.create_app`; nothing is built at import time.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from pydantic import Field, SecretStr
from pydantic_settings import BaseSettings, SettingsConfigDict

DEFAULT_DATA_DIR = Path("data")
"""Relative to the working directory the server is started in."""


class Settings(BaseSettings):
    """Everything that differs between deployments. Environment: ``TEACHREPEAT_<NAME>``."""

    model_config = SettingsConfigDict(env_prefix="TEACHREPEAT_", extra="ignore")

    db: Path = Field(
        default=DEFAULT_DATA_DIR / "teachrepeat.sqlite",
        description="SQLite database file; created with its folder when missing.",
    )
    admin_token: SecretStr | None = Field(
        default=None,
        description="Bearer token for admin endpoints. When unset, `serve` generates one and "
        "writes it next to the database (mode 0600); it is never logged.",
    )
    host: str = Field(default="127.0.0.1", description="Interface the API binds to.")
    port: int = Field(default=8000, ge=0, le=65535, description="API port; 0 = any free port.")
    dashboard_port: int | None = Field(
        default=8080, ge=0, le=65535, description="Dashboard port; 0 = any free port; None = off."
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
    max_image_bytes: int = Field(
        default=4 * 1024 * 1024, gt=0, description="Largest accepted image body, bytes."
    )
    max_image_pixels: int = Field(
        default=4096 * 3072, gt=0, description="Largest accepted width x height, pixels."
    )
    max_image_side: int = Field(default=8192, gt=0, description="Largest accepted width or height.")
    min_image_side: int = Field(default=16, gt=0, description="Smallest accepted width or height.")
    max_location_name: int = Field(default=64, gt=0, description="Longest location name, chars.")
