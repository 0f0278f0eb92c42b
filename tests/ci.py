"""Whether this run is CI's (``CI=true``, as `.ci/run` sets it): there a missing part of the
set-up (Chromium, ../shared) fails the test instead of skipping it."""

from __future__ import annotations

import os


def on_ci() -> bool:
    return os.environ.get("CI", "").strip().lower() in ("true", "1", "yes")
