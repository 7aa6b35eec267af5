"""systemd notify: datagrams to NOTIFY_SOCKET, abstract addresses, and a silent no-op without it."""
import os
import socket

from daemon.ritad.notify import Notifier


def test_notify_sends_datagrams(tmp_path):
    path = str(tmp_path / "notify.sock")
    srv = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    srv.bind(path)
    srv.settimeout(2)
    n = Notifier(path)
    assert n.ready("bus up")
    assert srv.recv(4096) == b"READY=1\nSTATUS=bus up"
    n.watchdog(); assert srv.recv(4096) == b"WATCHDOG=1"
    n.status("a\nb"); assert srv.recv(4096) == b"STATUS=a b"
    n.stopping(); assert srv.recv(4096) == b"STOPPING=1"
    n.close(); srv.close()


def test_abstract_namespace():
    name = f"rita-test-{os.getpid()}"
    srv = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    srv.bind("\0" + name)
    srv.settimeout(2)
    assert Notifier("@" + name).ready()
    assert srv.recv(100) == b"READY=1"
    srv.close()


def test_no_socket_is_a_noop(monkeypatch, tmp_path):
    monkeypatch.delenv("NOTIFY_SOCKET", raising=False)
    n = Notifier()
    assert not n.enabled and n.ready() is False
    assert Notifier(str(tmp_path / "missing.sock")).ready() is False  # never raises


def test_watchdog_interval(monkeypatch):
    monkeypatch.setenv("WATCHDOG_USEC", "20000000")
    monkeypatch.setenv("WATCHDOG_PID", str(os.getpid()))
    assert Notifier("x").watchdog_interval == 10.0
    monkeypatch.setenv("WATCHDOG_PID", "1")
    assert Notifier("x").watchdog_interval is None


def test_a_socket_nobody_reads_never_blocks(tmp_path):
    """Once the unread queue is full, send drops the message and returns False at once."""
    path = str(tmp_path / "full.sock")
    srv = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    srv.bind(path)
    n = Notifier(path)
    results = [n.watchdog() for _ in range(5000)]  # far past any datagram queue length
    assert results[0] is True and results[-1] is False
    n.close(); srv.close()
