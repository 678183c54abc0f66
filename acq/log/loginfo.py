"""The old module name, for the one caller left: ``acq info`` (acq/cli/info.py, with its
tests), which imports ``acq.log.loginfo`` until it is re-pointed at :mod:`acq.log`; then
this module goes."""

from acq.log import format_info, info_many, repair

__all__ = ["format_info", "info_many", "repair"]
