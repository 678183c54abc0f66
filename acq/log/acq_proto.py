"""Our own versioned ``acq.*`` protobuf messages (file ``acq/v1.proto``, package ``acq``),
built at import time from a ``FileDescriptorProto`` (no protoc), and their message
classes: ``acq.RawTelegram``, ``acq.Timing``, ``acq.Clock``, ``acq.Status``,
``acq.DeviceStatus`` (with the live colouring's ``acq.Colouring`` and ``acq.ColourShare``),
``acq.Odometry``, ``acq.CanFrame`` and ``acq.TimeBase`` (with
its parts ``acq.KernelClock``, ``acq.ChronyTracking``, ``acq.PtpTime``, ``acq.PpsSource``
and ``acq.GnssTime``). A change that is not
backwards compatible gets a new file (``acq/v2.proto``); v1 field numbers stay, new
messages and fields may be added. Their encoders are in :mod:`acq.log.schemas`.
"""

from __future__ import annotations

from typing import Any

from google.protobuf import descriptor_pb2, descriptor_pool, timestamp_pb2
from google.protobuf.descriptor import FileDescriptor
from google.protobuf.message_factory import GetMessageClass

__all__ = [
    "ACQ_PROTO",
    "CanFrameMsg",
    "ClockMsg",
    "DeviceStatusMsg",
    "OdometryMsg",
    "RawTelegramMsg",
    "StatusMsg",
    "TimeBaseMsg",
    "TimingMsg",
]

ACQ_PROTO = "acq/v1.proto"  # the file holding the acq.* messages

_F = descriptor_pb2.FieldDescriptorProto
_TIMESTAMP = ".google.protobuf.Timestamp"

# (name, number, type, label, message type name or "")
_FieldSpec = tuple[str, int, int, int, str]
_ONE, _MANY = _F.LABEL_OPTIONAL, _F.LABEL_REPEATED

_ACQ_MESSAGES: dict[str, list[_FieldSpec]] = {
    "RawTelegram": [
        ("timestamp", 1, _F.TYPE_MESSAGE, _ONE, _TIMESTAMP),  # the record's stamp (first point)
        ("device", 2, _F.TYPE_STRING, _ONE, ""),
        ("data", 3, _F.TYPE_BYTES, _ONE, ""),  # the telegram exactly as received
        ("device_ticks", 4, _F.TYPE_UINT64, _MANY, ""),  # raw device clock values
        ("sequence", 5, _F.TYPE_UINT64, _ONE, ""),
        ("recv_ns", 6, _F.TYPE_INT64, _ONE, ""),  # host monotonic ns at receipt
    ],
    "Timing": [
        ("recv_ns", 1, _F.TYPE_INT64, _ONE, ""),
        ("device_ticks", 2, _F.TYPE_UINT64, _MANY, ""),
        ("unwrapped_tick", 3, _F.TYPE_INT64, _ONE, ""),
        ("epoch", 4, _F.TYPE_UINT32, _ONE, ""),  # bumped when the device clock restarts
        ("stamp_ns", 5, _F.TYPE_INT64, _ONE, ""),  # the clock's estimate of the record's time
        ("offset_ns", 6, _F.TYPE_INT64, _ONE, ""),  # host minus device time
        ("drift_ppm", 7, _F.TYPE_DOUBLE, _ONE, ""),
        ("uncertainty_s", 8, _F.TYPE_DOUBLE, _ONE, ""),
        ("sequence", 9, _F.TYPE_UINT64, _ONE, ""),
        ("received", 10, _F.TYPE_UINT64, _ONE, ""),  # records received so far
        ("dropped", 11, _F.TYPE_UINT64, _ONE, ""),  # records lost so far
        # what set stamp_ns: "fix" (the record's own UTC time through the host's UTC
        # clock) or "receipt" (the device clock mapped through receipt times); "": the latter
        ("stamp_source", 12, _F.TYPE_STRING, _ONE, ""),
    ],
    "Clock": [
        ("realtime_ns", 1, _F.TYPE_INT64, _ONE, ""),  # CLOCK_REALTIME, ns since the epoch
        ("monotonic_ns", 2, _F.TYPE_INT64, _ONE, ""),  # CLOCK_MONOTONIC, ns
    ],
    "DeviceStatus": [
        ("name", 1, _F.TYPE_STRING, _ONE, ""),
        ("kind", 2, _F.TYPE_STRING, _ONE, ""),  # "scanner" | "camera" | "can" | "gnss"
        ("connected", 3, _F.TYPE_BOOL, _ONE, ""),
        ("rate_hz", 4, _F.TYPE_DOUBLE, _ONE, ""),
        ("received", 5, _F.TYPE_UINT64, _ONE, ""),
        ("dropped", 6, _F.TYPE_UINT64, _ONE, ""),
        ("corrupt", 7, _F.TYPE_UINT64, _ONE, ""),
        ("disconnects", 8, _F.TYPE_UINT64, _ONE, ""),
        ("protocol_errors", 9, _F.TYPE_UINT64, _ONE, ""),
        ("gap_s", 10, _F.TYPE_DOUBLE, _ONE, ""),
        ("last_event", 11, _F.TYPE_STRING, _ONE, ""),
        ("clock_offset_ns", 12, _F.TYPE_INT64, _ONE, ""),
        ("clock_drift_ppm", 13, _F.TYPE_DOUBLE, _ONE, ""),
        ("clock_uncertainty_s", 14, _F.TYPE_DOUBLE, _ONE, ""),
        ("epoch", 15, _F.TYPE_UINT32, _ONE, ""),
        ("odd_size", 16, _F.TYPE_UINT64, _ONE, ""),  # frames of an unexpected size (cameras)
        ("fast_s", 17, _F.TYPE_DOUBLE, _ONE, ""),  # s over 1.5 x the configured fps (cameras)
        ("required", 18, _F.TYPE_BOOL, _ONE, ""),  # its loss fails the recording
    ],
    "Status": [
        ("timestamp", 1, _F.TYPE_MESSAGE, _ONE, _TIMESTAMP),
        ("uptime_s", 2, _F.TYPE_DOUBLE, _ONE, ""),
        ("file", 3, _F.TYPE_STRING, _ONE, ""),  # the log file being written
        ("disk_free_bytes", 4, _F.TYPE_UINT64, _ONE, ""),
        ("disk_minutes_left", 5, _F.TYPE_DOUBLE, _ONE, ""),
        ("writer_queue", 6, _F.TYPE_UINT32, _ONE, ""),  # records waiting for the writer
        ("devices", 7, _F.TYPE_MESSAGE, _MANY, ".acq.DeviceStatus"),
        ("colouring", 8, _F.TYPE_MESSAGE, _ONE, ".acq.Colouring"),  # unset: no live colouring
    ],
    "ColourShare": [  # one camera's part of the last scans' points
        ("camera", 1, _F.TYPE_STRING, _ONE, ""),
        ("share", 2, _F.TYPE_DOUBLE, _ONE, ""),  # 0..1 of the points, coloured from it
    ],
    "Colouring": [  # the live colourer's counts since start (acq.Status.colouring)
        ("scans_coloured", 1, _F.TYPE_UINT64, _ONE, ""),
        ("scans_skipped", 2, _F.TYPE_UINT64, _ONE, ""),  # it fell behind: not coloured
        ("coloured_share", 3, _F.TYPE_DOUBLE, _ONE, ""),  # 0..1 of the last scans' points
        ("cameras", 4, _F.TYPE_MESSAGE, _MANY, ".acq.ColourShare"),
    ],
    "Odometry": [  # /vehicle/odometry: one per decoded CAN message; NaN: not in it
        ("timestamp", 1, _F.TYPE_MESSAGE, _ONE, _TIMESTAMP),  # the CAN receive stamp
        ("recv_ns", 2, _F.TYPE_INT64, _ONE, ""),  # when the driver read the frame
        ("speed_mps", 3, _F.TYPE_DOUBLE, _ONE, ""),
        ("yaw_rate_rps", 4, _F.TYPE_DOUBLE, _ONE, ""),  # counter-clockwise, REP-103
        ("wheel_speeds_mps", 5, _F.TYPE_DOUBLE, _MANY, ""),  # FL, FR, RL, RR; empty: none
        ("arbitration_id", 6, _F.TYPE_UINT32, _ONE, ""),  # the CAN message decoded
    ],
    "CanFrame": [  # /vehicle/can: every frame of the bus, as received
        ("timestamp", 1, _F.TYPE_MESSAGE, _ONE, _TIMESTAMP),  # receive stamp, monotonic
        ("recv_ns", 2, _F.TYPE_INT64, _ONE, ""),
        ("wall_ns", 3, _F.TYPE_INT64, _ONE, ""),  # the interface's stamp, CLOCK_REALTIME
        ("arbitration_id", 4, _F.TYPE_UINT32, _ONE, ""),
        ("is_extended", 5, _F.TYPE_BOOL, _ONE, ""),
        ("is_remote", 6, _F.TYPE_BOOL, _ONE, ""),
        ("is_error", 7, _F.TYPE_BOOL, _ONE, ""),
        ("is_fd", 8, _F.TYPE_BOOL, _ONE, ""),
        ("data", 9, _F.TYPE_BYTES, _ONE, ""),
        ("channel", 10, _F.TYPE_STRING, _ONE, ""),
    ],
    "KernelClock": [  # adjtimex(2) read only: acq.time.kernel_clock
        ("synchronised", 1, _F.TYPE_BOOL, _ONE, ""),
        ("state", 2, _F.TYPE_STRING, _ONE, ""),
        ("maxerror_s", 3, _F.TYPE_DOUBLE, _ONE, ""),
        ("esterror_s", 4, _F.TYPE_DOUBLE, _ONE, ""),
        ("offset_s", 5, _F.TYPE_DOUBLE, _ONE, ""),
        ("freq_ppm", 6, _F.TYPE_DOUBLE, _ONE, ""),
        ("pll", 7, _F.TYPE_BOOL, _ONE, ""),
        ("pps", 8, _F.TYPE_BOOL, _ONE, ""),
        ("tai_s", 9, _F.TYPE_INT32, _ONE, ""),
    ],
    "ChronyTracking": [  # `chronyc -c tracking`: acq.time.chrony
        ("reference_id", 1, _F.TYPE_UINT32, _ONE, ""),
        ("reference_name", 2, _F.TYPE_STRING, _ONE, ""),
        ("stratum", 3, _F.TYPE_UINT32, _ONE, ""),
        ("ref_time_s", 4, _F.TYPE_DOUBLE, _ONE, ""),  # UTC s of the last update
        ("system_offset_s", 5, _F.TYPE_DOUBLE, _ONE, ""),  # positive: host clock behind
        ("last_offset_s", 6, _F.TYPE_DOUBLE, _ONE, ""),  # host clock minus the reference
        ("rms_offset_s", 7, _F.TYPE_DOUBLE, _ONE, ""),
        ("frequency_ppm", 8, _F.TYPE_DOUBLE, _ONE, ""),
        ("residual_frequency_ppm", 9, _F.TYPE_DOUBLE, _ONE, ""),
        ("skew_ppm", 10, _F.TYPE_DOUBLE, _ONE, ""),
        ("root_delay_s", 11, _F.TYPE_DOUBLE, _ONE, ""),
        ("root_dispersion_s", 12, _F.TYPE_DOUBLE, _ONE, ""),
        ("update_interval_s", 13, _F.TYPE_DOUBLE, _ONE, ""),
        ("leap_status", 14, _F.TYPE_STRING, _ONE, ""),
    ],
    "PtpTime": [  # ptp4l's TIME_STATUS_NP: acq.time.ptp
        ("master_offset_s", 1, _F.TYPE_DOUBLE, _ONE, ""),
        ("gm_present", 2, _F.TYPE_BOOL, _ONE, ""),
        ("gm_identity", 3, _F.TYPE_STRING, _ONE, ""),
    ],
    "PpsSource": [  # /sys/class/pps/ppsN: acq.time.pps
        ("name", 1, _F.TYPE_STRING, _ONE, ""),
        ("assert_sequence", 2, _F.TYPE_UINT64, _ONE, ""),
        ("assert_s", 3, _F.TYPE_DOUBLE, _ONE, ""),  # host UTC s
        ("clear_sequence", 4, _F.TYPE_UINT64, _ONE, ""),
        ("clear_s", 5, _F.TYPE_DOUBLE, _ONE, ""),
    ],
    "GnssTime": [  # the GNSS receiver's time against the host clock
        ("host_minus_gnss_s", 1, _F.TYPE_DOUBLE, _ONE, ""),
        ("latency_s", 2, _F.TYPE_DOUBLE, _ONE, ""),
        ("fix_age_s", 3, _F.TYPE_DOUBLE, _ONE, ""),
    ],
    "TimeBase": [  # /acq/timebase, 1 Hz: what the host knows about its clock
        ("timestamp", 1, _F.TYPE_MESSAGE, _ONE, _TIMESTAMP),  # host monotonic
        ("realtime_ns", 2, _F.TYPE_INT64, _ONE, ""),  # read with monotonic_ns
        ("monotonic_ns", 3, _F.TYPE_INT64, _ONE, ""),
        ("kernel", 4, _F.TYPE_MESSAGE, _ONE, ".acq.KernelClock"),  # each: unset when absent
        ("chrony", 5, _F.TYPE_MESSAGE, _ONE, ".acq.ChronyTracking"),
        ("ptp", 6, _F.TYPE_MESSAGE, _ONE, ".acq.PtpTime"),
        ("pps", 7, _F.TYPE_MESSAGE, _ONE, ".acq.PpsSource"),
        ("gnss", 8, _F.TYPE_MESSAGE, _ONE, ".acq.GnssTime"),
        ("absent", 9, _F.TYPE_STRING, _MANY, ""),  # "<source>: why", one per absent source
        ("synchronised", 10, _F.TYPE_BOOL, _ONE, ""),  # something disciplines the clock
    ],
}


def _acq_file_proto() -> descriptor_pb2.FileDescriptorProto:
    fdp = descriptor_pb2.FileDescriptorProto(
        name=ACQ_PROTO,
        package="acq",
        syntax="proto3",
        dependency=[timestamp_pb2.DESCRIPTOR.name],
    )
    for msg_name, specs in _ACQ_MESSAGES.items():
        msg = fdp.message_type.add(name=msg_name)
        for name, number, ftype, label, type_name in specs:
            field = msg.field.add(name=name, number=number, type=ftype, label=label)
            if type_name:
                field.type_name = type_name
    return fdp


def _acq_file() -> FileDescriptor:
    pool = descriptor_pool.Default()  # already holds google/protobuf/timestamp.proto
    try:
        return pool.FindFileByName(ACQ_PROTO)
    except KeyError:
        pool.Add(_acq_file_proto())
        return pool.FindFileByName(ACQ_PROTO)


_ACQ_FILE = _acq_file()
# built at run time, so their fields are unknown to the type checker: Any, not Message
RawTelegramMsg: Any = GetMessageClass(_ACQ_FILE.message_types_by_name["RawTelegram"])
TimingMsg: Any = GetMessageClass(_ACQ_FILE.message_types_by_name["Timing"])
ClockMsg: Any = GetMessageClass(_ACQ_FILE.message_types_by_name["Clock"])
DeviceStatusMsg: Any = GetMessageClass(_ACQ_FILE.message_types_by_name["DeviceStatus"])
StatusMsg: Any = GetMessageClass(_ACQ_FILE.message_types_by_name["Status"])
OdometryMsg: Any = GetMessageClass(_ACQ_FILE.message_types_by_name["Odometry"])
CanFrameMsg: Any = GetMessageClass(_ACQ_FILE.message_types_by_name["CanFrame"])
TimeBaseMsg: Any = GetMessageClass(_ACQ_FILE.message_types_by_name["TimeBase"])
