"""ritad, the daemon on the robot: config, device runners, command server, publishers."""

from daemon.face import lazy_face  # noqa: E402

__all__, __getattr__ = lazy_face(__name__, {"Daemon": "main", "RitadExit": "main", "main": "main", "Config": "config", "ConfigError": "config",
         "load": "config"})
