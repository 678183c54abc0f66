"""Credentials in URLs redacted from texts and log lines."""

from __future__ import annotations

import io
import json
import logging

import pytest
import yaml

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


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("http://host/x?user=admin&password=s3cret: cannot connect",
         "http://host/x?user=admin&password=*** cannot connect"),
        ("http://cam/cgi-bin/CGIStream.cgi?cmd=GetMJStream&usr=admin&pwd=s3cret",
         "http://cam/cgi-bin/CGIStream.cgi?cmd=GetMJStream&usr=admin&pwd=***"),
        ("{\"source\": \"http://h/v?PASS=a%26b&fps=25\"}",
         "{\"source\": \"http://h/v?PASS=***&fps=25\"}"),
        ("source: 'rtsp://u:p@h/x?passwd=1;token=2&api_key=3&X-Api-Key=4#access_token=5'",
         "source: 'rtsp://***@h/x?passwd=***;token=***&api_key=***&X-Api-Key=***"
         "#access_token=***'"),
        ("http://h/x?secret=&key=k&client_secret=c", "http://h/x?secret=***&key=***&client_secret=***"),
        # names that only hold a secret's letters stay, as do values outside a query
        ("http://h/x?keyframe=1&passive=0&monkey=2&keys=3", "http://h/x?keyframe=1&passive=0&monkey=2&keys=3"),
        ("password=s3cret in a sentence", "password=s3cret in a sentence"),
    ],
)  # fmt: skip
def test_redact_hides_the_secret_parameters_of_a_query(text: str, expected: str) -> None:
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


@pytest.mark.parametrize("secret", ["it's", "a'b\\c", "x''", "é%27s"])
def test_a_secret_with_quotes_is_hidden_whole_wherever_it_is_written(secret: str) -> None:
    url = f"http://cam/x?usr=admin&pwd={secret}&fps=25"
    hidden = "http://cam/x?usr=admin&pwd=***&fps=25"
    as_json = redact(json.dumps({"source": url}))
    assert json.loads(as_json) == {"source": hidden}
    as_yaml = redact(yaml.safe_dump({"source": url}))
    assert yaml.safe_load(as_yaml) == {"source": hidden}
    listed = redact(repr([url[:-7], 1]))  # as %r writes it, the secret last
    assert listed in (f"['{hidden[:-7]}', 1]", f'["{hidden[:-7]}", 1]'), listed
    quoted = redact(f"'{url[:-7]}': connection refused")
    assert quoted == f"'{hidden[:-7]}': connection refused"
