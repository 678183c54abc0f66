"""Credentials in URLs kept out of what acq prints and stores.

A device URL may carry a user and password (``http://admin:secret@192.168.0.90/video``);
:func:`redact` replaces that user information with ``***`` wherever such a URL appears
in a text, keeping the scheme, host, port and path, so a log line or a recording still
says which device it was. :class:`RedactingFilter` applies it to every log record that
passes a handler, its traceback included.
"""

from __future__ import annotations

import logging
import re

__all__ = ["MASK", "RedactingFilter", "redact"]

MASK = "***"

# scheme://userinfo@ : the user information runs to the last '@' before the authority ends
# (at '/', '?', '#' or a blank), so a password holding an unescaped '@' is hidden too
_USERINFO = re.compile(r"(?P<scheme>\b[A-Za-z][A-Za-z0-9+.\-]*://)[^\s/?#]*@")


def redact(text: str) -> str:
    """``text`` with the user and password of every ``scheme://user:pass@host`` in it
    replaced by ``***`` (``http://***@host:port/path``)."""
    if "@" not in text:
        return text
    return _USERINFO.sub(lambda m: f"{m.group('scheme')}{MASK}@", text)


class RedactingFilter(logging.Filter):
    """Redacts the credentials of URLs in a log record's message and traceback (the
    record is changed in place: install it on the handler, so every line it writes is
    redacted whichever logger made it)."""

    def filter(self, record: logging.LogRecord) -> bool:
        message = record.getMessage()
        clean = redact(message)
        if clean != message:
            record.msg, record.args = clean, None
        if record.exc_info and not record.exc_text:
            record.exc_text = logging.Formatter().formatException(record.exc_info)
        if record.exc_text:
            record.exc_text = redact(record.exc_text)
        if record.stack_info:
            record.stack_info = redact(record.stack_info)
        return True
