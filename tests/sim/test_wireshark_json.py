"""tests.wireshark_json: Wireshark JSON exports of TCP sessions, synthetic and real.

The synthetic exports follow ``tshark -T json`` (full dissection: frame, ip, tcp with
its analysis and Timestamps subtrees) and ``tshark -T json -e FIELD`` (flat lists); the
real one is the LMS111 capture, whose converter kept only the TCP payload and time.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from acq.drivers.cola_codec import ColaFramer, Telegram
from tests.wireshark_json import (
    CaptureFormatError,
    Endpoint,
    Packet,
    read_packets,
    reassemble,
    split_directions,
)

HOST = ("192.168.0.10", 40000)
DEVICE = ("192.168.0.1", 2112)


def element(
    time_s: float,
    payload: bytes,
    *,
    src: tuple[str, int] = HOST,
    dst: tuple[str, int] = DEVICE,
    seq: int | None = None,
    flag: str | None = None,
) -> dict[str, Any]:
    """One packet as ``tshark -T json`` writes it (the fields the reader looks at)."""
    tcp: dict[str, Any] = {
        "tcp.srcport": str(src[1]),
        "tcp.dstport": str(dst[1]),
        "tcp.len": str(len(payload)),
        "tcp.flags_tree": {"tcp.flags.push": "1"},
        "Timestamps": {"tcp.time_delta": "0.0", "tcp.time_relative": str(time_s - 0.5)},
    }
    if seq is not None:
        tcp["tcp.seq"] = str(seq)
        tcp["tcp.seq_raw"] = str(seq + 123456789)
    analysis: dict[str, Any] = {"tcp.analysis.bytes_in_flight": str(len(payload))}
    if flag is not None:
        analysis[flag] = {"_ws.expert": {flag: "", "_ws.expert.severity": "4194304"}}
    tcp["tcp.analysis"] = analysis
    if payload:
        tcp["tcp.payload"] = payload.hex(":")
    layers = {
        "frame": {"frame.time_relative": repr(time_s), "frame.number": "1"},
        "eth": {"eth.type": "0x0800"},
        "ip": {"ip.src": src[0], "ip.dst": dst[0], "ip.src_host": src[0]},
        "tcp": tcp,
    }
    return {"_index": "packets-2021-03-02", "_type": "doc", "_score": None,
            "_source": {"layers": layers}}  # fmt: skip


def write(tmp_path: Path, elements: Any, name: str = "cap.json") -> Path:
    path = tmp_path / name
    path.write_text(json.dumps(elements))
    return path


# --- reading ----------------------------------------------------------------------------


def test_full_dissection_fields(tmp_path: Path) -> None:
    arp = {"_source": {"layers": {"frame": {"frame.time_relative": "0.0"}, "arp": {}}}}
    path = write(
        tmp_path,
        [
            arp,
            element(1.25, b"", seq=0),  # a SYN: no payload
            element(1.5, b"\x02ab", seq=1),
            element(1.75, b"\x02ab", seq=1, flag="tcp.analysis.retransmission"),
            element(2.0, b"xyz", src=DEVICE, dst=HOST, seq=1),
        ],
    )
    packets = read_packets(path)
    assert [p.index for p in packets] == [1, 2, 3, 4]  # element indices; ARP skipped
    p = packets[1]
    assert p == Packet(2, 1.5, b"\x02ab", Endpoint(*HOST), Endpoint(*DEVICE), 1, False)
    assert packets[0].payload == b"" and packets[2].retransmission
    assert packets[3].src == Endpoint(*DEVICE) and str(packets[3].src) == "192.168.0.1:2112"
    assert str(Endpoint("fe80::1", 2112)) == "[fe80::1]:2112"


def test_flat_field_export_and_tcp_time(tmp_path: Path) -> None:
    """``-e`` exports hold lists of values; tcp.time_relative stands in for frame's."""
    layers = {
        "tcp.time_relative": ["0.125"],
        "ipv6.src": ["fe80::1"],
        "ipv6.dst": ["fe80::2"],
        "tcp.srcport": ["2112"],
        "tcp.dstport": ["50000"],
        "tcp.payload": ["41:42"],
        "tcp.analysis.fast_retransmission": [""],
    }
    (p,) = read_packets(write(tmp_path, [{"_source": {"layers": layers}}]))
    assert p.time_s == 0.125 and p.payload == b"AB" and p.seq is None
    assert p.src == Endpoint("fe80::1", 2112) and p.dst == Endpoint("fe80::2", 50000)
    assert p.retransmission


@pytest.mark.parametrize(
    ("content", "index", "message"),
    [
        ("[{]", None, "not JSON: .* line 1 column 3"),
        ('{"a": 1}', None, "not a JSON array"),
        ('[{"_source": {"layers": {"tcp": {"tcp.time_relative": "0"}}}}, 3]', 1, "_source"),
        ('[{"_source": {}}]', 0, "no _source.layers"),
        ('[{"_source": 7}]', 0, "no _source.layers"),
        ('[{"_source": {"layers": {"tcp": {"tcp.payload": "41"}}}}]', 0, "time_relative"),
    ],
)
def test_malformed_file(tmp_path: Path, content: str, index: int | None, message: str) -> None:
    path = tmp_path / "bad.json"
    path.write_text(content)
    with pytest.raises(CaptureFormatError, match=message) as e:
        read_packets(path)
    assert e.value.index == index and e.value.path == path
    where = f"{path}: " if index is None else f"{path}: element {index}: "
    assert str(e.value).startswith(where)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"tcp.payload": "02:zz:03"}, "tcp.payload: not colon-separated hex"),
        ({"tcp.len": "7"}, "tcp.len is 7 but the exported payload has 3 bytes"),
        ({"tcp.seq": "one"}, "tcp.seq: not a number"),
        ({"tcp.srcport": ""}, "tcp.srcport: not a number"),
        ({"Timestamps": {"tcp.time_relative": "nan"}}, None),
    ],
)
def test_malformed_element(tmp_path: Path, change: dict[str, Any], message: str | None) -> None:
    good = element(0.5, b"abc", seq=1)
    bad = element(0.75, b"abc", seq=4)
    bad["_source"]["layers"]["tcp"].update(change)
    if message is None:  # a bad time: the frame's is read first
        bad["_source"]["layers"]["frame"]["frame.time_relative"] = "inf"
        message = "frame.time_relative: not a finite number"
    path = write(tmp_path, [good, good, bad])
    with pytest.raises(CaptureFormatError, match=message) as e:
        read_packets(path)
    assert e.value.index == 2 and str(e.value).startswith(f"{path}: element 2: ")


def test_unreadable_file_is_an_os_error(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError):
        read_packets(tmp_path / "missing.json")
    (tmp_path / "bin.json").write_bytes(b"\xff\xfe\x00[")
    with pytest.raises(CaptureFormatError, match=r"bin\.json: not JSON"):
        read_packets(tmp_path / "bin.json")


# --- directions ---------------------------------------------------------------------------


def test_split_by_addresses(tmp_path: Path) -> None:
    packets = read_packets(
        write(
            tmp_path,
            [
                element(0.1, b"", seq=0),
                element(0.2, b"req", seq=1),
                element(0.3, b"ans", src=DEVICE, dst=HOST, seq=1),
                element(0.4, b"", src=DEVICE, dst=HOST, seq=4),
            ],
        )
    )
    to_dev, from_dev = split_directions(packets)  # the server: the first packet's dst
    assert [p.index for p in to_dev] == [1] and [p.index for p in from_dev] == [2]
    # the addresses win over a content classifier that says otherwise
    assert split_directions(packets, server_port=2112, from_server=lambda b: True) == (
        to_dev,
        from_dev,
    )
    assert split_directions(packets, server_port=40000) == (from_dev, to_dev)
    with pytest.raises(ValueError, match="no endpoint on port 1"):
        split_directions(packets, server_port=1)
    third = element(0.5, b"x", src=("10.0.0.9", 1), seq=1)
    more = read_packets(write(tmp_path, [*map(_raw, packets), third], "more.json"))
    with pytest.raises(ValueError, match=r"one TCP session .*10\.0\.0\.9:1"):
        split_directions(more)


def _raw(p: Packet) -> dict[str, Any]:
    assert p.src is not None and p.dst is not None
    src, dst = (p.src.address, p.src.port), (p.dst.address, p.dst.port)
    return element(p.time_s, p.payload, src=src, dst=dst, seq=p.seq)


def test_split_by_content() -> None:
    def from_server(b: bytes) -> bool | None:
        return {b"Q": False, b"A": True}.get(b[:1])

    packets = [Packet(i, 0.1 * i, b) for i, b in enumerate([b"Q1", b"..", b"A1", b"", b".."])]
    to_s, from_s = split_directions(packets, from_server=from_server)
    assert [p.index for p in to_s] == [0, 1] and [p.index for p in from_s] == [2, 4]
    with pytest.raises(ValueError, match="no addresses"):
        split_directions(packets)
    with pytest.raises(ValueError, match="element 1: cannot tell"):
        split_directions(packets[1:], from_server=from_server)


# --- reassembly -----------------------------------------------------------------------------


def test_reassemble_by_sequence_numbers() -> None:
    """Whole and partial retransmissions are dropped; a packet that came early waits for
    the hole before it and takes the filling packet's time."""
    p = [
        Packet(0, 1.0, b"abcd", seq=1),
        Packet(1, 1.1, b"abcd", seq=1, retransmission=True),  # a whole repeat
        Packet(2, 1.2, b"cdef", seq=3),  # overlaps: "ef" is new
        Packet(3, 1.3, b"klm", seq=11),  # early: "ghij" is missing
        Packet(4, 1.4, b"ghij", seq=7),  # fills the hole
        Packet(5, 1.5, b"", seq=14),  # an ACK
        Packet(6, 1.6, b"nop", seq=14),
    ]
    s = reassemble(p)
    assert s.data == b"abcdefghijklmnop" and len(s) == 16
    assert s.pieces() == [b"abcd", b"ef", b"ghij", b"klm", b"nop"]
    assert s.indices.tolist() == [0, 2, 4, 3, 6] and s.offsets.tolist() == [0, 4, 6, 10, 13]
    assert s.times_s.tolist() == [1.0, 1.2, 1.4, 1.4, 1.6]
    assert s.dropped == (1,) and s.gaps == ()
    assert s.time_at(0) == 1.0 and s.time_at(5) == 1.2 and s.time_at(12) == 1.4
    assert s.times_at([3, 4, 15]).tolist() == [1.0, 1.2, 1.6]
    for bad in (-1, 16):
        with pytest.raises(IndexError):
            s.time_at(bad)


def test_reassemble_sequence_wrap_and_unfilled_hole() -> None:
    top = (1 << 32) - 2
    p = [
        Packet(0, 0.0, b"ab", seq=top),
        Packet(1, 0.1, b"cd", seq=0),  # the sequence number wrapped
        Packet(2, 0.2, b"gh", seq=4),  # "ef" never captured
        Packet(3, 0.3, b"cd", seq=0),  # a late repeat
    ]
    s = reassemble(p)
    assert s.data == b"abcdgh" and s.gaps == ((4, 2),) and s.dropped == (3,)
    assert s.times_s.tolist() == [0.0, 0.1, 0.2]


def test_reassemble_without_sequence_numbers() -> None:
    p = [
        Packet(0, 0.0, b"one"),
        Packet(1, 0.1, b"one"),  # an exact repeat: a retransmission
        Packet(2, 0.2, b"two"),
        Packet(3, 0.3, b"xx", retransmission=True),  # flagged by Wireshark
        Packet(4, 0.4, b"one"),  # not the previous payload: kept
    ]
    s = reassemble(p)
    assert s.data == b"onetwoone" and s.dropped == (1, 3)
    assert s.indices.tolist() == [0, 2, 4] and s.time_at(8) == 0.4
    empty = reassemble([Packet(0, 0.0, b"")])
    assert empty.data == b"" and empty.offsets.size == 0 and empty.times_at([]).size == 0


# --- the real LMS111 capture ------------------------------------------------------------


def _from_device(payload: bytes) -> bool | None:
    if payload[:4] != b"\x02\x02\x02\x02":
        return None
    return payload[8:11] not in (b"sMN", b"sRN", b"sWN", b"sEN")


def test_real_capture(shared_dir: Path) -> None:
    path = shared_dir / "data" / "sick" / "20210302_lms111.pcapng.json"
    packets = read_packets(path)
    assert len(packets) == 277 and [p.index for p in packets] == list(range(277))
    assert all(p.src is None and p.seq is None and not p.retransmission for p in packets)
    times = np.array([p.time_s for p in packets])
    assert times[0] == pytest.approx(0.20301556587219238) and (np.diff(times) >= 0).all()
    host_pk, dev_pk = split_directions(packets, from_server=_from_device)
    host, device = reassemble(host_pk), reassemble(dev_pk)
    assert host.dropped == () and len(device.dropped) == 6
    # The time of each telegram's last byte, from the stream, is the stamp a framer fed
    # packet by packet gives it.
    framer = ColaFramer("b")
    for piece, t in zip(device.pieces(), device.times_s.tolist(), strict=True):
        framer.feed(piece, stamp_ns=round(t * 1e9))
    fed = [t for t in framer.items() if isinstance(t, Telegram)]
    assert framer.skipped == 0 and framer.pending == 0
    ends = np.cumsum([len(t.raw) for t in fed]) - 1
    assert ends[-1] == len(device) - 1
    assert np.array_equal(np.round(device.times_at(ends) * 1e9), [t.stamp_ns for t in fed])
    scans = [t for t in fed if t.kind == "sSN" and t.name == "LMDscandata"]
    assert len(scans) == 172
