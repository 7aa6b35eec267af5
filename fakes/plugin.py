"""The simulator as a ritad plugin: the shared world, its installer and the ``sim.*`` commands.

Registered in pyproject.toml (``rita.adapters``: ``plugin.sim`` beside the ``sim:`` device
adapters); ritad finds it as it would any third-party plugin (daemon/ritad/plugins.py). When a
configured device URL is ``sim:``, :meth:`SimPlugin.start` builds one world from the ``[sim]``
section, plays the installer into the data dir (the definition files of fakes/installer.py and,
for a simulated tracker, the station file ritad reads ``abs_H_trk`` from), and names the world
in every ``sim:`` URL. The commands stand in for what an operator's hands and eyes do on the
real floor; ``sim.truth`` scores results and is never read by the product.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Callable, Mapping
from urllib.parse import quote

from daemon.bus.command_table import Arg, Command
from daemon.bus.protocol import CommandError, ErrorCode
from drivers.base import DeviceURL

NAME = "sim"
SCHEME = "sim"

COMMANDS: tuple[Command, ...] = (
    Command("sim.truth", "simulated world only: ground truth", polled=True,
            result="rob_H_cam, abs_H_ref, abs_H_trk, abs_H_rob, nests, marks, camera_model, plate; not_found "
            "without a simulated world"),
    Command("sim.place_robot_on_plate", "simulated world only: put the robot on the plate, target in view",
            "operator", motion="moves", result="{x_mm, y_mm, heading_deg}", args=(
                Arg("heading_deg", "float", "robot heading", unit="°", lo=-360, hi=360,
                    default_text="plate yaw + 60"),)),
    Command("sim.hold_board", "simulated world only: the operator holds the calibration board under "
            "the camera (pose in the camera frame), or takes it away", "operator",
            result="{held, board_id, cam_H_board}", args=(
                Arg("z_mm", "float", "board centre's depth along the optical axis", unit="mm", lo=0,
                    lo_open=True, default_text="the board is taken away"),
                Arg("x_mm", "float", "board centre, camera x (image right)", unit="mm", default=0.0),
                Arg("y_mm", "float", "board centre, camera y (image down)", unit="mm", default=0.0),
                Arg("tilt_x_deg", "float", "tilt about the image x axis (+: top edge towards the camera)",
                    unit="°", default=0.0, lo=-80, hi=80),
                Arg("tilt_y_deg", "float", "tilt about the image y axis (+: right edge towards the camera)",
                    unit="°", default=0.0, lo=-80, hi=80),
                Arg("rot_deg", "float", "turn in the image plane (+: clockwise in the image)", unit="°",
                    default=0.0, lo=-360, hi=360))),
    Command("sim.survey_images", "simulated world only: photograph the whole plate with a survey camera "
            "(PNG, RGB) into data_dir/sim/survey/, for `ritactl plate survey`", "operator",
            result="{folder, files}: paths relative to the data dir; rendering takes ~2 s per view "
            "(use --timeout)", args=(
                Arg("views", "int", "number of photographs", default=8, lo=3, hi=12),
                Arg("width_px", "int", "image width (height 2/3 of it; the 6000x4000 sensor resampled; the "
                    "renderer peaks at ~0.7 GB at 2400)", unit="px", default=2400, lo=900, hi=3000))),
)

#: the [sim] section: key -> (type, default)
SECTION: dict[str, tuple[type, Any]] = {"seed": (int, 1), "tracker_sigma_mm": (float, 0.010),
                                        "profile": (str, "ideal")}


def _typed(key: str, value: Any, kind: type, where: str) -> Any:
    ok = isinstance(value, kind) or (kind is float and isinstance(value, int))
    if isinstance(value, bool) or not ok:
        noun = {int: "an integer", float: "a number", str: "str"}[kind]
        raise ValueError(f"{where.strip('[]')}.{key}: expected {noun}, got {type(value).__name__} {value!r}")
    return kind(value)


class SimSession:
    """One ritad's world: built at start, handed to the sim.* handlers, dropped at stop."""

    def __init__(self, section: Mapping[str, Any], data_dir: Path, urls: Mapping[str, str]) -> None:
        from daemon.bus.storage import atomic_write_json
        from daemon.bus.station import STATION_FILE
        from fakes import installer

        self.name, self.world = installer.start(section, str(data_dir))
        if DeviceURL.parse(urls["tracker"]).scheme == SCHEME:  # the simulated tracker stands in this world
            atomic_write_json(Path(data_dir) / STATION_FILE,
                              {"abs_H_trk": self.world.abs_H_trk.tolist(),
                               "source": f"simulated world (seed {section['seed']}, "
                                         f"profile {section['profile']})"})

    def urls(self, urls: dict[str, str]) -> dict[str, str]:
        """Every ``sim:`` URL names this world (others unchanged)."""
        out = {}
        for kind, url in urls.items():
            parsed = DeviceURL.parse(url)
            if parsed.scheme == SCHEME and "world" not in parsed.query:
                url = f"{url}{'&' if '?' in url else '?'}world={quote(self.name, safe='')}"
            out[kind] = url
        return out

    def hello(self) -> dict[str, Any]:
        return {"sim": True}

    def close(self) -> None:
        self.world = None

    def handlers(self, s: Any) -> dict[str, Callable[[Any], Any]]:
        w = self.world

        def truth(req: Any) -> Any:
            out = w.truth()
            size = s.device_info("camera").get("size") or list(w.params.reduced_size)
            out["camera_model"] = {"K": w.camera_matrix(tuple(size)).tolist(),
                                   "dist": w.dist_coeffs().tolist(), "size": list(size)}
            out["plate"] = w.plate().to_dict()
            return out

        def place_robot_on_plate(req: Any) -> Any:
            """Put the robot on the plate with the target in view (an operator's job on the real floor)."""
            heading = req.args["heading_deg"]
            pose = w.pose_with_target_in_view(w.plate_yaw_deg + 60.0 if heading is None else heading)
            w.set_robot(w.settle(pose))  # on its wheels: the tilt of the plate under them (error profiles)
            return {"x_mm": pose.x_mm, "y_mm": pose.y_mm, "heading_deg": pose.heading_deg}

        def hold_board(req: Any) -> Any:
            """The operator holds the intrinsics board under the camera (an operator's hands on the
            real robot)."""
            try:
                return w.hold_board(**req.args)
            except ValueError as exc:
                raise CommandError(ErrorCode.BAD_ARGS, f"{req.cmd}: {exc}") from None

        def survey_images(req: Any) -> Any:
            """Whole-plate photographs for the plate survey (an operator's camera on the real floor)."""
            from fakes.survey_views import install as render

            a, root = req.args, Path(s.data_dir)

            def run() -> Any:
                paths = render(w, root, a["views"], (a["width_px"], a["width_px"] * 2 // 3))
                return {"folder": "sim/survey", "files": [p.relative_to(root).as_posix() for p in paths]}

            return s.storage.submit(run)

        return {"sim.truth": truth, "sim.place_robot_on_plate": place_robot_on_plate,
                "sim.hold_board": hold_board, "sim.survey_images": survey_images}


class SimPlugin:
    name = NAME
    commands = COMMANDS

    def check_config(self, table: Mapping[str, Any], where: str) -> dict[str, Any]:
        """The ``[sim]`` section with defaults; a bad key or value is named (ritad adds the file)."""
        unknown = sorted(set(table) - set(SECTION))
        if unknown:
            raise ValueError(f"unknown key(s) {', '.join(f'{NAME}.{u}' for u in unknown)} in {where} "
                             f"(known: {', '.join(sorted(SECTION))})")
        out = {k: _typed(k, table[k], kind, where) if k in table else default
               for k, (kind, default) in SECTION.items()}
        if out["tracker_sigma_mm"] < 0:
            raise ValueError(f"{NAME}.tracker_sigma_mm must be >= 0, got {out['tracker_sigma_mm']}")
        from fakes.profiles import PROFILES

        if out["profile"] not in PROFILES:
            raise ValueError(f"{NAME}.profile {out['profile']!r} is not a simulation profile "
                             f"(profiles: {', '.join(PROFILES)})")
        return out

    def start(self, section: Mapping[str, Any], data_dir: Path, urls: Mapping[str, str]) -> SimSession | None:
        """A world when any device is simulated; nothing otherwise."""
        if not any(DeviceURL.parse(u).scheme == SCHEME for u in urls.values()):
            return None
        return SimSession(section or self.check_config({}, f"[{NAME}]"), data_dir, urls)


PLUGIN = SimPlugin()

__all__ = ["COMMANDS", "NAME", "PLUGIN", "SimPlugin", "SimSession"]
