"""The shared vocabulary of acq: what a driver hands to the rest of the system.

Frozen dataclasses around numpy arrays. Times are integer nanoseconds on the host's
monotonic clock (``time.monotonic_ns()`` at receipt) unless a field says otherwise;
device clocks are kept as the raw ticks the device sent, so a log can be re-timed.
This module imports nothing of acq's own.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np
import numpy.typing as npt

__all__ = [
    "CanFrame",
    "CovarianceType",
    "DeviceInfo",
    "Fix",
    "Frame",
    "Odometry",
    "Scan",
    "Sentence",
]


def _frozen_array(values: npt.ArrayLike, dtype: npt.DTypeLike, name: str) -> np.ndarray:
    """A read-only 1-D copy-free view of ``values`` as ``dtype``."""
    arr = np.asarray(values, dtype=dtype)
    if arr.ndim != 1:
        raise ValueError(f"{name} must be 1-D, got shape {arr.shape}")
    if arr.flags.writeable:
        arr = arr.view()
        arr.flags.writeable = False
    return arr


@dataclass(frozen=True, slots=True)
class DeviceInfo:
    """What a device says about itself (SCIP VV/PP/II, CoLa identity, V4L2 caps)."""

    name: str
    driver: str
    vendor: str = ""
    model: str = ""
    serial: str = ""
    firmware: str = ""
    extra: dict[str, str] = field(default_factory=dict)


@dataclass(frozen=True, slots=True)
class Scan:
    """One profile of a 2D laser scanner, in the REP-103 laser frame.

    Point ``i`` lies at angle ``angle_min + i * angle_increment`` (rad, counter-clockwise
    about z, 0 along x) and was measured at ``start_ns + i * time_increment`` seconds
    after the scan's first point. Ranges are metres, REP-117: ``+inf`` no return,
    ``-inf`` too close, ``nan`` a device error code (the raw code stays in ``raw``).
    """

    ranges: np.ndarray  # (N,) float32, metres
    intensities: np.ndarray  # (N,) float32, device units; empty when the device sends none
    angle_min: float  # rad, angle of point 0
    angle_increment: float  # rad
    time_increment: float  # s between consecutive points
    scan_period: float  # s between consecutive scans
    recv_ns: int  # host monotonic ns at receipt of the telegram
    start_ns: int | None = None  # host monotonic ns of point 0, once a clock is applied
    device_ticks: tuple[int, ...] = ()  # raw device clock values (Hokuyo: ms; SICK: µs)
    sequence: int = 0  # device scan counter where it has one, else the driver's
    raw: bytes = b""  # the telegram as received
    # Multi-echo devices: further echoes per point, (N, E) metres (+inf none) and their
    # intensities; ``ranges``/``intensities`` hold the first echo.
    extra_echoes: np.ndarray | None = None
    extra_intensities: np.ndarray | None = None

    def __post_init__(self) -> None:
        ranges = _frozen_array(self.ranges, np.float32, "ranges")
        object.__setattr__(self, "ranges", ranges)
        intens = _frozen_array(self.intensities, np.float32, "intensities")
        if intens.size not in (0, ranges.size):
            raise ValueError(f"intensities has {intens.size} values for {ranges.size} ranges")
        object.__setattr__(self, "intensities", intens)
        if self.time_increment < 0 or self.scan_period < 0:
            raise ValueError("time_increment and scan_period must be >= 0")

    @property
    def size(self) -> int:
        return int(self.ranges.size)

    def angles(self) -> np.ndarray:
        """(N,) float64 angle of every point, rad."""
        return self.angle_min + self.angle_increment * np.arange(self.size, dtype=np.float64)

    def points(self) -> np.ndarray:
        """(N,3) float64 laser-frame points (z = 0); non-finite ranges give non-finite rows."""
        a = self.angles()
        r = self.ranges.astype(np.float64)
        with np.errstate(invalid="ignore"):  # inf * sin(0) is nan: fine for no-echo rows
            return np.stack([r * np.cos(a), r * np.sin(a), np.zeros_like(r)], axis=1)


@dataclass(frozen=True, slots=True)
class Frame:
    """One camera image: JPEG bytes as the camera sent them, or decoded pixels.

    ``stamp_ns`` is the middle of the exposure on the host clock; ``exposure_s`` its
    length (0 where unknown).
    """

    recv_ns: int  # host monotonic ns at receipt
    stamp_ns: int  # host monotonic ns of the middle of exposure
    sequence: int  # the source's frame counter, gaps are drops
    width: int
    height: int
    jpeg: bytes = b""  # the compressed image as sent, when the source sends JPEG
    image: np.ndarray | None = None  # (H,W,3) uint8 BGR, when decoded or raw
    exposure_s: float = 0.0
    time_source: str = "receipt"  # receipt | kernel | device

    def __post_init__(self) -> None:
        if not self.jpeg and self.image is None:
            raise ValueError("a Frame needs jpeg bytes or an image")
        if self.image is not None and self.image.shape[:2] != (self.height, self.width):
            raise ValueError(
                f"image shape {self.image.shape[:2]} does not match {self.height}x{self.width}"
            )


@dataclass(frozen=True, slots=True)
class CanFrame:
    """One CAN frame as the bus delivered it (any id, decoded or not).

    ``wall_ns`` is the interface's receive stamp as sent (socketcan: the kernel's
    ``CLOCK_REALTIME`` stamp, ns since the Unix epoch; 0 where the interface gives none);
    ``stamp_ns`` is that instant on the host monotonic clock (see
    :mod:`acq.drivers.can_odometry`), ``recv_ns`` when the stamp could not be used.
    """

    recv_ns: int  # host monotonic ns when the driver got the frame
    stamp_ns: int  # host monotonic ns of the interface's receive stamp
    wall_ns: int  # the interface's stamp, CLOCK_REALTIME ns (0: none)
    arbitration_id: int
    data: bytes
    is_extended: bool = False  # 29-bit identifier
    is_remote: bool = False
    is_error: bool = False  # an error frame (bus error report), not data
    is_fd: bool = False
    channel: str = ""


@dataclass(frozen=True, slots=True)
class Odometry:
    """Vehicle motion from one CAN message: speed (m/s) and yaw rate (rad/s, positive
    counter-clockwise seen from above, REP-103), at ``stamp_ns`` (host monotonic ns).

    Wheel speeds and yaw rate usually come in different CAN messages, measured at
    different instants: a record holds what its message carried and NaN for the rest
    (never a value held over from an older message). ``speed`` is the mean of the finite
    ``wheel_speeds`` (m/s, front left, front right, rear left, rear right), or the
    vehicle speed signal where one is configured. A value the DBC marks out of range
    (an ECU's "invalid" code) is NaN too.
    """

    recv_ns: int
    stamp_ns: int
    speed: float
    yaw_rate: float
    wheel_speeds: tuple[float, ...] = ()
    arbitration_id: int = 0  # the CAN message it was decoded from


class CovarianceType(IntEnum):
    """How a fix's position sigmas were obtained (the values of ``foxglove.LocationFix``'s
    and ROS ``NavSatFix``'s position covariance type)."""

    UNKNOWN = 0
    APPROXIMATED = 1  # from dilutions of precision and an assumed range error
    DIAGONAL_KNOWN = 2  # the receiver's own estimate per axis (GST)
    KNOWN = 3


@dataclass(frozen=True, slots=True)
class Fix:
    """A GNSS fix: one epoch's NMEA sentences merged (GGA's position, the date of RMC,
    motion from RMC or VTG, accuracy from GST or the DOPs of GGA and GSA).

    WGS-84 degrees; ``altitude`` metres above the WGS-84 ellipsoid (GGA's mean-sea-level
    altitude plus its geoid separation); ``utc_s`` the fix time, UTC seconds since the
    Unix epoch; ``quality`` GGA's fix quality (0 none, 1 GPS, 2 DGPS, 4 RTK fixed, 5 RTK
    float...), with NaN latitude/longitude/altitude when it is 0; ``speed`` m/s over
    ground and ``course`` rad clockwise from true north (RMC or VTG; NaN where not sent).
    ``sigma_east``, ``sigma_north``, ``sigma_up``: the position's 1-sigma, m (NaN when
    unknown), of the kind ``covariance_type`` says (:class:`CovarianceType`).
    """

    recv_ns: int  # host monotonic ns at receipt of the sentence's last byte
    utc_s: float
    latitude: float
    longitude: float
    altitude: float
    quality: int = 0
    satellites: int = 0
    hdop: float = float("nan")
    speed: float = float("nan")
    course: float = float("nan")
    geoid_separation: float = float("nan")  # m, geoid above the ellipsoid (GGA)
    vdop: float = float("nan")  # GSA
    sigma_east: float = float("nan")
    sigma_north: float = float("nan")
    sigma_up: float = float("nan")
    covariance_type: int = 0  # a CovarianceType


@dataclass(frozen=True, slots=True)
class Sentence:
    """One line of a text protocol (an NMEA sentence) as received, without CR LF."""

    recv_ns: int  # host monotonic ns at receipt of its last byte
    data: bytes
