"""MCAP logs: the message schemas (:mod:`acq.log.schemas`), the recorder's writer, one
reader (a decoder cached per channel), the summaries of ``acq info``, and repair."""

from acq.log.reader import LogError, LogReader, read_messages, read_metadata
from acq.log.repair import repair
from acq.log.summary import ChannelInfo, DeviceSync, LogInfo, format_info, info, info_many
from acq.log.writer import LatchedData, LogWriter

__all__ = [
    "ChannelInfo",
    "DeviceSync",
    "LatchedData",
    "LogError",
    "LogInfo",
    "LogReader",
    "LogWriter",
    "format_info",
    "info",
    "info_many",
    "read_messages",
    "read_metadata",
    "repair",
]
