"""Config loading: the robot's example file, built-in sim config, and errors that name key and file."""
import json
from pathlib import Path

import pytest

from daemon.ritad import config
from drivers.base import DeviceURL

ROOT = Path(__file__).resolve().parents[3]
#: every device URL is required; the tests of other keys use the simulated ones
SIM_DEVICES = "[devices]\ncamera = 'sim:'\ntracker = 'sim:'\nrobot = 'sim:'\n"


def test_example_config_loads():
    cfg = config.load(ROOT / "systemd" / "ritad.toml")
    assert cfg.devices.tracker == "emscon://192.168.0.1:700"
    url = DeviceURL.parse(cfg.devices.camera)
    assert url.scheme == "genicam" and url.path.endswith("GenTL_LUCID.cti") and url.query["serial"]
    assert DeviceURL.parse(cfg.devices.robot).option("baudrate", 9600, int) == 115200
    assert all(DeviceURL.parse(u).scheme != "sim" for u in cfg.device_urls().values())


def test_sim_config(tmp_path):
    cfg = config.sim_config(tmp_path)
    assert set(cfg.device_urls().values()) == {"sim:"} and cfg.plugins["sim"]["seed"] == 1
    assert cfg.daemon.command_endpoints == [f"ipc://{tmp_path}/cmd"]


@pytest.mark.parametrize("text, needle", [
    ("[daemon]\nfoo = 1\n", "daemon.foo"),
    ("[daemon]\nhealth_interval_s = 'fast'\n", "daemon.health_interval_s: expected a number, got str 'fast'"),
    ("[daemon]\nhealth_interval_s = 0\n", "daemon.health_interval_s must be > 0"),
    ("[camera]\nexposure_us = true\n", "camera.exposure_us"),
    ("[camera]\ntrigger = 'sometimes'\n", "camera.trigger 'sometimes'"),
    (SIM_DEVICES.replace("camera = 'sim:'", "camera = 'no-scheme'"), "devices.camera"),
    (SIM_DEVICES.replace("tracker = 'sim:'", "tracker = 'emscon://h:notaport'"), "bad port"),
    ("[daemon]\ncommand_endpoints = ['http://x']\n", "daemon.command_endpoints"),
    ("[tracker]\nabs_H_trk = [[1.0]]\n", "tracker.abs_H_trk"),
    ("[tracker]\nabs_H_trk = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, -1, 0], [0, 0, 0, 1]]\n", "det R = -1"),
    ("[sim]\nseed = 'x'\n", "sim.seed: expected an integer, got str 'x'"),
    ("[sim]\nbogus = 1\n", "unknown key(s) sim.bogus in [sim]"),
    ("[sim]\ntracker_sigma_mm = -1\n", "sim.tracker_sigma_mm must be >= 0"),
    ("[daemon]\nheartbeat_timeout_s = 0.3\n", "daemon.heartbeat_timeout_s must be >= 1.0"),
    ("[daemon]\nopen_timeout_s = -1\n", "daemon.open_timeout_s must be > 0"),
    ("bogus = 1\n", "bogus"),
    ("[daemon\n", "not valid TOML"),
])
def test_bad_config_names_key_and_file(tmp_path, text, needle):
    f = tmp_path / "bad.toml"
    f.write_text(text if "[devices]" in text or "[daemon\n" in text else SIM_DEVICES + text)
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


def test_example_config_runs_the_worker_and_is_secure():
    cfg = config.load(ROOT / "systemd" / "ritad.toml")
    assert cfg.daemon.start_worker is True  # else `ritactl calibrate` stays queued forever
    tcp = [e for e in cfg.daemon.command_endpoints if e.startswith("tcp://")]
    assert tcp and cfg.security.curve is True and cfg.security.insecure_tcp is False


def test_example_config_documents_every_key():
    """Every key ritad accepts appears in the example (set or commented), so operators can find it."""
    import dataclasses
    import re

    text = (ROOT / "systemd" / "ritad.toml").read_text()
    from daemon.ritad.plugins import installed

    keys = {f.name: [k.name for k in dataclasses.fields(getattr(config.Config(), f.name))]
            for f in dataclasses.fields(config.Config) if f.name not in ("source", "plugins")}
    keys.update({name: list(p.check_config({}, f"[{name}]")) for name, p in installed().items()})  # [sim]
    missing = []
    for name, names in keys.items():
        header = re.search(rf"^\[{name}\]$", text, re.M)
        if header is None:
            missing.append(f"[{name}]")
            continue
        body = text[header.start():].split("\n[", 1)[0]
        for key in names:
            if not re.search(rf"^#? ?{key} = ", body, re.M) and f"{key}," not in body:
                missing.append(f"{name}.{key}")
    assert missing == []


@pytest.mark.parametrize("kind, url", [("camera", "usb://0"), ("tracker", "http://192.168.0.1:80"),
                                       ("robot", "genicam:///x.cti")])
def test_unknown_device_scheme_is_a_config_error(tmp_path, kind, url):
    f = tmp_path / "c.toml"
    f.write_text(SIM_DEVICES.replace(f"{kind} = 'sim:'", f"{kind} = '{url}'"))
    with pytest.raises(config.ConfigError) as err:
        config.load(f)
    scheme = url.split(":")[0]
    assert f"devices.{kind}: unknown scheme '{scheme}'" in str(err.value) and "known:" in str(err.value)


def test_tcp_without_curve_is_refused_unless_insecure_tcp(tmp_path):
    f = tmp_path / "c.toml"
    tcp = SIM_DEVICES + "[daemon]\ncommand_endpoints = ['ipc:///tmp/x/cmd', 'tcp://127.0.0.1:5555']\n"
    f.write_text(tcp)
    with pytest.raises(config.ConfigError, match=r"daemon.command_endpoints: 'tcp://127.0.0.1:5555' is a tcp "
                                                 r"endpoint without CURVE.*insecure_tcp = true"):
        config.load(f)
    f.write_text(tcp + "[security]\ninsecure_tcp = true\n")
    assert config.load(f).security.insecure_tcp is True
    f.write_text(tcp + "[security]\ncurve = true\n")
    assert config.load(f).security.curve is True


def test_unused_server_secret_key_is_refused(tmp_path):
    f = tmp_path / "c.toml"
    f.write_text(SIM_DEVICES + "[security]\nserver_secret_key = '/etc/ritad/keys/server.key_secret'\n")
    with pytest.raises(config.ConfigError, match="security.server_secret_key is no longer supported.*"
                                                 "CREDENTIALS_DIRECTORY"):
        config.load(f)


def test_reconnect_backoff_must_be_ordered(tmp_path):
    f = tmp_path / "c.toml"
    f.write_text(SIM_DEVICES + "[daemon]\nreconnect_min_s = 5.0\nreconnect_max_s = 1.0\n")
    with pytest.raises(config.ConfigError, match="daemon.reconnect_max_s"):
        config.load(f)


@pytest.mark.parametrize("kind", ["camera", "tracker", "robot"])
def test_a_missing_device_url_is_an_error_naming_the_key(tmp_path, kind):
    """A robot config that forgets a device must not silently simulate it."""
    f = tmp_path / "c.toml"
    f.write_text("\n".join(line for line in SIM_DEVICES.splitlines() if not line.startswith(kind)))
    with pytest.raises(config.ConfigError) as err:
        config.load(f)
    assert f"devices.{kind} is missing" in str(err.value) and str(f) in str(err.value)
    f.write_text("[daemon]\nlog_level = 'INFO'\n")  # no [devices] at all: the first device is named
    with pytest.raises(config.ConfigError, match="devices.camera is missing"):
        config.load(f)


def test_empty_device_url_is_refused(tmp_path):
    f = tmp_path / "c.toml"
    f.write_text(SIM_DEVICES.replace("robot = 'sim:'", "robot = ''"))
    with pytest.raises(config.ConfigError, match="devices.robot is missing"):
        config.load(f)


def test_sim_section_reaches_the_world_through_config(tmp_path):
    """The simulator's plugin builds the world from [sim]; every sim: URL then names that one world."""
    from daemon.ritad import plugins
    from daemon.bus.station import STATION_FILE
    from fakes import worlds

    cfg = config.sim_config(tmp_path / "rt", tmp_path / "data", seed=7)
    cfg.plugins["sim"]["tracker_sigma_mm"] = 0.02
    urls = {"camera": "sim:?size=64x48", "tracker": "sim:", "robot": "emscon://127.0.0.1:700"}
    running = plugins.start(plugins.installed(), cfg.plugins, Path(cfg.daemon.data_dir), urls)
    world = running.sessions["sim"].world
    assert world.params.seed == 7 and world.params.tracker_sigma_mm == 0.02
    assert sorted(p.name for p in (tmp_path / "data" / "sim").iterdir()) == \
        ["board.json", "nests.json", "plate.json"]
    station = json.loads((tmp_path / "data" / STATION_FILE).read_text())
    assert station["abs_H_trk"] == world.abs_H_trk.tolist()  # the installer's, not a change to the config
    got = running.urls(urls)
    url = DeviceURL.parse(got["camera"])
    assert worlds.world_for(url) is world and url.option("size", "") == "64x48"
    assert got["robot"] == "emscon://127.0.0.1:700"
    assert worlds.world_for(DeviceURL.parse("sim:")) is not world  # no world= : a private one
    with pytest.raises(ValueError, match="no simulated world named 'nope'"):
        worlds.world_for(DeviceURL.parse("sim:?world=nope"))


def test_check_devices_builds_each_adapter_and_names_a_bad_option(tmp_path, monkeypatch):
    """--check-config's device check: a typo is an error naming it, a missing package only a warning
    (ritad starts without it), an adapter module that cannot be imported an error without a traceback."""
    from daemon.ritad import registry

    f = tmp_path / "c.toml"
    f.write_text(SIM_DEVICES.replace("tracker = 'sim:'", "tracker = 'emscon://127.0.0.1:700?timout=3'"))
    cfg = config.load(f)  # a start does not build the adapters: the typo passes here
    with pytest.raises(config.ConfigError, match=r"devices.tracker: tracker URL .*unknown option 'timout'"):
        config.check_devices(cfg)
    f.write_text(SIM_DEVICES.replace("camera = 'sim:'", "camera = 'genicam:///x.cti'"))
    monkeypatch.setitem(registry.ADAPTERS, "camera", {**registry.ADAPTERS["camera"], "genicam": "rita_no_pkg:Cam"})
    monkeypatch.setitem(registry.INSTALL_HINTS, "rita_no_pkg", "pip install rita-no-pkg")
    warnings = config.check_devices(config.load(f))
    assert len(warnings) == 1 and "devices.camera: URL options not checked" in warnings[0]
    assert "pip install rita-no-pkg" in warnings[0]
    monkeypatch.delitem(registry.INSTALL_HINTS, "rita_no_pkg")
    with pytest.raises(config.ConfigError, match="devices.camera: 'genicam:///x.cti': ModuleNotFoundError"):
        config.check_devices(config.load(f))
