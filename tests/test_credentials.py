"""Credentials in URLs redacted from texts and log lines."""

from __future__ import annotations

import io
import logging

import pytest

from acq.credentials import RedactingFilter, redact


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("http://admin:S3CRET@127.0.0.1:8080/stream.mjpg: cannot connect",
         "http://***@127.0.0.1:8080/stream.mjpg: cannot connect"),
        ("source: rtsp://user@cam.local/live", "source: rtsp://***@cam.local/live"),
        ("'https://a:p@ss@host' and ftp://u:x@h:21", "'https://***@host' and ftp://***@h:21"),
        ("{\"source\": \"http://admin:pw@10.0.0.9/v?x=a@b#c@d\"}",
         "{\"source\": \"http://***@10.0.0.9/v?x=a@b#c@d\"}"),
        ("http://host/path?mail=a@b.c", "http://host/path?mail=a@b.c"),
        ("socket://127.0.0.1:10940, or user@example.org",
         "socket://127.0.0.1:10940, or user@example.org"),
        ("", ""),
    ],
)  # fmt: skip
def test_redact_hides_the_user_and_password_of_every_url(text: str, expected: str) -> None:
    assert redact(text) == expected


def test_the_filter_redacts_messages_arguments_and_tracebacks() -> None:
    stream = io.StringIO()
    handler = logging.StreamHandler(stream)
    handler.addFilter(RedactingFilter())
    log = logging.getLogger("tests.credentials")
    log.addHandler(handler)
    log.propagate = False
    try:
        log.warning("camera: %s", "http://admin:S3CRET@127.0.0.1:1/x: refused")
        try:
            raise ConnectionError("rtsp://admin:S3CRET@cam/live: reset")
        except ConnectionError:
            log.exception("failed")
    finally:
        log.removeHandler(handler)
        log.propagate = True
    text = stream.getvalue()
    assert "S3CRET" not in text
    assert "camera: http://***@127.0.0.1:1/x: refused" in text
    assert "ConnectionError: rtsp://***@cam/live: reset" in text
