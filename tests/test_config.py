"""Config loading: the robot's example file, built-in sim config, and errors that name key and file."""
from pathlib import Path

import pytest

from daemon import config
from drivers.base import DeviceURL

ROOT = Path(__file__).resolve().parents[1]


def test_example_config_loads():
    cfg = config.load(ROOT / "systemd" / "ritad.toml")
    assert cfg.devices.tracker == "emscon://192.168.0.1:700"
    url = DeviceURL.parse(cfg.devices.camera)
    assert url.scheme == "genicam" and url.path.endswith("GenTL_LUCID.cti") and url.query["serial"]
    assert DeviceURL.parse(cfg.devices.robot).option("baudrate", 9600, int) == 115200
    assert not cfg.uses_sim


def test_sim_config(tmp_path):
    cfg = config.sim_config(tmp_path)
    assert cfg.uses_sim and cfg.daemon.command_endpoints == [f"ipc://{tmp_path}/cmd"]


@pytest.mark.parametrize("text, needle", [
    ("[daemon]\nfoo = 1\n", "daemon.foo"),
    ("[daemon]\nhealth_interval_s = 'fast'\n", "daemon.health_interval_s: expected a number, got str 'fast'"),
    ("[daemon]\nhealth_interval_s = 0\n", "daemon.health_interval_s must be > 0"),
    ("[camera]\nexposure_us = true\n", "camera.exposure_us"),
    ("[camera]\ntrigger = 'sometimes'\n", "camera.trigger 'sometimes'"),
    ("[devices]\ncamera = 'no-scheme'\n", "devices.camera"),
    ("[devices]\ntracker = 'emscon://h:notaport'\n", "bad port"),
    ("[daemon]\ncommand_endpoints = ['http://x']\n", "daemon.command_endpoints"),
    ("[tracker]\nabs_H_trk = [[1.0]]\n", "tracker.abs_H_trk"),
    ("bogus = 1\n", "bogus"),
    ("[daemon\n", "not valid TOML"),
])
def test_bad_config_names_key_and_file(tmp_path, text, needle):
    f = tmp_path / "bad.toml"
    f.write_text(text)
    with pytest.raises(config.ConfigError) as err:
        config.load(f)
    assert needle in str(err.value)
    assert str(f) in str(err.value)


def test_missing_file(tmp_path):
    with pytest.raises(config.ConfigError, match="not found"):
        config.load(tmp_path / "nope.toml")


def test_device_url_options():
    url = DeviceURL.parse("sim:?sigma_mm=0.02&drop_after=5")
    assert url.scheme == "sim" and url.option("sigma_mm", 0.01, float) == 0.02
    with pytest.raises(ValueError, match="drop_after='x'"):
        DeviceURL.parse("sim:?drop_after=x").option("drop_after", 0, int)
