"""Laptop side of CURVE: key selection by name, no silent plaintext fallback, the
ritactl.toml config file, and `keys` sub-commands with documented exit codes."""
import os
import stat
import sys

import pytest

from daemon.ctl import config as ctl_config
from daemon.ctl.config import CtlConfigError, load_ctl_config
from daemon.ctl.keys import KeyConfigError, client_curve, resolve_connection
from daemon.ctl.exitcodes import Exit

TCP = "tcp://127.0.0.1:5555"


@pytest.fixture(autouse=True)
def clean_env(monkeypatch, tmp_path):
    """No user config or keys leak in: the default config folder is an empty temp dir."""
    for var in ("RITA_KEYS", "RITA_CONFIG", "RITA_ENDPOINT", "APPDATA"):
        monkeypatch.delenv(var, raising=False)
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "xdg"))


def keys(argv):
    from daemon.ctl.keys import add_parser
    import argparse

    ap = argparse.ArgumentParser()
    add_parser(ap.add_subparsers())
    a = ap.parse_args(["keys", *argv])
    return a.fn(None, a)


def test_ipc_and_unconfigured_tcp_use_no_keys():
    assert client_curve("ipc:///run/ritad/cmd", key_name="bob") == (None, None)
    assert client_curve(TCP) == (None, None)  # nothing configured anywhere: the daemon decides


def test_key_selected_by_name(tmp_path):
    d = tmp_path / "k"
    assert keys(["init", "--name", "bob", "--dir", str(d)]) == 0
    (d / "server.key").write_bytes((d / "bob.key").read_bytes())  # any public key file will do here
    curve, key_id = client_curve(TCP, d, "bob")
    assert curve["public"] in (d / "bob.key").read_bytes() and key_id.startswith("bob (")
    with pytest.raises(KeyConfigError) as e:  # the default name is not silently used instead
        client_curve(TCP, d)
    assert str(d / "client.key_secret") in str(e.value) and "ritactl keys init" in str(e.value)


def test_missing_files_are_named_never_plaintext(tmp_path, monkeypatch):
    d = tmp_path / "k"
    keys(["init", "--dir", str(d)])
    with pytest.raises(KeyConfigError) as e:
        client_curve(TCP, d)
    assert str(d / "server.key") in str(e.value)
    with pytest.raises(KeyConfigError) as e:
        client_curve(TCP, d, "alice")
    assert str(d / "alice.key_secret") in str(e.value) and "--name alice" in str(e.value)
    # keys in the default folder count as configured: a missing server.key is an error, not plaintext
    default = tmp_path / "xdg" / "rita"
    keys(["init", "--dir", str(default)])
    with pytest.raises(KeyConfigError) as e:
        client_curve(TCP)
    assert str(default / "server.key") in str(e.value)


def test_readable_secret_is_refused(tmp_path):
    d = tmp_path / "k"
    keys(["init", "--dir", str(d)])
    (d / "server.key").write_bytes((d / "client.key").read_bytes())
    os.chmod(d / "client.key_secret", 0o644)
    with pytest.raises(KeyConfigError) as e:
        client_curve(TCP, d)
    assert str(d / "client.key_secret") in str(e.value) and "chmod 600" in str(e.value)


def test_keys_allow_names_a_missing_file(tmp_path, capsys):
    assert keys(["allow", str(tmp_path / "nonexistent.key"),
                 "--dir", str(tmp_path / "auth")]) == Exit.BAD_INPUT
    assert f"{tmp_path / 'nonexistent.key'} does not exist" in capsys.readouterr().err
    (tmp_path / "junk.key").write_text("hello")
    assert keys(["allow", str(tmp_path / "junk.key"), "--dir", str(tmp_path / "auth")]) == Exit.BAD_INPUT
    assert "not a CURVE public key file" in capsys.readouterr().err
    keys(["init", "--name", "bob", "--dir", str(tmp_path / "k")])
    assert keys(["allow", str(tmp_path / "k" / "bob.key_secret"),
                 "--dir", str(tmp_path / "auth")]) == Exit.BAD_INPUT
    assert "secret" in capsys.readouterr().err and not (tmp_path / "auth" / "bob.key").exists()
    assert keys(["allow", str(tmp_path / "k" / "bob.key"), "--dir", str(tmp_path / "auth")]) == 0
    assert stat.S_IMODE((tmp_path / "k" / "bob.key_secret").stat().st_mode) == 0o600
    assert keys(["revoke", "--name", "nobody", "--dir", str(tmp_path / "auth")]) == Exit.BAD_INPUT
    assert keys(["init", "--name", "../evil", "--dir", str(tmp_path / "k")]) == Exit.USAGE


def test_config_file(tmp_path, monkeypatch):
    assert load_ctl_config() == {}  # no file in the default place: empty
    f = tmp_path / "ritactl.toml"
    f.write_text('endpoint = "tcp://robot:5555"\nkey = "bob"\nkeys_dir = "~/k"\ntimeout = 2\n')
    cfg = load_ctl_config(f)
    assert cfg["endpoint"] == "tcp://robot:5555" and cfg["key"] == "bob" and cfg["timeout"] == 2.0
    assert cfg["keys_dir"] == ctl_config.Path.home() / "k"
    monkeypatch.setenv("RITA_CONFIG", str(f))
    assert load_ctl_config()["key"] == "bob"
    monkeypatch.setenv("RITA_CONFIG", str(tmp_path / "missing.toml"))
    with pytest.raises(CtlConfigError, match="missing.toml does not exist"):
        load_ctl_config()
    for text, named in (('endpint = "tcp://a:1"', "'endpint'"),
                        ('endpoint = "robot:5555"', "endpoint = 'robot:5555'"),
                        ("key = 3", "key = 3"), ('key = "a/b"', "key = 'a/b'"),
                        ("timeout = -1", "timeout = -1"),
                        ("endpoint = [", "not valid TOML")):
        f.write_text(text)
        with pytest.raises(CtlConfigError) as e:
            load_ctl_config(f)
        assert named in str(e.value) and str(f) in str(e.value), (text, str(e.value))


def test_config_folder_on_windows(monkeypatch, tmp_path):
    monkeypatch.setattr(sys, "platform", "win32")
    monkeypatch.setenv("APPDATA", str(tmp_path / "Roaming"))
    assert ctl_config.config_path() == (tmp_path / "Roaming" / "rita" / "ritactl.toml", False)
    assert ctl_config.default_keys_dir() == tmp_path / "Roaming" / "rita"


def test_command_line_beats_environment_beats_file(tmp_path, monkeypatch):
    d = tmp_path / "k"
    for name in ("bob", "carol"):
        keys(["init", "--name", name, "--dir", str(d)])
    (d / "server.key").write_bytes((d / "bob.key").read_bytes())
    f = tmp_path / "ritactl.toml"
    f.write_text(f'endpoint = "tcp://robot:5555"\nkey = "bob"\nkeys_dir = "{d}"\ntimeout = 9\n')
    r = resolve_connection(config_path=f)
    assert r["endpoint"] == "tcp://robot:5555" and r["key_id"].startswith("bob (") and r["timeout"] == 9.0
    monkeypatch.setenv("RITA_ENDPOINT", "tcp://other:5555")
    assert resolve_connection(config_path=f)["endpoint"] == "tcp://other:5555"
    r = resolve_connection("tcp://cli:5555", key="carol", config_path=f)
    assert r["endpoint"] == "tcp://cli:5555" and r["key_id"].startswith("carol (")
    with pytest.raises(KeyConfigError, match="dave.key_secret"):
        resolve_connection(key="dave", config_path=f)
