"""Opening the robot base's serial port without resetting it, and saying why an open failed.

An Arduino-class base resets when DTR is asserted: its USB-serial chip's DTR pin reaches the MCU's
RESET through a capacitor, and pyserial asserts DTR (and RTS) on open by default. pyserial's API docs
(pyserial.readthedocs.io, "pySerial API": ``Serial.dtr``/``Serial.rts`` may be assigned before the
port is opened and are applied by ``open()``; ``serial_for_url(..., do_not_open=True)`` returns the
port unopened) give the way out: the host opens with both held low and flow control off, unless the
URL asks otherwise (``dtr=1``/``rts=1``, docs/robot-protocol.md).

Limit, public (pyserial issue #124 and its linked reports): on Linux the tty layer itself raises DTR
and RTS for a moment at every open of a real serial port, before any program can lower them, and
lowers them at close while the termios flag HUPCL is set. A base with auto-reset may therefore still
reset at an open; the HELLO boot window (drivers/robot.py) rides through that. With ``dtr=1`` the host
clears HUPCL on a local port, so that DTR stays up between opens and only the first open is an edge.
"""
from __future__ import annotations

import errno
import grp
import os
import pwd
import termios
from typing import Any

import serial

#: schemes whose pyserial class has no write timeout (rfc2217 raises NotImplementedError for one)
NO_WRITE_TIMEOUT = frozenset({"rfc2217"})


def open_port(target: str, scheme: str, *, baudrate: int, timeout: float, write_timeout: float,
              dtr: bool, rts: bool) -> Any:
    """The port at ``target`` opened with DTR/RTS as asked and flow control off; SerialException/OSError
    as pyserial raises them."""
    port = serial.serial_for_url(target, do_not_open=True, baudrate=baudrate, timeout=timeout,
                                 write_timeout=None if scheme in NO_WRITE_TIMEOUT else write_timeout,
                                 rtscts=False, dsrdtr=False, xonxoff=False)
    port.dtr, port.rts = dtr, rts  # before open: the state pyserial sets at open (no assert-then-drop)
    port.open()
    if dtr and scheme == "serial":
        _keep_lines_on_close(port)
    return port


def _keep_lines_on_close(port: Any) -> None:
    """Clear HUPCL: a close then leaves DTR up, so the next open raises no edge (a reset) on it."""
    try:
        fd = port.fileno()
        attrs = termios.tcgetattr(fd)
        attrs[2] &= ~termios.HUPCL
        termios.tcsetattr(fd, termios.TCSANOW, attrs)
    except (AttributeError, OSError, termios.error, serial.SerialException):
        pass  # not a local tty (a pty of a test, a URL handler): nothing to keep


def open_error(target: str, exc: BaseException) -> str:
    """Why the port did not open: for a permission denied, the device, its group, this process's user and
    groups, and the unit settings that cause it most often."""
    if getattr(exc, "errno", None) != errno.EACCES or not target.startswith("/"):
        return f"cannot open robot port {target!r}: {exc}"
    return f"cannot open robot port {target!r}: permission denied. " + permission_hint(target)


def permission_hint(device: str) -> str:
    """Who owns ``device``, who we are, and what to check (docs/operations.md, "Serial port")."""
    try:
        st = os.stat(device)
        owner = f"{_group(st.st_gid)} (mode {st.st_mode & 0o777:o})"
    except OSError as exc:
        owner = f"unknown ({exc.strerror})"
    user = _user(os.geteuid())
    groups = ", ".join(sorted({_group(g) for g in (os.getegid(), *os.getgroups())}))
    return (f"The device's group is {owner}; this process runs as user {user} in groups {groups}. "
            "Under systemd: the unit needs SupplementaryGroups= naming the device's group, and "
            "PrivateUsers=yes can leave that group unmapped (systemd issue #41994): remove it "
            "(`systemctl show ritad -p SupplementaryGroups -p PrivateUsers`). Outside systemd: "
            f"`sudo usermod -aG {owner.split()[0]} {user}` and log in again.")


def _group(gid: int) -> str:
    try:
        return grp.getgrgid(gid).gr_name
    except KeyError:
        return str(gid)


def _user(uid: int) -> str:
    try:
        return pwd.getpwuid(uid).pw_name
    except KeyError:
        return str(uid)
