"""[sim] profile and ritad --sim --profile: the simulated world's error profile (fakes/profiles.py)."""
import pytest

from daemon.ritad import config
from daemon.ritad.main import parse_args


def _sim_cfg(tmp_path, profile: str) -> dict:
    return {"daemon": {"command_endpoints": [f"ipc://{tmp_path}/c"], "telemetry_endpoints": [f"ipc://{tmp_path}/t"],
                       "frame_endpoints": [f"ipc://{tmp_path}/f"], "data_dir": str(tmp_path / "d")},
            "devices": {"camera": "sim:", "tracker": "sim:", "robot": "sim:"},
            "sim": {"profile": profile}}


def test_a_bad_profile_is_a_config_error_naming_it_and_listing_the_profiles(tmp_path):
    with pytest.raises(config.ConfigError, match=r"sim\.profile 'papr' is not a simulation profile "
                                                 r"\(profiles: ideal, paper, paper\+imu, paper-fit, paper-fit\+imu\)"):
        config.from_dict(_sim_cfg(tmp_path, "papr"))
    assert config.from_dict(_sim_cfg(tmp_path, "paper+imu")).plugins["sim"]["profile"] == "paper+imu"
    assert config.sim_config(tmp_path, profile="paper").plugins["sim"]["profile"] == "paper"
    with pytest.raises(config.ConfigError, match="'nope'"):
        config.sim_config(tmp_path, profile="nope")


def test_ritad_profile_option_is_for_sim_only(capsys):
    assert parse_args(["--sim", "--profile", "paper"]).profile == "paper"
    with pytest.raises(SystemExit) as exc:
        parse_args(["--config", "x.toml", "--profile", "paper"])
    assert exc.value.code == 2 and "--profile applies to --sim only" in capsys.readouterr().err


def test_the_profile_reaches_the_world(tmp_path):
    from fakes import installer

    _, world = installer.start({"seed": 2, "tracker_sigma_mm": 0.01, "profile": "paper+imu"}, str(tmp_path))
    assert world.effects.model.imu is not None and world.params.base_has_inclinometer
