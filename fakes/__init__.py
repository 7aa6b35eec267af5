"""The simulated world and a fake for every device, speaking its protocol; the simulator's
ritad plugin (fakes/plugin.py). Enters the product only through entry points and config.
"""
from __future__ import annotations

from daemon.face import lazy_face

#: the package's public names -> the module that defines them; imported on first use
_FACE = {
    "World": "world", "WorldParams": "world", "RobotPose": "world", "PLUGIN": "plugin",
    "SimCamera": "camera", "SimTracker": "tracker", "SimRobot": "robot", "PROFILES": "profiles",
}
__all__, __getattr__ = lazy_face(__name__, _FACE)
