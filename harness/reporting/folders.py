"""Results folders that never clobber: ``results/<what>-<YYYYmmdd-HHMMSS>/`` and a
``results/latest`` link to the newest one."""

from __future__ import annotations

import datetime as _dt
import logging
import os
from pathlib import Path

__all__ = ["DEFAULT_RESULTS_ROOT", "LATEST_LINK", "latest_results_folder",
           "new_results_folder"]

#: Results root of the default output folders ``results/<command>-<time>/``.
DEFAULT_RESULTS_ROOT = Path("results")
#: Name of the link in the results root that points to the newest default folder.
LATEST_LINK = "latest"

log = logging.getLogger(__name__)


def new_results_folder(command: str, root: Path = DEFAULT_RESULTS_ROOT) -> Path:
    """Create ``root/<command>-<YYYYmmdd-HHMMSS>/`` (``-2``, ``-3`` ... if taken) and
    point ``root/latest`` to it; returns the new folder.

    Every command that writes results without an explicit ``--out`` gets a folder of
    its own this way, so that no command overwrites another one's report.
    """
    root.mkdir(parents=True, exist_ok=True)
    stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    for n in range(1, 1000):
        folder = root / (f"{command}-{stamp}" if n == 1 else f"{command}-{stamp}-{n}")
        try:
            folder.mkdir()
        except FileExistsError:
            continue
        _point_latest(root, folder)
        return folder
    raise FileExistsError(f"{root}: no free folder name for {command}-{stamp}")


def _point_latest(root: Path, folder: Path) -> None:
    link = root / LATEST_LINK
    tmp = root / f".{LATEST_LINK}.{os.getpid()}"
    try:
        tmp.unlink(missing_ok=True)
        tmp.symlink_to(folder.name, target_is_directory=True)
        os.replace(tmp, link)  # atomic: a reader never sees no link
    except OSError as exc:  # no symlinks (some Windows set-ups): say where instead
        tmp.unlink(missing_ok=True)
        (root / f"{LATEST_LINK}.txt").write_text(f"{folder.name}\n", encoding="utf-8")
        log.debug("results/%s is a text file: %s", LATEST_LINK, exc)


def latest_results_folder(root: Path = DEFAULT_RESULTS_ROOT) -> Path:
    """The folder ``root/latest`` points to (FileNotFoundError if none)."""
    link = root / LATEST_LINK
    if link.is_dir():
        return link.resolve()
    text = root / f"{LATEST_LINK}.txt"
    if text.is_file():
        return (root / text.read_text(encoding="utf-8").strip()).resolve()
    raise FileNotFoundError(f"{link}: no results yet (run a command first, or pass --out)")
