"""ritactl's terminal I/O, shared by every verb: results, notes, errors and yes/no questions.

With ``--json``, stdout carries only JSON (the result, or an error object) and the
human notes (progress, hints, questions) go to stderr, so ``ritactl --json … | jq``
always reads one document. Errors are ``{"error": code, "message": text, "exit": n}``
on stdout with ``--json``, else ``ritactl: text`` on stderr.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
from typing import Any

from daemon.ctl.exitcodes import Exit


def print_result(obj: Any, as_json: bool) -> None:
    if as_json:
        print(json.dumps(obj, indent=2, default=str), flush=True)
    elif isinstance(obj, dict):
        for k, v in obj.items():
            print(f"{k}: {json.dumps(v, default=str) if isinstance(v, (dict, list)) else v}")
    else:
        print(obj)


def say(text: str, as_json: bool = False) -> None:
    """A line for the person at the terminal (stderr under ``--json``)."""
    print(text, file=sys.stderr if as_json else sys.stdout, flush=True)


def fail(exit: Exit, code: str, message: str, as_json: bool) -> int:
    """Report an error the documented way and return its exit code."""
    try:
        if as_json:
            print(json.dumps({"error": code, "message": message, "exit": int(exit)}), flush=True)
        else:
            print(f"ritactl: {message}", file=sys.stderr, flush=True)
    except BrokenPipeError:
        quiet_stdout()
    except OSError:
        pass  # nowhere left to say it; the exit code still tells
    return int(exit)


def ask(question: str) -> str | None:
    """Ask on the terminal; the stripped line, or None at end of input (Ctrl-D, closed stdin).

    The question goes to stderr so it never mixes with ``--json`` output.
    A KeyboardInterrupt while waiting propagates: callers give it a meaning.
    """
    print(question, end="", file=sys.stderr, flush=True)
    line = sys.stdin.readline() if sys.stdin is not None else ""
    return line.strip() if line else None


def yes_after_ctrl_c(question: str, as_json: bool = False) -> bool:
    """After a Ctrl-C: ask ``question [y/N]``; y or a second Ctrl-C is yes, Enter or end of input is no."""
    try:
        say("", as_json)
        answer = ask(f"{question} [y/N] (Ctrl-C again: yes) ")
    except KeyboardInterrupt:
        return True
    return (answer or "").lower() in ("y", "yes")


def quiet_stdout() -> None:
    """After EPIPE (``ritactl … | head``), point stdout at devnull so the exit flush stays silent."""
    try:
        fd = sys.stdout.fileno()
    except (AttributeError, ValueError, OSError):
        return  # not a real file (tests capture it): nothing will flush at exit
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, fd)
    os.close(devnull)



def subparsers_of(p: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    """The subcommands of ``p`` by name (aliases included)."""
    for action in p._actions:  # argparse keeps no public list
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}
