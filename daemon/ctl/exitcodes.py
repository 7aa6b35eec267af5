"""ritactl exit codes: the one list, documented in docs/operations.md ("Exit codes").

Scripts on the operator's laptop branch on these, so they never change meaning.
A procedure verb (calibrate, experiment, measure-mark, intrinsics, recompute,
follow) maps its verdict to OK / WARN / FAIL.
"""
from __future__ import annotations

import enum


class Exit(enum.IntEnum):
    OK = 0            # done; a procedure's verdict is "ok"
    WARN = 1          # a procedure finished with verdict "warn"
    FAIL = 2          # verdict "fail", a failed/cancelled/stopped job, or a calibration error
    NO_ANSWER = 3     # no reply: the daemon is down (its ipc socket file is missing), unreachable,
    #                   or refused this key
    REFUSED = 4       # the daemon answered with an error (bad_args, device fault, forbidden, ...)
    BAD_INPUT = 5     # a local file or dataset is missing or invalid (validate found problems), or a package
    #                   the verb needs is not installed (the message names the extra)
    USAGE = 64        # bad command line (sysexits EX_USAGE)
    INTERRUPTED = 130  # Ctrl-C (128 + SIGINT)


def for_verdict(verdict: str | None) -> Exit:
    """OK / WARN / FAIL for a procedure verdict; anything unknown counts as FAIL."""
    return {"ok": Exit.OK, "warn": Exit.WARN}.get(verdict or "", Exit.FAIL)


class CtlError(Exception):
    """A failure a ritactl verb reports itself: ``main()`` prints ``message`` and exits with ``exit``.

    ``code`` is the short word shown as ``{"error": code}`` with ``--json`` (e.g. ``bad_input``).
    """

    def __init__(self, exit: Exit, code: str, message: str) -> None:
        super().__init__(message)
        self.exit = exit
        self.code = code


def bad_input(message: str) -> CtlError:
    """A local file or dataset is missing or invalid (exit 5)."""
    return CtlError(Exit.BAD_INPUT, "bad_input", message)


def missing_extra(what: str, extra: str, packages: str, exc: ImportError) -> CtlError:
    """A verb that needs packages this install lacks (exit 5): the message names the extra to install."""
    missing = f"{exc.name} is not installed" if exc.name else str(exc)
    return CtlError(Exit.BAD_INPUT, "missing_package",
                    f"{what} needs {packages} on this computer ({missing}): pip install 'rita[{extra}]'")
