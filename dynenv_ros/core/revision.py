"""Which code made a file: the git revision of the source tree, recorded in checkpoints, policies and the test
ledger."""
from __future__ import annotations

import functools
import re
import subprocess
from pathlib import Path


@functools.lru_cache(maxsize=1)
def code_revision() -> str | None:
    """``git rev-parse HEAD`` of the source tree this module runs from, or None (not a git checkout, no git)."""
    try:
        out = subprocess.run(["git", "rev-parse", "HEAD"], cwd=Path(__file__).resolve().parent, timeout=5,
                             capture_output=True, text=True, check=False)
    except (OSError, subprocess.SubprocessError):
        return None
    revision = out.stdout.strip()
    return revision if out.returncode == 0 and re.fullmatch(r"[0-9a-f]{40,64}", revision) else None
