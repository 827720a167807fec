"""``results.jsonl`` and the job folders: one record per finished job, written so that a batch
killed at any moment resumes where it stopped.

A job's files are written into a hidden temporary folder and renamed to ``DIR/<job id>`` in one
step; only then is its record appended (one line, flushed and synced). So a record always names
outputs that exist whole, and a job without a record is simply done again: a half-written
folder is replaced, a half-written last line (a kill inside ``write``) is ignored on reading.

On a re-run, a job is skipped when its latest record has the same input hash and status ``ok``
(its folder still there) or ``error`` (bad input fails the same way again); ``failed`` jobs (a
worker died twice, or a time limit) are tried again.
"""

from __future__ import annotations

import json
import os
import shutil
import time
from pathlib import Path, PurePosixPath
from typing import Any

__all__ = ["RESULTS_NAME", "ResultsLog", "write_job_files"]

RESULTS_NAME = "results.jsonl"
#: Statuses that a re-run does not redo (with the same inputs).
FINAL = ("ok", "error")
_PARTIAL = ".partial"


class ResultsLog:
    """The append-only ``results.jsonl`` of an output folder.

    Parameters
    ----------
    out_dir : Path
    """

    def __init__(self, out_dir: Path) -> None:
        self.out_dir = out_dir
        self.path = out_dir / RESULTS_NAME
        self._file: Any = None

    def latest(self) -> dict[str, dict[str, Any]]:
        """The last record of every job id (lines that do not parse are skipped)."""
        out: dict[str, dict[str, Any]] = {}
        try:
            with open(self.path, encoding="utf-8") as f:
                for line in f:
                    try:
                        rec = json.loads(line)
                    except ValueError:
                        continue  # a line cut short by a kill
                    if isinstance(rec, dict) and isinstance(rec.get("id"), str):
                        out[rec["id"]] = rec
        except FileNotFoundError:
            pass
        return out

    def is_done(self, record: dict[str, Any] | None, input_hash: str) -> bool:
        """Whether a job with this latest record and these inputs needs no new run."""
        if record is None or record.get("hash") != input_hash:
            return False
        if record.get("status") == "ok":
            return (self.out_dir / record["id"]).is_dir()
        return record.get("status") in FINAL

    def open(self) -> None:
        self.out_dir.mkdir(parents=True, exist_ok=True)
        # A kill inside a write may leave a last line without its newline: end it, so the next
        # record starts on a line of its own.
        if self.path.exists() and self.path.stat().st_size:
            with open(self.path, "rb") as f:
                f.seek(-1, os.SEEK_END)
                torn = f.read(1) != b"\n"
            if torn:
                with open(self.path, "ab") as f:
                    f.write(b"\n")
        self._file = open(self.path, "a", encoding="utf-8")  # noqa: SIM115  (closed in close())

    def append(self, record: dict[str, Any]) -> None:
        """One record, on disk before this returns."""
        record = {**record, "finished": time.strftime("%Y-%m-%dT%H:%M:%S%z")}
        self._file.write(json.dumps(record, separators=(",", ":"), default=str) + "\n")
        self._file.flush()
        os.fsync(self._file.fileno())

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None


def write_job_files(out_dir: Path, job_id: str, files: dict[str, bytes]) -> list[str]:
    """Write a job's files to ``out_dir/job_id`` whole or not at all; returns their names.

    Names are relative paths made by the worker (``view_001/color.png``); none may leave the
    job's folder.
    """
    partial = out_dir / _PARTIAL / f"{job_id}.{os.getpid()}"
    if partial.exists():
        shutil.rmtree(partial)
    names = sorted(files)
    # Checked by the name alone, before anything is written: the folder is new, so no link
    # inside it can lead out (resolving each path asked the file system twice per file).
    for name in names:
        parts = PurePosixPath(name).parts
        if (not parts or parts[0] == "/" or any(p in (".", "..") for p in parts)
                or "\\" in name or "\0" in name):
            raise ValueError(f"output name {name!r} leaves the job's folder")
    made: set[Path] = set()
    for name in names:
        target = partial / name
        if target.parent not in made:
            target.parent.mkdir(parents=True, exist_ok=True)
            made.add(target.parent)
        target.write_bytes(files[name])
    final = out_dir / job_id
    if final.exists():
        shutil.rmtree(final)  # an earlier run's outputs, for other inputs or never recorded
    os.replace(partial, final)
    return names


def clean_partial(out_dir: Path) -> None:
    """Remove what killed runs left half-written."""
    shutil.rmtree(out_dir / _PARTIAL, ignore_errors=True)

