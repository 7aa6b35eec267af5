"""The writing half of ``ritactl record``: bus messages in, MCAP out (no sockets: the benchmark and
the tests drive it directly). The layout is daemon/ctl/mcapfile.py's and docs/operations.md's.

Every message is logged at its sample's own time (:func:`mcapfile.sample_time`) and counted per
channel (the MCAP ``sequence``). Beside ritad's own channels it writes Foxglove's well-known
messages (daemon/ctl/foxglove.py): the robot's pose, each tracker record, the journal, and frames
as RawImage or, with ``frames_format`` jpeg or png, CompressedImage.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import IO, Any, Callable

from daemon import __version__
from daemon.ctl import foxglove as fox
from daemon.ctl import mcapfile as fmt
from daemon.ctl.exitcodes import CtlError, Exit, missing_extra
from daemon.ctl.foxglove_schemas import schema_bytes
from daemon.ctl.reclimits import Limits

FRAME_FORMATS = ("raw", "jpeg", "png")
#: the bytes a frame's image record adds beyond its pixels (the RawImage's own fields)
IMAGE_OVERHEAD = 256


@dataclass
class Counts:
    messages: int = 0
    frames: int = 0
    missed: int = 0          # telemetry messages lost before they reached the recorder (seq gaps)
    frames_missed: int = 0   # frames dropped for this subscriber (not the ones --frames skips)
    unsupported: int = 0     # frames with no RawImage encoding: only their header is recorded
    topics: dict[str, int] = field(default_factory=dict)


def image_encoder(frames_format: str) -> Callable[[dict[str, Any], Any], bytes]:
    """A bus frame (header, pixels) → the CDR image of ``frames_format``; jpeg and png need OpenCV
    (the laptop or robot extra), refused before anything is written when it is missing."""
    if frames_format == "raw":
        return fmt.raw_image
    try:
        import cv2
        import numpy as np
    except ImportError as exc:
        raise missing_extra(f"--frames-format {frames_format}", "laptop", "OpenCV", exc) from None
    ext = ".jpg" if frames_format == "jpeg" else ".png"

    def encode(header: dict[str, Any], pixels: Any) -> bytes:
        fmt.raw_image_encoding(header)  # a layout RawImage cannot show is no picture either
        image = np.frombuffer(pixels, dtype=str(header["dtype"])).reshape(header["shape"])
        ok, data = cv2.imencode(ext, image)
        if not ok:
            raise fmt.UnsupportedFrame(f"OpenCV could not encode a {header.get('pixel_format')} frame "
                                       f"as {ext}")
        return fmt.compressed_image(header, data.tobytes(), frames_format)
    return encode


class Recorder:
    """With ``limits``, a message that would take the file past ``--max-size`` or the disk under
    ``--min-free`` is not written: ``ended`` says which, and the caller finishes the file."""

    def __init__(self, stream: IO[bytes], metadata: dict[str, str], compression: str = "zstd",
                 limits: Limits | None = None, frames_format: str = "raw") -> None:
        try:
            from mcap.writer import CompressionType, Writer
        except ImportError as exc:
            raise CtlError(Exit.BAD_INPUT, "missing_package",
                           f"recording needs the mcap package ({exc.name} is not installed): "
                           f"pip install --upgrade rita") from None
        self.encode_image = image_encoder(frames_format)
        self.frames_format = frames_format
        kind = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4,
                "none": CompressionType.NONE}[compression]
        self.stream = stream
        self.writer = Writer(stream, compression=kind)
        self.writer.start(profile=fmt.PROFILE, library=f"ritactl {__version__}")
        self.writer.add_metadata(fmt.METADATA_NAME, {**metadata, "frames_format": frames_format})
        self.channels: dict[str, int] = {}
        self.schemas: dict[str, dict[str, Any]] = {}  # bus topic → its inferred schema
        self.sequences: dict[int, int] = {}  # channel → the last MCAP sequence written on it
        self.counts = Counts()
        self.limits = limits
        self.ended: str | None = None  # "max_size" / "min_free": a limit stopped the writing
        self.odometry = False  # the base streams its samples: the pose comes from them, not the STATUS
        self._seq: int | None = None
        self._frame_seq: int | None = None  # the last frame seen
        self.kept_seq: int | None = None  # the last frame written (--frames every N counts from it)
        self.finishing = False  # finish() was called: a second try after its failure would write garbage

    def _register(self, channel: str, name: str, encoding: str, data: bytes, message_encoding: str) -> int:
        schema = self.writer.register_schema(name, encoding, data)
        ch = self.channels[channel] = self.writer.register_channel(channel, message_encoding, schema)
        return ch

    def _bus_channel(self, topic: str, sample: Any) -> int:
        """The channel of a bus topic, its JSON schema inferred from its first message."""
        ch = self.channels.get(fmt.mcap_topic(topic))
        if ch is None:
            inferred = self.schemas[topic] = fmt.infer_schema(topic, sample)
            ch = self._register(fmt.mcap_topic(topic), topic, "jsonschema", fmt.to_json(inferred), "json")
        return ch

    def _fox_channel(self, channel: str, name: str) -> int:
        """A channel of Foxglove's well-known ``foxglove.<name>`` in JSON, with Foxglove's
        published schema."""
        ch = self.channels.get(channel)
        return ch if ch is not None else self._register(channel, f"foxglove.{name}", "jsonschema",
                                                        schema_bytes(name), "json")

    def _image_channel(self) -> int:
        ch = self.channels.get(fmt.FRAME_CHANNEL)
        if ch is not None:
            return ch
        if self.frames_format == "raw":
            return self._register(fmt.FRAME_CHANNEL, fmt.RAW_IMAGE_SCHEMA, "ros2msg",
                                  fmt.RAW_IMAGE_ROS2MSG.encode(), "cdr")
        return self._register(fmt.FRAME_CHANNEL, fmt.COMPRESSED_IMAGE_SCHEMA, "ros2msg",
                              fmt.COMPRESSED_IMAGE_ROS2MSG.encode(), "cdr")

    def _json(self, topic: str, data: Any) -> bytes:
        """``data`` as JSON that its channel's schema accepts: a null where the schema has a type is
        left out (a replay puts it back), since a strict reader refuses a null "string"."""
        body = fmt.to_json(data)
        if b"null" in body:  # rare: the walk only for messages that may hold one
            body = fmt.to_json(fmt.drop_typed_nulls(data, self.schemas[topic]))
        return body

    def allowed(self, incoming: int) -> bool:
        """False once the limits end the recording (``ended`` says why)."""
        if self.ended is None and self.limits is not None:
            self.ended = self.limits.reason(self.stream.tell(), incoming)
        return self.ended is None

    def telemetry(self, topic: str, msg: dict[str, Any], recv_ns: int) -> None:
        seq = int(msg.get("seq") or 0)
        data = msg.get("data")
        t = fmt.sample_time(topic, data, int(msg.get("t_ns") or recv_ns))
        if topic == "log" and isinstance(data, dict):  # the journal: Foxglove's Log holds all of it
            body = fmt.to_json(fox.log_entry(data, t))
            if self.allowed(len(body)):
                self._note_seq(seq)
                self._write(fox.LOG_TOPIC, self._fox_channel(fox.LOG_TOPIC, fox.LOG_SCHEMA), body, t, recv_ns)
            return
        ch = self._bus_channel(topic, data)
        body = self._json(topic, data)
        if not self.allowed(2 * len(body)):  # its Foxglove twin is about as large
            return
        self._note_seq(seq)
        self._write(fmt.mcap_topic(topic), ch, body, t, recv_ns)
        if isinstance(data, dict):
            self._foxglove(topic, data, t, recv_ns)

    def _note_seq(self, seq: int) -> None:
        if self._seq is not None and seq > self._seq + 1:
            self.counts.missed += seq - self._seq - 1
        self._seq = seq

    def _foxglove(self, topic: str, data: dict[str, Any], t: int, recv_ns: int) -> None:
        """The Foxglove messages a bus message adds: the robot's pose, each tracker record's pose."""
        poses: list[tuple[int, bytes]] = []
        channel = fox.ROBOT_POSE_TOPIC
        if topic == "robot.state" and not self.odometry:
            pose = fox.robot_pose(data, t)
            poses = [(t, pose)] if pose is not None else []
        elif topic == "robot.odometry" and (times := fmt.sample_times(topic, data)):
            self.odometry = True
            rows = zip(times, data.get("x_mm") or [], data.get("y_mm") or [], data.get("heading_deg") or [])
            made = ((s, fox.robot_pose({"x_mm": x, "y_mm": y, "heading_deg": h}, s)) for s, x, y, h in rows)
            poses = [(s, p) for s, p in made if p is not None]
        elif topic == "tracker.point" and (times := fmt.sample_times(topic, data)):
            poses = list(fox.tracker_poses(data, times))
            channel = fox.TRACKER_POSE_TOPIC
        if poses:
            ch = self._fox_channel(channel, fox.POSE_SCHEMA)
            for s, pose in poses:
                self._write(channel, ch, pose, s, recv_ns)

    def frame(self, header: dict[str, Any], pixels: bytes | memoryview, recv_ns: int) -> None:
        hch = self._bus_channel(fmt.FRAME_HEADER_TOPIC, header)
        head = self._json(fmt.FRAME_HEADER_TOPIC, header)
        if not self.allowed(len(head) + len(pixels) + IMAGE_OVERHEAD):
            return
        self.note_frame_seen(int(header.get("seq") or 0))
        self.kept_seq = self._frame_seq
        t = fmt.sample_time(fmt.FRAME_TOPIC, header, recv_ns)  # the exposure's mid-time
        self._write(fmt.FRAME_HEADER_CHANNEL, hch, head, t, recv_ns)
        try:
            image = self.encode_image(header, pixels)
        except fmt.UnsupportedFrame:
            self.counts.unsupported += 1
            return
        self._write(fmt.FRAME_CHANNEL, self._image_channel(), image, t, recv_ns)
        self.counts.frames += 1

    def note_frame_seen(self, seq: int) -> None:
        """A frame --frames skips: keeps the frame gap count honest."""
        if self._frame_seq is not None and seq > self._frame_seq + 1:
            self.counts.frames_missed += seq - self._frame_seq - 1
        self._frame_seq = seq

    def _write(self, channel: str, ch: int, data: bytes, log_ns: int, recv_ns: int) -> None:
        # the MCAP sequence counts this channel's messages (1, 2, ...): a reader's gap check per
        # channel finds none; the bus seq, one counter across topics, gave every channel false gaps
        seq = self.sequences[ch] = self.sequences.get(ch, 0) + 1
        self.writer.add_message(ch, log_time=max(0, log_ns), data=data, publish_time=recv_ns,
                                sequence=seq % fmt.SEQ_MOD)
        self.counts.messages += 1
        topics = self.counts.topics
        topics[channel] = topics.get(channel, 0) + 1

    def finish(self, ended: str = "", error: str = "") -> None:
        """The end record (how it ended, what was lost), then the summary; call once."""
        self.finishing = True
        if ended:
            c = self.counts
            self.writer.add_metadata(fmt.END_METADATA_NAME, {
                "ended": ended, "error": error, "messages": str(c.messages), "frames": str(c.frames),
                "frames_dropped": str(c.frames_missed), "telemetry_missed": str(c.missed),
                "frames_unsupported": str(c.unsupported)})
        self.writer.finish()  # type: ignore[no-untyped-call]  # mcap 1.6 leaves finish() unannotated
