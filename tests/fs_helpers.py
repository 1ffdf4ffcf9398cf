"""A small real file system for the tests that fill a disk."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest


def mount_tmpfs(mnt: Path, size: str) -> None:
    """Make ``mnt`` and mount a real tmpfs of ``size`` (mount's -o size=) on it, or skip the test:
    mounting needs the right to (root in CI containers)."""
    mnt.mkdir()
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(mnt)],
                          capture_output=True, text=True)
    if done.returncode != 0:
        pytest.skip(f"cannot mount a small tmpfs to fill a disk: {done.stderr.strip() or done.returncode}")
