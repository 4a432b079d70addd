"""Campaign records on disk: one JSON file per finished run (written atomically), the
run records of an output folder (:func:`load_records`) and of the runs it planned
(:func:`load_campaign_output`, the input of summaries over several campaigns)."""

from __future__ import annotations

import json
import os
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any


def write_json_atomic(path: Path, data: dict[str, Any]) -> None:
    """Write ``data`` as JSON to ``path`` atomically (a temporary file renamed)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}-", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            json.dump(data, fh, indent=1, sort_keys=True, allow_nan=True)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def load_records(records_dir: Path) -> dict[str, dict[str, Any]]:
    """Run id → record of every record file in ``records_dir``."""
    out = {}
    if records_dir.is_dir():
        for p in sorted(records_dir.glob("*.json")):
            try:
                out[p.stem] = json.loads(p.read_text(encoding="utf-8"))
            except json.JSONDecodeError:
                continue  # cannot happen with atomic writes; re-run it if it does
    return out


@dataclass
class CampaignOutput:
    """One campaign's output folder as :func:`load_campaign_output` reads it."""

    name: str
    out_dir: Path
    n_planned: int
    fraction: float
    records: list[dict[str, Any]]
    # flight conditions the run was restricted to (``--group``/``--condition``), if any
    selection: dict[str, list[str] | None] = field(default_factory=dict)


def load_campaign_output(out_dir: Path | str) -> CampaignOutput:
    """The records of the runs a campaign output folder planned (its ``campaign.json``),
    for summarising several campaigns as one (``python -m gyrodiag_harness campaign-summary``).

    Raises ValueError naming the folder when it holds no readable ``campaign.json``.
    """
    out_dir = Path(out_dir)
    path = out_dir / "campaign.json"
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
        name, ids = str(data["spec"]["name"]), list(data["run_ids"])
        fraction = float(data.get("fraction", 1.0))
        selection = {k: (None if v is None else [str(x) for x in v])
                     for k, v in dict(data.get("selection") or {}).items()}
    except FileNotFoundError:
        raise ValueError(f"{out_dir}: not a campaign output folder (no campaign.json; "
                         "run `gyrodiag campaign SPEC --out DIR` first)") from None
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"{path}: unreadable campaign record ({exc})") from None
    done = load_records(out_dir / "runs")
    return CampaignOutput(name=name, out_dir=out_dir, n_planned=len(ids), fraction=fraction,
                          records=[done[rid] for rid in ids if rid in done],
                          selection=selection)


def write_plan(out_dir: Path, spec: dict[str, Any], base_dir: Path, fraction: float,
               groups: Sequence[str] | None, conditions: Sequence[str] | None,
               run_ids: list[str]) -> None:
    """``<out_dir>/campaign.json``: the spec (as a dict), the runs planned and the
    selection (:func:`load_campaign_output` reads it back)."""
    write_json_atomic(out_dir / "campaign.json", {
        "spec": spec, "base_dir": str(base_dir),
        "fraction": fraction,
        "selection": {"groups": list(groups) if groups is not None else None,
                      "conditions": list(conditions) if conditions is not None else None},
        "run_ids": run_ids})


def remove_stale_temporaries(records_dir: Path) -> None:
    """Remove the temporary files of atomic writes cut short by a kill (older than a
    minute: not one being written now)."""
    for stale in records_dir.glob(".*.tmp"):  # atomic writes cut short by a kill
        if time.time() - stale.stat().st_mtime > 60.0:  # not one being written now
            stale.unlink(missing_ok=True)
