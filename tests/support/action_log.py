"""The rig's action log as tests read it: the entries its file holds, oldest first."""
from __future__ import annotations

import json
from pathlib import Path

from coordinator.console.audit import FILE_NAME


def action_log_entries(rig_dir: Path) -> list[dict]:
    """Every entry written to ``rig_dir``'s action log so far ([] before the first)."""
    f = Path(rig_dir) / FILE_NAME
    return [json.loads(line) for line in f.read_text().splitlines()] if f.exists() else []
