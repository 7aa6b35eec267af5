"""ritactl, the operator's client (a laptop needs only the bus library)."""

from daemon.face import lazy_face  # noqa: E402

__all__, __getattr__ = lazy_face(__name__, {"main": "main", "Exit": "exitcodes"})
