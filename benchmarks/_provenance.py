"""Provenance of a library-level benchmark's figures: commit, dirty flag, source hash."""

from __future__ import annotations

import hashlib
import subprocess
from pathlib import Path


def library_provenance(root: Path) -> dict[str, str]:
    """The commit, whether the tree is dirty, and the sha256 of the library sources."""
    def git(*a: str) -> str:
        return subprocess.run(["git", *a], cwd=root, capture_output=True, text=True,
                              check=False, timeout=60).stdout.strip()
    h = hashlib.sha256()
    for p in sorted((root / "fmu_src" / "gyrodiag").rglob("*.py")):
        h.update(p.read_bytes())
    return {"commit": git("rev-parse", "HEAD"), "dirty": str(bool(git("status", "--short"))),
            "library_sha256": h.hexdigest()}
