"""Credentials in URLs kept out of what acq prints and stores.

A device URL may carry a user and password (``http://admin:secret@192.168.0.90/video``)
or pass them in its query (``http://cam/cgi?usr=admin&pwd=secret``, the Foscam form);
:func:`redact` replaces that user information, and the value of every query or fragment
parameter that names a secret (:data:`SECRET_KEYS`), with ``***`` wherever such a URL
appears in a text, keeping the scheme, host, port, path and the other parameters, so a
log line or a recording still says which device it was. :class:`RedactingFilter`
applies it to every log record that passes a handler, its traceback included.
"""

from __future__ import annotations

import logging
import re

__all__ = ["MASK", "SECRET_KEYS", "RedactingFilter", "redact"]

MASK = "***"

# scheme://userinfo@ : the user information runs to the last '@' before the authority ends
# (at '/', '?', '#' or a blank), so a password holding an unescaped '@' is hidden too
_USERINFO = re.compile(r"(?P<scheme>\b[A-Za-z][A-Za-z0-9+.\-]*://)[^\s/?#]*@")

SECRET_KEYS = ("password", "passwd", "pass", "pwd", "pw", "passphrase", "secret", "token",
               "key", "apikey", "auth", "authorization", "credential", "credentials",
               "signature", "sig", "session", "sessionid", "sid", "cookie")  # fmt: skip
"""Query parameters whose value is a secret, in any case, alone or as the last word of
a longer name (``api_key``, ``X-Api-Key``, ``access_token``, ``client.secret``)."""

# ?name=value, &name=value, ;name=value or #name=value (a fragment's OAuth token): the
# value runs to the next parameter, the fragment, a blank, a double quote (not allowed
# in a URL) or a single quote that closes a quoted text ('...pwd=x': or 'pwd=x', 1); a
# JSON escape (\" \\) and a YAML single-quoted string's '' are part of it
_SECRET_PARAM = re.compile(
    r"(?P<name>[?&;#](?:[A-Za-z0-9%_.\-]*[_.\-])?(?:" + "|".join(SECRET_KEYS) + r")=)"
    r"(?:\\.|''|'(?![\s,:)\]}]|$)|[^&;#\s'\"<>\\])*",
    re.IGNORECASE,
)


def redact(text: str) -> str:
    """``text`` with the user and password of every ``scheme://user:pass@host`` in it
    replaced by ``***`` (``http://***@host:port/path``), and the value of every query
    parameter naming a secret (``?usr=admin&pwd=***``)."""
    if "@" in text:
        text = _USERINFO.sub(lambda m: f"{m.group('scheme')}{MASK}@", text)
    if "=" in text:
        text = _SECRET_PARAM.sub(lambda m: f"{m.group('name')}{MASK}", text)
    return text


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
