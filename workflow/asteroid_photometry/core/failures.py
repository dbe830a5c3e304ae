"""Failures of the data, recorded instead of raised; bad input, refused by name.

A per-set stage that cannot give its result for a reason of the data (pycolmap
registers too few images, no unambiguous registration, too few observations to
fit) raises :class:`DataFailure`. The stage catches it and writes its declared
outputs with ``status: failed`` and the ``reason``; the stages after it read
that status and pass it on (:func:`passed_on`) instead of computing on it, and
the tables show the set as a row whose ``status`` column holds the reason and
whose numbers are empty. The run completes. Any other exception is a bug and
still fails its job, with its log.

:class:`BadInput` is the other kind: a file that is not what the workflow
wrote or expects (an image of the wrong size, NaN pixels, a malformed pose).
That stops the job at once, naming the file and what was expected.
"""

from __future__ import annotations

import logging

import numpy as np

from asteroid_photometry.core import files

log = logging.getLogger(__name__)

OK = "ok"
FAILED = "failed"


class DataFailure(Exception):
    """The data cannot give this stage's result (not a bug): recorded as the set's status, passed on by later stages."""

    def __init__(self, reason: str, upstream: bool = False):
        super().__init__(reason)
        self.upstream = upstream

    def reason_in(self, stage: str) -> str:
        """The reason as recorded: prefixed with the stage that failed (a passed-on reason keeps its own)."""
        return str(self) if self.upstream else f"{stage}: {self}"


class BadInput(ValueError):
    """An input file that is not of the expected form; the message names the file and what was expected."""


def passed_on(reason: str) -> DataFailure:
    """The failure of an earlier stage, to be recorded unchanged by this one."""
    return DataFailure(reason, upstream=True)


def record(stage: str, failure: DataFailure) -> str:
    """Log a caught failure and return its recorded reason."""
    reason = failure.reason_in(stage)
    log.warning("not computed, a failure of the data (recorded as the status): %s", reason)
    return reason


def table_status(reason: str | None = None) -> str:
    """A table's ``status`` cell: ``ok``, or ``failed: <reason>``."""
    return OK if reason is None else f"{FAILED}: {reason}"


# ------------------------------------------------------------- status in files


def write_failed_npz(path, reason: str) -> None:
    """A stage's .npz output for a set it could not process: the status and the reason, no arrays."""
    files.savez(path, status=np.str_(FAILED), reason=np.str_(reason))


def check_npz(data, path) -> None:
    """Raise the recorded failure if the loaded .npz ``data`` (of ``path``) is a failed stage's output."""
    if "status" in data.files and str(data["status"]) != OK:
        raise passed_on(str(data["reason"]) if "reason" in data.files else f"{path} is marked failed")


def write_status_json(path, reason: str | None = None, **extra) -> dict:
    """``{"status": "ok"}`` or ``{"status": "failed", "reason": ...}``, with ``extra`` keys, written to ``path``."""
    content = {"status": OK if reason is None else FAILED, **({} if reason is None else {"reason": reason}), **extra}
    files.write_json(path, content)
    return content


def check_status(content: dict, path) -> None:
    """Raise the recorded failure if ``content`` (a JSON object read from ``path``) says failed."""
    if content.get("status", OK) != OK:
        raise passed_on(content.get("reason", f"{path} is marked failed"))


def status_counts_line(table, what: str = "sets", keys=("set_id", "priors", "method")) -> str:
    """E.g. ``14 of 16 sets ok; 2 failed: light0_albedo0.5_k0.7 (reconstruct: ...); ...`` (one line of Markdown).

    A failed row is named by its ``keys`` columns (those it has).
    """
    if "status" not in table or not len(table):
        return f"{len(table)} {what}."
    ok = table["status"].fillna(OK).astype(str) == OK
    line = f"{int(ok.sum())} of {len(table)} {what} ok"
    failed = table[~ok]
    if failed.empty:
        return line + "."
    labels = failed.apply(lambda row: " ".join(str(row[key]) for key in keys if key in row and row[key] == row[key]), axis=1)
    return line + f"; {len(failed)} failed: " + "; ".join(f"{label} ({status.removeprefix(FAILED + ': ')})" for label, status in zip(labels, failed["status"])) + "."
