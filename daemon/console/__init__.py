"""The operator console: a local web page (``ritactl console``) in front of the robot's bus.

A bus client like ritactl (layers: bus library <- programs). Needs the ``console``
extra (aiohttp); static files ship in ``daemon/console/static``.
"""

from daemon.face import lazy_face  # noqa: E402

__all__, __getattr__ = lazy_face(__name__, {"Console": "server", "serve": "server"})
