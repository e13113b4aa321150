"""What the console's browser tests share."""
from __future__ import annotations

import os

import pytest

from bench.console import browser_missing

CI = os.environ.get("CI", "").lower() == "true"


@pytest.fixture
def browser_ready():
    """Debian's headless Chromium and chromedriver are there (under CI=true their absence fails)."""
    missing = browser_missing()
    if missing:
        if CI:
            pytest.fail(f"the console's browser test needs a headless Chromium: {missing}")
        pytest.skip(missing)
