"""Several sensors, one clock: stream two (or more) fingers as time-paired frames.

::

    import thintact_sdk as thintact
    with thintact.open_group(["virtual-finger", "virtual-finger"], names=["left", "right"]) as g:
        for pair in g.stream(max_frames=100):
            left, right = pair.frames["left"], pair.frames["right"]
            print(pair.skew_ms, pair.missing)          # {} while every finger delivers
        print(g.status())                              # per member: state, drops, stalls

Every member runs its own capture thread (``Sensor.read_raw`` then ``Sensor.process``) and
keeps its not-yet-delivered frames in a short buffer. Frames are paired on the host's
monotonic clock (``timestamp_ns``, taken when the frame arrived), the one clock all
cameras share; device timestamps of different cameras are not comparable.

Guarantees (docs/robot-api.md, "Several sensors"):

* every :class:`GroupFrame` holds, for each member that is running, the frame closest in
  time to the newest frame of the slowest member, and its ``skew_ns`` (newest minus
  oldest timestamp of the pair) is at most ``max_skew_ms``: frames that cannot be paired
  within it are dropped and counted (``unpaired``), never delivered;
* a member with no frame for ``stall_after_s`` (or for :data:`STALL_FRAME_PERIODS` of its own
  recent frame intervals, when that is longer: a slow member is not a stalled one) is
  *stalled*: the group delivers the other
  members' frames with that member ``None`` and named in ``GroupFrame.missing``, and takes
  it back as soon as it delivers again;
* a member whose camera is lost (unplugged) or whose source ended is reported in
  ``missing`` and :meth:`SensorGroup.status` with the error, and the others keep running;
  :meth:`SensorGroup.stream` raises only when no member is left.

Before pairing starts, :meth:`SensorGroup.open` warms every member up
(:meth:`Sensor.warm_up`: decoder built with its backends measured, LUT loaded, one frame
decoded; one member after the other, so no member's measurement runs against another's), so
the first pairs are complete instead of one member stalled behind its first decode. Skew
statistics (:meth:`SensorGroup.skew_summary`) count complete pairs only and say how many
were incomplete.

A hardware or software trigger is used where the cameras have one (``trigger=``): the
camera plugin then offers ``set_trigger(source)`` and ``fire_trigger()`` (the GenICam
plugin does, through ``TriggerMode``/``TriggerSource``/``TriggerSoftware``).
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal, Protocol, runtime_checkable

import numpy as np

from thintact_sdk.device.sensor import Sensor
from thintact_sdk.errors import (
    DeviceError,
    DeviceLostError,
    DeviceTimeoutError,
    EndOfStreamError,
    ThinTactError,
    UnsupportedFeatureError,
)
from thintact_sdk.formats.profiles import Profile, load_profile
from thintact_sdk.frames import RawFrame, TactileFrame

MemberState = Literal["starting", "running", "stalled", "lost", "ended", "failed", "closed"]
TriggerMode = Literal["none", "software", "hardware"]
BUFFER_FRAMES = 8
"""Frames kept per member while waiting for a partner (older ones are dropped, counted)."""
STALL_FRAME_PERIODS = 4.0
"""A running member is stalled after this many of its median recent frame intervals without a
frame, when that is longer than ``stall_after_s``."""
PACE_FRAMES = 8
"""Frame intervals per member its pace (median interval) is taken over."""


@runtime_checkable
class TriggerableCamera(Protocol):
    """A camera that can wait for a trigger (e.g. GenICam ``TriggerMode``)."""

    def set_trigger(self, source: str | None) -> None:
        """Wait for a trigger from ``source`` (``"Software"``, ``"Line0"``, ...) before each
        frame; ``None`` returns to free running. Raises UnsupportedFeatureError."""

    def fire_trigger(self) -> None:
        """Issue one software trigger."""


@runtime_checkable
class WarmableCamera(Protocol):
    """A camera whose first frames cost more than the later ones (e.g. the virtual camera
    rendering its scenes) and that can pay for them ahead."""

    def warm_up(self) -> float:
        """Prepare the next frames; returns the seconds spent."""


@dataclass
class MemberStatus:
    """Accounting and health of one member of a group.

    Attributes
    ----------
    name
        The member's name in the group.
    state
        ``starting`` (no frame yet), ``running``, ``stalled`` (no frame for ``stall_after_s``), ``lost`` (camera gone),
        ``ended`` (finite source finished), ``failed`` (any other error) or ``closed``.
    captured
        Frames the member delivered to the group.
    delivered
        Frames handed to the consumer inside a :class:`GroupFrame`.
    unpaired
        Frames dropped because no partner lay within ``max_skew_ms`` or a newer pair
        superseded them (a slow consumer).
    camera_dropped
        Frames the camera lost (gaps in its frame ids).
    stalls
        How many times the member went from running to stalled.
    last_frame_age_s
        Seconds since its last frame (inf before the first).
    error
        The error that ended or stalled it, as text ("" when none).
    """

    name: str
    state: MemberState
    captured: int = 0
    delivered: int = 0
    unpaired: int = 0
    camera_dropped: int = 0
    stalls: int = 0
    last_frame_age_s: float = float("inf")
    error: str = ""


@dataclass
class GroupFrame:
    """One time-paired set of frames.

    Attributes
    ----------
    frames
        Member name → its frame (:class:`TactileFrame`, or :class:`RawFrame` when the group
        was opened with ``process=False``); ``None`` for a member that is stalled, lost or
        ended (see ``missing``).
    timestamp_ns
        Host monotonic time of the pair's anchor: the newest frame of the slowest member.
    skew_ns
        Newest minus oldest timestamp among the frames present (0 with one frame: an
        incomplete pair has no skew; :meth:`SensorGroup.skew_summary` leaves it out).
    missing
        Member name → state for every member without a frame in this pair.
    index
        0, 1, 2, ... in delivery order.
    """

    frames: dict[str, TactileFrame | RawFrame | None]
    timestamp_ns: int
    skew_ns: int
    missing: dict[str, MemberState] = field(default_factory=dict)
    index: int = 0

    @property
    def skew_ms(self) -> float:
        """``skew_ns`` in milliseconds."""
        return self.skew_ns / 1e6

    @property
    def complete(self) -> bool:
        """True when every member contributed a frame."""
        return not self.missing


class _Member:
    """One sensor of the group, its capture thread and its pending frames."""

    def __init__(self, name: str, sensor: Sensor, process: bool) -> None:
        self.name = name
        self.sensor = sensor
        self.process = process
        self.owned = False  # the group opened it, so the group closes it
        self.pending: deque[TactileFrame | RawFrame] = deque()
        self.status = MemberStatus(name, "starting")
        self.last_frame_s = float("-inf")
        self.intervals_s: deque[float] = deque(maxlen=PACE_FRAMES)
        self.thread: threading.Thread | None = None

    def read_one(self) -> TactileFrame | RawFrame:
        raw = self.sensor.read_raw()
        if not self.process:
            return raw
        return self.sensor.process(raw)


class SensorGroup:
    """Several sensors streamed together, their frames paired by time.

    Parameters
    ----------
    sensors
        Profile names, profile files, :class:`Profile` objects or :class:`Sensor` objects
        (opened or not; the group opens what is closed and closes only what it opened).
    names
        One name per member (default: the profile names, ``#2``, ``#3`` appended to
        repeats).
    max_skew_ms
        Largest spread of timestamps inside a delivered :class:`GroupFrame` (ms). For
        free-running cameras at f frames/s a partner lies within ``1/(2 f)`` plus jitter,
        so the default of 20 ms suits cameras at 30 fps and faster.
    stall_after_s
        A member with no frame for this long, and for :data:`STALL_FRAME_PERIODS` of its median
        recent frame interval (the first one counted from the start of capture), is reported
        stalled and left out of pairs until it delivers again.
    startup_s
        The first pair waits this long for every member's first frame after the warm-up; a
        member still silent then is stalled.
    warm_up
        True (default): :meth:`open` warms every member up before capture starts, one member
        after the other, outside ``startup_s`` and the read timeout: its camera when that
        offers ``warm_up()`` (:class:`WarmableCamera`: the virtual camera renders its scenes
        ahead) and, with ``process=True``, :meth:`Sensor.warm_up` (skipped for a sensor whose
        decoder was warmed up already). False: the members' first frames pay for it (and
        may be stalled by ``startup_s`` or come too far apart to be paired).
    process
        True: members deliver :class:`TactileFrame` (decode and interpret in each member's
        thread); False: :class:`RawFrame` as the camera gives it (recording, raw sync).
    trigger
        ``"none"`` (free running), ``"software"`` (the group fires every camera's software
        trigger at ``trigger_fps``) or ``"hardware"`` (cameras wait for ``trigger_source``,
        an input line wired to a common pulse). Members whose camera has no trigger make
        :meth:`open` raise UnsupportedFeatureError naming them.
    trigger_fps
        Rate of the software trigger (Hz).
    trigger_source
        Hardware trigger input (GenICam ``TriggerSource``, e.g. ``"Line0"``).
    sensor_options
        Keyword arguments for each :class:`Sensor` the group builds from a profile.
    """

    def __init__(
        self,
        sensors: Sequence[str | Profile | Sensor],
        names: Sequence[str] | None = None,
        max_skew_ms: float = 20.0,
        stall_after_s: float = 0.5,
        startup_s: float = 10.0,
        process: bool = True,
        warm_up: bool = True,
        trigger: TriggerMode = "none",
        trigger_fps: float = 30.0,
        trigger_source: str = "Line0",
        sensor_options: dict[str, Any] | None = None,
    ) -> None:
        if not sensors:
            raise ThinTactError("open_group needs at least one sensor")
        if names is not None and len(names) != len(sensors):
            raise ThinTactError(f"open_group: {len(names)} names for {len(sensors)} sensors")
        if names is not None and len(set(names)) != len(names):
            raise ThinTactError(f"open_group: member names must differ, got {list(names)}")
        if max_skew_ms <= 0 or stall_after_s <= 0:
            raise ThinTactError("open_group: max_skew_ms and stall_after_s must be positive")
        if trigger not in ("none", "software", "hardware"):
            raise ThinTactError(f"open_group: trigger must be none, software or hardware, got {trigger!r}")
        if trigger == "software" and trigger_fps <= 0:
            raise ThinTactError("open_group: trigger_fps must be positive")
        self.max_skew_ns = int(round(max_skew_ms * 1e6))
        self.stall_after_s = float(stall_after_s)
        self.startup_s = float(startup_s)
        self.warm_up = bool(warm_up)
        self.warm_up_s: dict[str, float] = {}
        """Seconds each member's warm-up took at :meth:`open` (0 where it was warm already)."""
        self._opened_s = 0.0
        self.trigger: TriggerMode = trigger
        self.trigger_fps = float(trigger_fps)
        self.trigger_source = trigger_source
        self.members: list[_Member] = []
        taken: dict[str, int] = {}
        for i, item in enumerate(sensors):
            sensor = item if isinstance(item, Sensor) else Sensor(
                load_profile(item), **(sensor_options or {}))
            if names is not None:
                name = names[i]
            else:
                base = sensor.profile.name
                taken[base] = taken.get(base, 0) + 1
                name = base if taken[base] == 1 else f"{base}#{taken[base]}"
            self.members.append(_Member(name, sensor, process))
        self._cond = threading.Condition()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._delivered = 0
        self._skews_ns: list[int] = []
        self._incomplete = 0

    # -- life cycle ------------------------------------------------------------------
    @property
    def names(self) -> list[str]:
        """Member names in order."""
        return [m.name for m in self.members]

    def sensor(self, name: str) -> Sensor:
        """The :class:`Sensor` of member ``name``."""
        for m in self.members:
            if m.name == name:
                return m.sensor
        raise ThinTactError(f"no member {name!r} in this group; members: {', '.join(self.names)}")

    def open(self) -> SensorGroup:
        """Open every member, warm it up (``warm_up``), and start capture; when one fails,
        close those it opened and raise that member's error, naming it."""
        if self._threads:
            return self
        opened: list[_Member] = []
        try:
            for m in self.members:
                if not m.sensor.is_open:
                    m.sensor.open()
                    opened.append(m)
            self._warm_up_members()
            self._configure_triggers()
        except BaseException:
            for m in opened:
                m.sensor.close()
            raise
        for m in opened:
            m.owned = True
        self._stop.clear()
        self._opened_s = time.monotonic()
        for m in self.members:
            m.status = MemberStatus(m.name, "starting")
            m.last_frame_s = self._opened_s  # so each startup ends at _opened_s + startup_s
            m.intervals_s.clear()
            m.thread = threading.Thread(target=self._capture_loop, args=(m,),
                                        name=f"group-{m.name}", daemon=True)
            self._threads.append(m.thread)
        if self.trigger == "software":
            self._threads.append(threading.Thread(target=self._trigger_loop,
                                                  name="group-trigger", daemon=True))
        for t in self._threads:
            t.start()
        return self

    def _warm_up_members(self) -> None:
        """Warm every member up in turn: its camera (:class:`WarmableCamera`), and, for
        tactile frames, its decoder and LUT (a sensor timed already is skipped)."""
        if not self.warm_up:
            return
        for m in self.members:
            took = 0.0
            try:
                if isinstance(m.sensor.camera, WarmableCamera):
                    took += float(m.sensor.camera.warm_up())
                if m.process and m.sensor.decode_ms is None:
                    took += m.sensor.warm_up()
                self.warm_up_s[m.name] = took
            except ThinTactError as err:
                raise type(err)(f"group member {m.name!r}: warm-up failed: {err}") from err

    def _trigger_cameras(self) -> list[TriggerableCamera]:
        cams: list[TriggerableCamera] = []
        for m in self.members:
            cam = m.sensor.camera
            if not isinstance(cam, TriggerableCamera):
                plugin = m.sensor.profile.camera.plugin if m.sensor.profile.camera else "?"
                raise UnsupportedFeatureError(
                    f"group member {m.name!r}: camera plugin {plugin!r} has no trigger; open "
                    "the group with trigger='none' (frames are then paired by time only)"
                )
            cams.append(cam)
        return cams

    def _configure_triggers(self) -> None:
        if self.trigger == "none":
            return
        source = "Software" if self.trigger == "software" else self.trigger_source
        for m, cam in zip(self.members, self._trigger_cameras(), strict=True):
            try:
                cam.set_trigger(source)
            except UnsupportedFeatureError as err:
                raise UnsupportedFeatureError(f"group member {m.name!r}: {err}") from None

    def close(self) -> None:
        """Stop capture, return triggered cameras to free running, close what the group
        opened. Safe to call twice."""
        self._stop.set()
        with self._cond:
            self._cond.notify_all()
        for t in self._threads:
            t.join(timeout=5.0)
        self._threads = []
        for m in self.members:
            cam = m.sensor.camera
            if self.trigger != "none" and isinstance(cam, TriggerableCamera):
                try:
                    cam.set_trigger(None)
                except ThinTactError:
                    pass  # a lost camera cannot be reset; it is closed below
            if m.owned:
                m.sensor.close()
            if m.status.state in ("running", "stalled", "starting"):
                m.status.state = "closed"

    def __enter__(self) -> SensorGroup:
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- capture threads ---------------------------------------------------------------
    def _capture_loop(self, m: _Member) -> None:
        while not self._stop.is_set():
            try:
                frame = m.read_one()
            except DeviceTimeoutError as err:
                with self._cond:
                    m.status.error = str(err)
                    self._cond.notify_all()
                continue  # a stall: keep asking, the member rejoins when frames come
            except EndOfStreamError as err:
                self._finish(m, "ended", err)
                return
            except DeviceLostError as err:
                self._finish(m, "lost", err)
                return
            except Exception as err:  # noqa: BLE001 - any member fault is reported, not raised
                self._finish(m, "failed", err)
                return
            with self._cond:
                m.pending.append(frame)
                if len(m.pending) > BUFFER_FRAMES:
                    m.pending.popleft()
                    m.status.unpaired += 1
                m.status.captured += 1
                m.status.camera_dropped = m.sensor.gaps.dropped
                now_s = time.monotonic()
                m.intervals_s.append(now_s - m.last_frame_s)
                m.last_frame_s = now_s
                if m.status.state in ("stalled", "starting"):
                    m.status.state = "running"
                    m.status.error = ""
                self._cond.notify_all()

    def _finish(self, m: _Member, state: MemberState, err: BaseException) -> None:
        with self._cond:
            m.status.state = state
            m.status.error = f"{type(err).__name__}: {err}"
            m.status.unpaired += len(m.pending)
            m.pending.clear()
            self._cond.notify_all()

    def _trigger_loop(self) -> None:
        cams = self._trigger_cameras()
        period = 1.0 / self.trigger_fps
        due = time.monotonic()
        while not self._stop.is_set():
            for m, cam in zip(self.members, cams, strict=True):
                if m.status.state in ("starting", "running", "stalled"):
                    try:
                        cam.fire_trigger()
                    except ThinTactError as err:
                        with self._cond:
                            m.status.error = f"trigger: {err}"
            due += period
            self._stop.wait(max(0.0, due - time.monotonic()))

    # -- pairing -----------------------------------------------------------------------
    def _update_stalls(self, now_s: float) -> None:
        for m in self.members:
            limit = self.startup_s if m.status.state == "starting" else self.stall_after_s
            if m.status.state == "running" and m.intervals_s:
                limit = max(limit, STALL_FRAME_PERIODS * float(np.median(m.intervals_s)))
            if m.status.state in ("running", "starting") and now_s - m.last_frame_s >= limit:
                m.status.state = "stalled"
                m.status.stalls += 1
                if not m.status.error:
                    m.status.error = f"no frame for {limit:.2f} s"

    def _try_pair(self) -> GroupFrame | None:
        """Pair the pending frames (call with the lock held); None when not yet possible."""
        if any(m.status.state == "starting" for m in self.members):
            return None  # the first pair waits for every member (up to startup_s)
        active = [m for m in self.members if m.status.state == "running"]
        if not active or any(not m.pending for m in active):
            return None
        anchor = min(m.pending[-1].timestamp_ns for m in active)
        chosen: dict[str, int] = {}
        for m in active:
            stamps = np.array([f.timestamp_ns for f in m.pending], np.int64)
            chosen[m.name] = int(np.argmin(np.abs(stamps - anchor)))
        picked = {m.name: m.pending[chosen[m.name]] for m in active}
        stamps_ns = [f.timestamp_ns for f in picked.values()]
        if max(stamps_ns) - min(stamps_ns) > self.max_skew_ns:
            # some member's nearest frame is later than anchor + max skew: the slowest
            # member's frames (all at or before the anchor) can never be paired, since
            # partners only get newer; drop them and wait for its next frame
            slowest = next(m for m in active if m.pending[-1].timestamp_ns == anchor)
            slowest.status.unpaired += len(slowest.pending)
            slowest.pending.clear()
            return None
        for m in active:
            k = chosen[m.name]
            m.status.unpaired += k
            for _ in range(k + 1):
                m.pending.popleft()
            m.status.delivered += 1
        skew = max(stamps_ns) - min(stamps_ns)
        frames: dict[str, TactileFrame | RawFrame | None] = {m.name: None for m in self.members}
        frames.update(picked)
        missing = {m.name: m.status.state for m in self.members if m.name not in picked}
        out = GroupFrame(frames, int(anchor), int(skew), missing, self._delivered)
        self._delivered += 1
        if missing:
            self._incomplete += 1
        else:
            self._skews_ns.append(int(skew))
        return out

    def _no_member_left(self) -> BaseException | None:
        states = [m.status.state for m in self.members]
        if any(s in ("running", "stalled", "starting") for s in states):
            return None
        detail = "; ".join(f"{m.name}: {m.status.state} ({m.status.error})" for m in self.members)
        if all(s == "ended" for s in states):
            return EndOfStreamError(f"every member of the group ended: {detail}")
        return DeviceLostError(f"no member of the group is left: {detail}")

    def read(self, timeout_s: float = 2.0) -> GroupFrame:
        """The next paired frame, waiting at most ``timeout_s``.

        Raises
        ------
        DeviceTimeoutError
            No pair within ``timeout_s`` (every running member stalled).
        DeviceLostError, EndOfStreamError
            Every member is lost / ended (the message names each and why).
        """
        if not self._threads:
            raise DeviceError("the group is not open; call open() or use it in a with block")
        deadline = max(time.monotonic() + timeout_s, self._opened_s + self.startup_s)
        with self._cond:
            while True:
                # one clock reading per pass: at the deadline, a member silent since the
                # open is already stalled when the pairing is tried
                now = time.monotonic()
                self._update_stalls(now)
                pair = self._try_pair()
                if pair is not None:
                    return pair
                gone = self._no_member_left()
                if gone is not None:
                    raise gone
                left = deadline - now
                if left <= 0:
                    states = ", ".join(f"{m.name} {m.status.state}" for m in self.members)
                    raise DeviceTimeoutError(
                        f"no paired frame within {timeout_s:.1f} s ({states})")
                self._cond.wait(min(left, 0.02))

    def stream(self, max_frames: int | None = None, timeout_s: float = 2.0) -> Iterator[GroupFrame]:
        """Paired frames as they come (newest pairs first: a slow consumer gets no backlog).

        Parameters
        ----------
        max_frames
            Stop after this many pairs (default: until the generator is closed).
        timeout_s
            Longest wait for one pair (see :meth:`read`).
        """
        n = 0
        while max_frames is None or n < max_frames:
            yield self.read(timeout_s)
            n += 1

    # -- reporting ---------------------------------------------------------------------
    def status(self) -> dict[str, MemberStatus]:
        """A snapshot of every member's state and frame accounting."""
        now = time.monotonic()
        with self._cond:
            self._update_stalls(now)
            out = {}
            for m in self.members:
                s = MemberStatus(**vars(m.status))
                s.last_frame_age_s = now - m.last_frame_s if self._threads else float("inf")
                out[m.name] = s
            return out

    def skew_summary(self) -> dict[str, float]:
        """Skew of the complete pairs delivered so far (every member present): ``pairs``
        (complete pairs), ``incomplete`` (pairs delivered with a member missing, left out of
        the statistics: their skew says nothing about the clocks), ``median_ms``, ``p95_ms``,
        ``max_ms`` (NaN without a complete pair)."""
        with self._cond:
            skews = np.array(self._skews_ns, np.float64) / 1e6
            incomplete = self._incomplete
        if len(skews) == 0:
            return {"pairs": 0, "incomplete": incomplete, "median_ms": float("nan"),
                    "p95_ms": float("nan"), "max_ms": float("nan")}
        return {"pairs": int(len(skews)), "incomplete": incomplete,
                "median_ms": float(np.median(skews)),
                "p95_ms": float(np.percentile(skews, 95)), "max_ms": float(skews.max())}


def open_group(sensors: Sequence[str | Profile | Sensor], **options: Any) -> SensorGroup:
    """Open several sensors as one :class:`SensorGroup` (use it as a context manager).

    ``options`` are those of :class:`SensorGroup` (``names``, ``max_skew_ms``,
    ``stall_after_s``, ``startup_s``, ``process``, ``warm_up``, ``trigger``, ``trigger_fps``, ``trigger_source``,
    ``sensor_options``).
    """
    return SensorGroup(sensors, **options).open()
