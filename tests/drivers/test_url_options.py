"""Every adapter refuses a URL option it does not read, naming it: the check lives once, in drivers/base.py.

A misspelt option (``timout=3``) would otherwise leave the default (30 s) silently in force.
"""
from __future__ import annotations

import pytest

from daemon.ritad.registry import ADAPTERS, AdapterError, build_device, schemes
from drivers.base import Device, DeviceURL

#: (kind, scheme) -> a URL with one known option and one misspelt one, and the misspelt name
TYPOS: dict[tuple[str, str], tuple[str, str]] = {
    ("camera", "genicam"): ("genicam:///opt/x/GenTL_LUCID.cti?serial=1&num_bufers=4", "num_bufers"),
    ("camera", "sim"): ("sim:?size=reduced&sise=full", "sise"),
    ("tracker", "emscon"): ("emscon://127.0.0.1:700?use_adm=1&timout=3", "timout"),
    ("tracker", "sim"): ("sim:?sigma_mm=0.01&timout=3", "timout"),
    ("robot", "serial"): ("serial:///dev/ttyUSB0?baudrate=9600&baudrat=9600", "baudrat"),
    ("robot", "socket"): ("socket://127.0.0.1:7000?logging=debug&loging=debug", "loging"),
    ("robot", "loop"): ("loop://?retries=1&retrys=3", "retrys"),
    ("robot", "rfc2217"): ("rfc2217://127.0.0.1:7000?poll_modem=1&poll_modm=1", "poll_modm"),
    ("robot", "sim"): ("sim:?time_scale=0&speed=3", "speed"),
}


def test_every_registered_scheme_is_covered() -> None:
    # the product's schemes and the installed plugins' (the simulator's sim: adapters, by entry point)
    assert set(TYPOS) == {(k, s) for k in ADAPTERS for s in schemes(k)}


@pytest.mark.parametrize("kind, scheme", sorted(TYPOS))
def test_a_misspelt_option_is_refused_by_name(kind: str, scheme: str) -> None:
    url, typo = TYPOS[(kind, scheme)]
    try:
        with pytest.raises(ValueError) as err:
            build_device(kind, url)
    except AdapterError as exc:  # the adapter's package is not installed here
        pytest.skip(str(exc))
    msg = str(err.value)
    assert f"{kind} URL {url!r}: unknown option {typo!r} (known: " in msg
    known = msg.split("(known: ", 1)[1]
    assert url.split("?", 1)[1].split("=", 1)[0] in known  # the option spelt right is listed
    build_device(kind, url.rsplit("&", 1)[0])  # without the typo the same URL builds


def test_an_adapter_declaring_no_options_refuses_any() -> None:
    class Bare(Device):
        kind = "thing"

        def open(self) -> None: ...

        def close(self) -> None: ...

    Bare(DeviceURL.parse("x://h"))
    with pytest.raises(ValueError,
                       match=r"thing URL 'x://h\?a=1&b=2': unknown options 'a', 'b' \(known: none\)"):
        Bare(DeviceURL.parse("x://h?a=1&b=2"))
