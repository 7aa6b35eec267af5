"""The guided procedures, each declared once: name, ritactl verb, help, parameters, whether it drives.

Everything else is derived from these declarations: ``calib.start``'s choices and the daemon's
check of a new job's ``params`` and their defaults (``Procedure.resolve``: ritad is the authority and
stores the resolved parameters with the job, the worker and the computation read them; the clients'
checks, ``check_params``, only answer earlier), ritactl's procedure verbs and their
options (daemon/ctl/procverbs.py; each parameter's ``--name`` plus its ``aliases``), the
console's per-procedure form (``schema``), which jobs a STOP stops (``MOVING_PROCEDURES``), which
stored inputs an offline recompute may replace (``inputs``), and the procedure table in
docs/operations.md (``python -m daemon.bus.procedures --markdown``; a test compares).

The programs attach their code to a declaration with :class:`Hooks` (the worker's ``run`` and
``finish``, the computation's ``compute``): a declared procedure without its hook fails at
import, not when a job of it arrives. A procedure's name is written here and nowhere else.
Stdlib only, like the command table.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field, make_dataclass
from functools import cached_property
from typing import Any, Callable, ClassVar, Generic, Iterator, TypeVar, cast

from daemon.bus.args import BadValue
from daemon.bus.procedure_params import (APPROACH_SPEED, CALIBRATION, COMPENSATION, DISTANCE, IMU_INTERVAL,
                                         IMU_READINGS, KIND, MARK_SIZE, MARK_XY, SIGMA_T, SPEED, STREAM_RATE,
                                         Param, ParamError, xyz_map)
from daemon.bus.protocol import CommandError

#: what the result shows (ritactl, the console's panel and plot)
VIEWS = ("pose", "camera_model", "mark", "clusters", "checks")


class Resolved:
    """A job's parameters with every default applied (:meth:`Procedure.resolve`): a frozen dataclass per
    procedure, read by attribute. A value the run decides is None, as the parameter's ``default_text``
    says (the robot's installed file, its current heading, the tracker's configured rate, the computation's
    σ).
    """

    procedure: ClassVar[str] = ""

    def to_dict(self) -> dict[str, Any]:
        """The JSON form stored with the job (``calib.jobs``, state.json's ``params``): every parameter."""
        values = {n: getattr(self, n) for n in self.__dataclass_fields__}
        return {n: list(v) if isinstance(v, tuple) else v for n, v in values.items()}

    def __getattr__(self, name: str) -> Any:  # reached only for a name that is no field
        raise AttributeError(f"{self.procedure}: no parameter {name!r}")


@dataclass(frozen=True)
class Procedure:
    """One guided procedure as every program sees it."""

    name: str                    # calib.start's ``procedure``, the datasets' ``procedure``
    verb: str                    # the ritactl verb that starts it
    help: str
    params: tuple[Param, ...]
    moves: bool                  # drives the robot: a STOP stops its job; it cannot start while latched
    view: str                    # one of VIEWS
    inputs: dict[str, str] = field(default_factory=dict)  # replaceable definition → its key in the stored obs

    def __post_init__(self) -> None:
        names = [p.name for p in self.params]
        for i, p in enumerate(self.params):  # resolve() applies defaults in order
            ordered = not p.default_of or p.default_of in names[:i]
            assert ordered, f"{self.name}.{p.name} before {p.default_of}"

    def param(self, name: str) -> Param:
        return next(p for p in self.params if p.name == name)

    def check(self, params: Any, *, required: bool = True, paths: bool = True) -> dict[str, Any]:
        """The given parameters checked; null or absent means the default (:meth:`resolve` applies it).

        ``bad_args`` names every bad parameter: wrong type, out of range, unknown, or (``required``)
        missing. ``paths``: a file parameter may be a data-dir path (the console's form); on the bus
        it is the file's JSON object, which is what the worker uses.
        """
        if not isinstance(params, dict):
            raise ParamError(f"{self.name}: the parameters must be a JSON object, got {params!r:.80}")
        known = {p.name: p for p in self.params}
        out: dict[str, Any] = {}
        bad: list[tuple[str, str]] = [(str(n), f"unknown parameter {n!r}") for n in params if n not in known]
        for name, p in known.items():
            v = params.get(name)
            try:
                if v is None or (p.type == "file" and v == ""):
                    if p.required and required:
                        raise BadValue(f"parameter {name!r} is required ({p.help})")
                    continue
                out[name] = p.checked(v, paths=paths)
            except BadValue as exc:
                bad.append((name, str(exc)))
        if bad:
            text = "; ".join(why for _, why in bad)
            if len(bad) > len([n for n, _ in bad if n in known]):
                text += f" (known: {', '.join(known)})"
            first = next((n for n, _ in bad if n in known), "")
            raise ParamError(f"{self.name}: {text}", first, tuple(n for n, _ in bad))
        return out

    @cached_property
    def resolved_type(self) -> type[Resolved]:
        """The frozen dataclass of this procedure's resolved parameters, one field per parameter in order."""
        name = "".join(w.title() for w in self.name.split("-")) + "Params"
        cls = make_dataclass(name, [(p.name, p.python_type()) for p in self.params], bases=(Resolved,),
                             frozen=True, namespace={"procedure": self.name})
        return cast(type[Resolved], cls)

    def resolve(self, params: Any, *, required: bool = True) -> Resolved:
        """The parameters checked as ``calib.start`` checks them, with every default applied: the one place a
        default is resolved. ritad stores the result with the job (``to_dict``), the worker and the
        computation read its attributes. Resolving a resolved record gives it back, so a record of any age
        resolves."""
        given = self.check(params, required=required, paths=False)
        values: dict[str, Any] = {}
        for p in self.params:  # in order: a default that follows an earlier parameter finds it resolved
            v = given.get(p.name)
            values[p.name] = p.value_of(values) if v is None else tuple(v) if p.type == "vec" else v
        return self.resolved_type(**values)


#: the inputs of the compensations at mark stops (docs/accuracy.md, "Compensations")
_COMPENSATIONS = (COMPENSATION, IMU_READINGS, IMU_INTERVAL, STREAM_RATE, APPROACH_SPEED)

REFERENCING = Procedure(
    "referencing", "calibrate", "referencing: rob_H_cam with the plate", moves=True, view="pose",
    inputs={"camera_model": "camera_model", "plate": "plate"}, params=(
        Param("plate", "file", "plate definition (plate.json)", installed="calibration/plate.json",
              default_text="the installed plate"),
        Param("camera_model", "file", "camera model (camera_model.json)",
              installed="calibration/camera_model.json", default_text="the installed camera model"),
        Param("nests_approx_trk", "file", "approximate nests {red|green|blue: [x, y, z]}, tracker frame, mm",
              content="xyz_map", default_text="none: the worker asks for each nest",
              aliases=("--nests-approx",)),
        Param("robot_approx_trk", "vec", "approximate robot reflector, tracker frame", unit="mm", length=3,
              default_text="none: the worker asks", aliases=("--robot-approx",)),
        Param("reversal", "bool", "second referencing turned 180° (instrument reversal; it also measures the "
              "reflector mount's offset)", default=True),
        DISTANCE, SPEED, SIGMA_T, IMU_READINGS, IMU_INTERVAL))
INTRINSICS = Procedure(
    "intrinsics", "intrinsics", "camera model from a hand-held board, view by view as the prompts say",
    moves=False, view="camera_model", inputs={"camera_model": "initial_model", "plate": "plate"}, params=(
        Param("board", "file", "the hand-held board's definition (board.json)",
              installed="calibration/board.json", default_text="the installed board"),))
MEASURE_MARK = Procedure(
    "measure-mark", "measure-mark", "one floor mark's ACS position with the active calibration", moves=True,
    view="mark", inputs={"calibration": "calibration"}, params=(
        MARK_XY, KIND,
        Param("heading_deg", "float", "approach heading, ACS", unit="°", lo=-360, hi=360,
              default_text="the robot's current heading", aliases=("--heading",)),
        MARK_SIZE, CALIBRATION, DISTANCE, SPEED, SIGMA_T, *_COMPENSATIONS))
EXPERIMENT = Procedure(
    "experiment", "experiment", "the paper's 8-direction experiment on one mark with the active calibration",
    moves=True, view="clusters", inputs={"calibration": "calibration"}, params=(
        MARK_XY, KIND,
        Param("directions", "int", "approach directions", default=8, lo=1),
        Param("repetitions", "int", "repetitions per direction", default=5, lo=1, aliases=("--reps",)),
        Param("seed", "int", "seed of the approach order and offsets", default=1, lo=0),
        Param("psi0_deg", "float", "heading of the first direction, ACS", unit="°", default=0.0,
              lo=-360, hi=360, aliases=("--psi0",)),
        Param("offset_mm", "float", "largest random offset of the mark from the image centre", unit="mm",
              default=3.0, lo=0),
        MARK_SIZE, CALIBRATION, DISTANCE, SPEED, SIGMA_T, *_COMPENSATIONS,
        Param("store_bias", "bool", "store the fitted robot-frame bias b in the active calibration "
              "(docs/operations.md)", default=False)))

COMMISSION = Procedure(
    "commission", "commission", "commissioning check: measures every assumption about the real devices that "
    "the docs call unverified, one by one (docs/operations.md, Commissioning)", moves=True, view="checks",
    params=(
        Param("devices", "str", "the devices to check: all, or a comma list of tracker, camera, base",
              default="all"),
        Param("allow_motion", "bool", "run the base's checks that drive it: the host watchdog and STOP's "
              "braking (~0.1 m forwards at 20-50 mm/s; clear its path)", default=False, aliases=("--yes",)),
        Param("reflector_approx_trk", "vec", "approximate reflector position to lock the tracker onto, "
              "tracker frame", unit="mm", length=3, default_text="none: a locked tracker, or the worker asks",
              aliases=("--reflector",)),
        Param("tracker_rate_hz", "float", "record rate of the tracker stream measured", unit="Hz", lo=0,
              lo_open=True, hi=1000, default_text="the tracker's configured rate ([tracker] stream_rate_hz)"),
        Param("duration_s", "float", "how long each device's stream is measured (the tracker's clock is "
              "judged from 60 s on)", unit="s", default=60.0, lo=1, hi=600)))

ALL: tuple[Procedure, ...] = (REFERENCING, INTRINSICS, MEASURE_MARK, EXPERIMENT, COMMISSION)
BY_NAME: dict[str, Procedure] = {p.name: p for p in ALL}
PROCEDURES: tuple[str, ...] = tuple(BY_NAME)
#: the procedures that drive the robot: a STOP stops their jobs, and they cannot start while it is latched
MOVING_PROCEDURES: tuple[str, ...] = tuple(p.name for p in ALL if p.moves)
PARAMS: dict[str, tuple[Param, ...]] = {p.name: p.params for p in ALL}
assert all(p.view in VIEWS for p in ALL)


def get(name: str) -> Procedure:
    """The declaration of ``name``; ``bad_args`` naming the known ones otherwise."""
    if name not in BY_NAME:
        raise ParamError(f"{name!r}: no such procedure (one of {', '.join(PROCEDURES)})")
    return BY_NAME[name]


T = TypeVar("T", bound=Callable[..., Any])


class Hooks(Generic[T]):
    """One program's code per procedure (``run``, ``compute``, ``finish``), attached to the declarations.

    ``@hooks.on(EXPERIMENT)`` registers; ``hooks[name]`` finds; ``complete()`` fails naming any
    declared procedure left without one (unless ``optional``: then ``hooks.get(name)`` may be None).
    """

    def __init__(self, what: str, optional: bool = False) -> None:
        self.what, self.optional = what, optional
        self._fns: dict[str, T] = {}

    def on(self, proc: Procedure) -> Callable[[T], T]:
        def register(fn: T) -> T:
            assert proc.name not in self._fns, f"two {self.what} hooks for {proc.name}"
            self._fns[proc.name] = fn
            return fn
        return register

    def __getitem__(self, name: str) -> T:
        get(name)
        if name not in self._fns:
            raise KeyError(f"no {self.what} for procedure {name!r}")
        return self._fns[name]

    def get(self, name: str) -> T | None:
        return self._fns.get(name)

    def __iter__(self) -> Iterator[str]:
        return iter(self._fns)

    def complete(self) -> "Hooks[T]":
        missing = [p.name for p in ALL if p.name not in self._fns]
        if missing and not self.optional:
            raise RuntimeError(f"declared procedure(s) without a {self.what}: {', '.join(missing)}")
        return self


def check_params(procedure: str, params: Any, *, required: bool = True, paths: bool = True) -> dict[str, Any]:
    """:meth:`Procedure.check` of the procedure named ``procedure`` (``bad_args`` for an unknown one)."""
    return get(procedure).check(params, required=required, paths=paths)


def _file_object(procedure: str, p: Param, path: str, read: Callable[[str], bytes]) -> Any:
    try:
        obj = json.loads(read(path))
    except (OSError, CommandError, ValueError) as exc:
        why = exc.args[0] if exc.args else type(exc).__name__
        raise ParamError(f"{procedure}: parameter {p.name!r}: cannot use {path}: {why}", p.name) from None
    if p.content == "xyz_map":
        try:
            return xyz_map(f"parameter {p.name!r}", obj)
        except BadValue as exc:
            raise ParamError(f"{procedure}: {exc} (in {path})", p.name) from None
    if not isinstance(obj, dict):
        raise ParamError(f"{procedure}: parameter {p.name!r}: {path} is not a JSON object", p.name)
    return obj


def load_files(procedure: str, params: dict[str, Any], read: Callable[[str], bytes]) -> dict[str, Any]:
    """``params`` (checked) with each file path replaced by the parsed JSON ``read(path)`` returns.

    ``read`` raises OSError/CommandError for a missing file; either becomes ``bad_args`` naming the parameter.
    """
    out = dict(params)
    for p in get(procedure).params:
        if p.type == "file" and isinstance(out.get(p.name), str):
            out[p.name] = _file_object(procedure, p, out[p.name], read)
    return out


def schema() -> dict[str, list[dict[str, Any]]]:
    """The form description the console page renders: per procedure, its parameters in order."""
    return {proc: [{"name": p.name, "kind": p.type, "help": p.help, "unit": p.unit, "required": p.required,
                    "default": None if p.required else p.default, "default_text": p.default_text,
                    "lo": p.lo, "hi": p.hi, "lo_open": p.lo_open, "range": p.range_text(),
                    "choices": list(p.choices), "length": p.length, "installed": p.installed}
                    for p in params] for proc, params in PARAMS.items()}


def describe() -> dict[str, dict[str, Any]]:
    """What a client shows of each procedure besides its form: verb, help, whether it drives, its view."""
    return {p.name: {"verb": p.verb, "help": p.help, "moves": p.moves, "view": p.view,
                     "inputs": sorted(p.inputs)} for p in ALL}


def cli_flags(p: Param) -> tuple[str, ...]:
    """A parameter's ritactl options: ``--name-with-dashes`` (a bool also ``--no-name``), then its aliases."""
    name = p.name.replace('_', '-')
    return (f"--{name}", *((f"--no-{name}",) if p.type == "bool" else ()), *p.aliases)


def _rows() -> Iterator[str]:
    yield "| procedure | ritactl | drives | parameter | options | type, range | default | what |"
    yield "|---|---|---|---|---|---|---|---|"
    for proc in ALL:
        for i, p in enumerate(proc.params):
            first = (f"`{proc.name}`", f"`ritactl {proc.verb}`", "yes" if proc.moves else "no")
            head = first if i == 0 else ("",) * 3  # the procedure's cells on its first row only
            bar = "\\|"  # a bar inside a cell would split it
            kind = p.type + (f", {p.unit}" if p.unit else "")
            kind += f", {p.range_text()}" if p.range_text() else ""
            kind += (", " + f" {bar} ".join(p.choices)) if p.choices else ""
            default = "**required**" if p.required else (p.default_text or json.dumps(p.default))
            flags = ", ".join(f"`{f}`" for f in cli_flags(p))
            what = p.help.replace('|', bar)
            yield f"| {' | '.join(head)} | `{p.name}` | {flags} | {kind} | {default} | {what} |"


def markdown_table() -> str:
    """The procedure table of docs/operations.md, generated from the declarations."""
    return "\n".join(_rows()) + "\n"


if __name__ == "__main__":
    import sys

    if sys.argv[1:] != ["--markdown"]:
        sys.exit("usage: python -m daemon.bus.procedures --markdown")
    sys.stdout.write(markdown_table())
