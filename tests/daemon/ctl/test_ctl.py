"""ritactl: thin imports, clear errors, and the stdlib PNG writer."""
import subprocess
import sys

import numpy as np

from daemon.bus.png_write import png_bytes
from daemon.ctl import main as ctl


def test_ritactl_imports_no_opencv_harvesters_or_numpy():
    code = ("import sys, daemon.ctl.main, daemon.bus.client; daemon.ctl.main.build_parser(); "
            "print([m for m in ('cv2', 'harvesters', 'genicam', 'numpy', 'serial') if m in sys.modules])")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True)
    assert out.stdout.strip() == "[]"


def test_unreachable_daemon_is_a_clear_error(tmp_path):
    res = subprocess.run([sys.executable, "-m", "daemon.ctl.main", "--endpoint", f"ipc://{tmp_path}/none",
                          "--timeout", "0.5", "status"], capture_output=True, text=True, timeout=30)
    assert res.returncode == 3
    assert "no answer from ritad" in res.stderr and "--endpoint" in res.stderr


def test_usage_errors(capsys):
    for argv in (["tracker", "aim", "1", "2"], ["robot", "move"], ["tracker", "stream", "go"],
                 ["robot", "move", "abc"], ["robot", "turn", "400", "--yes"],
                 ["tracker", "aim", "1", "2", "nan"]):
        assert ctl.main(argv) == 64, argv
        err = capsys.readouterr().err
        assert "usage: ritactl" in err and "Traceback" not in err


def test_png_writer_roundtrip(tmp_path):
    import cv2

    img = (np.arange(37 * 23) % 256).astype(np.uint8).reshape(23, 37)
    (tmp_path / "a.png").write_bytes(png_bytes(img.tobytes(), 37, 23))
    assert np.array_equal(cv2.imread(str(tmp_path / "a.png"), cv2.IMREAD_UNCHANGED), img)
    img16 = (np.arange(37 * 23, dtype=np.uint16) * 61).reshape(23, 37)
    (tmp_path / "b.png").write_bytes(png_bytes(img16.astype(">u2").tobytes(), 37, 23, bit_depth=16))
    assert np.array_equal(cv2.imread(str(tmp_path / "b.png"), cv2.IMREAD_UNCHANGED), img16)


def test_ritactl_status_against_a_daemon_loads_no_numpy_or_opencv(tmp_path):
    """The laptop's most used verb, end to end: numpy and OpenCV blocked, it still answers (exit 0)."""
    from tests.ctl_sim import sim_daemon

    code = ("import sys\n"
            "for m in ('numpy', 'cv2', 'harvesters', 'serial'): sys.modules[m] = None  # import fails\n"
            "from daemon.ctl.main import main\nsys.exit(main(sys.argv[1:]))")
    with sim_daemon(tmp_path) as d:
        res = subprocess.run([sys.executable, "-c", code, "--endpoint", d.server.endpoints[0], "status"],
                             capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    assert "READY" in res.stdout and "Traceback" not in res.stderr
