"""The operator console: a local web page (``ritactl console``) in front of the robot's bus.

A bus client like ritactl (layers: bus library <- programs). Needs the ``console``
extra (aiohttp); static files ship in ``daemon/console/static``.
"""
