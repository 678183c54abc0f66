"""TCP packets from a Wireshark "Export Packet Dissections as JSON" file (``tshark -T json``).

:func:`read_packets` turns the export into :class:`Packet` records (capture time in
seconds since the capture began, payload bytes, addresses, sequence number and
Wireshark's retransmission flag, each where the export has it); :func:`split_directions`
separates the two directions of one TCP session, by the exported addresses or, when the
export has none, by a caller's look at the content; :func:`reassemble` rebuilds one
direction's byte stream as a TCP stack would deliver it, without retransmitted repeats,
and the resulting :class:`Stream` tells for any byte offset the capture time at which
that byte became available to the application.

Every problem with the file is a :class:`CaptureFormatError` naming the file and the
element index, e.g. ``x.json: element 12: tcp.payload: not colon-separated hex``.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from acq.errors import InputValueError

__all__ = [
    "CaptureFormatError",
    "Endpoint",
    "Packet",
    "Stream",
    "read_packets",
    "reassemble",
    "split_directions",
]

_RETRANSMISSION_FLAGS = (
    "tcp.analysis.retransmission",
    "tcp.analysis.fast_retransmission",
    "tcp.analysis.spurious_retransmission",
)
_SEQ_MOD = 1 << 32


class CaptureFormatError(InputValueError):
    """A capture export that cannot be read; names the file and the element index."""

    def __init__(self, path: str | Path, index: int | None, message: str) -> None:
        self.path = Path(path)
        self.index = index
        self.message = message
        where = f"{self.path}: " if index is None else f"{self.path}: element {index}: "
        super().__init__(where + message)


@dataclass(frozen=True, slots=True)
class Endpoint:
    """One end of a TCP connection: IP address as Wireshark prints it, and port."""

    address: str
    port: int

    def __str__(self) -> str:
        host = f"[{self.address}]" if ":" in self.address else self.address
        return f"{host}:{self.port}"


@dataclass(frozen=True, slots=True)
class Packet:
    """One TCP packet of the export.

    ``time_s``: seconds since the capture began (``frame.time_relative``; where the
    export has only the TCP conversation's ``tcp.time_relative``, seconds since the
    session's first packet). ``src``/``dst``/``seq`` are None when the export lacks
    them; ``seq`` is ``tcp.seq`` as exported (relative unless Wireshark was told
    otherwise). ``retransmission``: Wireshark's TCP analysis flagged the packet as a
    (fast or spurious) retransmission; False also when the export has no analysis.
    """

    index: int  # element index in the JSON array
    time_s: float
    payload: bytes
    src: Endpoint | None = None
    dst: Endpoint | None = None
    seq: int | None = None
    retransmission: bool = False


@dataclass(frozen=True)
class Stream:
    """One direction's byte stream, reassembled, and where each piece came from.

    Piece ``i`` is ``data[offsets[i]:offsets[i + 1]]`` (the last runs to the end): the new
    bytes of the packet at element ``indices[i]``, available to the application at
    capture time ``times_s[i]`` (s; the packet's own time, or later when it arrived out
    of order and waited for an earlier one). ``dropped``: element indices of packets
    that carried nothing new (retransmissions). ``gaps``: (stream offset, bytes)
    missing from the capture, where sequence numbers show a hole that was never filled.
    """

    data: bytes
    offsets: np.ndarray  # (P,) int64, stream offset of each piece's first byte
    times_s: np.ndarray  # (P,) float64, capture s when the piece became available
    indices: np.ndarray  # (P,) int64, element index of the packet that carried it
    dropped: tuple[int, ...] = ()
    gaps: tuple[tuple[int, int], ...] = ()

    def __len__(self) -> int:
        return len(self.data)

    def pieces(self) -> list[bytes]:
        """The bytes each kept packet contributed, in stream order."""
        ends = [*self.offsets[1:].tolist(), len(self.data)]
        return [self.data[a:b] for a, b in zip(self.offsets.tolist(), ends, strict=True)]

    def times_at(self, offsets: npt.ArrayLike) -> np.ndarray:
        """Capture s at which the bytes at these stream offsets became available."""
        off = np.asarray(offsets, dtype=np.int64)
        if off.size and (off.min() < 0 or off.max() >= len(self.data)):
            raise IndexError(f"stream offset outside 0..{len(self.data) - 1}")
        piece = np.searchsorted(self.offsets, off, side="right") - 1
        return np.asarray(self.times_s[piece], dtype=np.float64)

    def time_at(self, offset: int) -> float:
        """Capture s at which the byte at stream ``offset`` became available."""
        return float(self.times_at(np.array([offset]))[0])


# --- reading ------------------------------------------------------------------------------


def _find(tree: Any, key: str) -> Any:
    """The value of ``key`` anywhere in a nest of dicts (depth first), or None."""
    if not isinstance(tree, dict):
        return None
    if key in tree:
        return tree[key]
    for value in tree.values():
        if isinstance(value, dict):
            found = _find(value, key)
            if found is not None:
                return found
    return None


def _field(layers: dict[str, Any], proto: str, key: str) -> str | None:
    """A field of a full dissection (``layers[proto]``, nested) or of a ``-e`` export
    (``layers[key]``, a list of values); None when absent."""
    value = _find(layers[proto], key) if isinstance(layers.get(proto), dict) else None
    if value is None:
        value = layers.get(key)
    if isinstance(value, list):
        value = value[0] if value else None
    if value is None or isinstance(value, dict | list):
        return None
    return str(value)


def _number(path: Path, index: int, key: str, text: str | None) -> float | None:
    """A finite float field; None when absent."""
    if text is None:
        return None
    try:
        value = float(text)
    except ValueError:
        raise CaptureFormatError(path, index, f"{key}: not a number: {text!r}") from None
    if not math.isfinite(value):
        raise CaptureFormatError(path, index, f"{key}: not a finite number: {text!r}")
    return value


def _integer(path: Path, index: int, key: str, text: str | None) -> int | None:
    """An integer field; None when absent."""
    if text is None:
        return None
    try:
        return int(text)
    except ValueError:
        raise CaptureFormatError(path, index, f"{key}: not a number: {text!r}") from None


def _endpoint(path: Path, index: int, layers: dict[str, Any], end: str) -> Endpoint | None:
    address = _field(layers, "ip", f"ip.{end}") or _field(layers, "ipv6", f"ipv6.{end}")
    port = _integer(path, index, f"tcp.{end}port", _field(layers, "tcp", f"tcp.{end}port"))
    if address is None or port is None:
        return None
    return Endpoint(address, port)


def _packet(path: Path, index: int, element: Any) -> Packet | None:
    """One element as a Packet; None when it is not a TCP packet (ARP, UDP ...)."""
    source = element.get("_source") if isinstance(element, dict) else None
    layers = source.get("layers") if isinstance(source, dict) else None
    if not isinstance(layers, dict):
        raise CaptureFormatError(path, index, "no _source.layers object")
    if not isinstance(layers.get("tcp"), dict) and not any(k.startswith("tcp.") for k in layers):
        return None
    key = "frame.time_relative"
    time_s = _number(path, index, key, _field(layers, "frame", key))
    if time_s is None:
        key = "tcp.time_relative"
        time_s = _number(path, index, key, _field(layers, "tcp", key))
    if time_s is None:
        raise CaptureFormatError(path, index, "no frame.time_relative or tcp.time_relative")
    hexes = _field(layers, "tcp", "tcp.payload")
    if hexes is None:
        hexes = _field(layers, "data", "data.data") or ""
    try:
        payload = bytes.fromhex(hexes.replace(":", "")) if hexes else b""
    except ValueError:
        raise CaptureFormatError(
            path, index, f"tcp.payload: not colon-separated hex: {hexes[:40]!r}"
        ) from None
    length = _integer(path, index, "tcp.len", _field(layers, "tcp", "tcp.len"))
    if length is not None and length != len(payload):
        raise CaptureFormatError(
            path, index, f"tcp.len is {length} but the exported payload has {len(payload)} bytes"
        )
    analysis = layers.get("tcp", {}) if isinstance(layers.get("tcp"), dict) else layers
    flagged = any(_find(analysis, f) is not None or f in layers for f in _RETRANSMISSION_FLAGS)
    return Packet(
        index=index,
        time_s=time_s,
        payload=payload,
        src=_endpoint(path, index, layers, "src"),
        dst=_endpoint(path, index, layers, "dst"),
        seq=_integer(path, index, "tcp.seq", _field(layers, "tcp", "tcp.seq")),
        retransmission=flagged,
    )


def read_packets(path: str | Path) -> list[Packet]:
    """Every TCP packet of a Wireshark JSON export, in file order (elements without a TCP
    layer are skipped). Raises :class:`CaptureFormatError` on malformed input, OSError
    when the file cannot be read."""
    path = Path(path)
    try:
        elements = json.loads(path.read_bytes())
    except json.JSONDecodeError as e:
        raise CaptureFormatError(
            path, None, f"not JSON: {e.msg} at line {e.lineno} column {e.colno}"
        ) from None
    except UnicodeDecodeError as e:
        raise CaptureFormatError(path, None, f"not JSON text: {e.reason}") from None
    if not isinstance(elements, list):
        raise CaptureFormatError(path, None, "not a JSON array of packets")
    packets = []
    for index, element in enumerate(elements):
        packet = _packet(path, index, element)
        if packet is not None:
            packets.append(packet)
    return packets


# --- directions and streams -----------------------------------------------------------------


def split_directions(
    packets: Iterable[Packet],
    *,
    server_port: int | None = None,
    from_server: Callable[[bytes], bool | None] | None = None,
) -> tuple[list[Packet], list[Packet]]:
    """(client to server, server to client): the packets of one TCP session that carry a
    payload, in capture order.

    With exported addresses the direction is theirs: the server is the endpoint on
    ``server_port``, or else the destination of the first packet (the SYN, or the first
    request). Without addresses ``from_server(payload)`` decides: True from the server,
    False to it, None when the payload does not show (it continues the direction of the
    packet before it). ValueError when neither is available, or the packets hold more
    than one session.
    """
    packets = list(packets)
    if packets and all(p.src is not None and p.dst is not None for p in packets):
        ends = {e for p in packets for e in (p.src, p.dst) if e is not None}
        if len(ends) != 2:
            names = ", ".join(sorted(str(e) for e in ends))
            raise ValueError(f"expected one TCP session (two endpoints), got {names}")
        if server_port is None:
            server = packets[0].dst
        else:
            server = next((e for e in ends if e.port == server_port), None)
            if server is None:
                raise ValueError(f"no endpoint on port {server_port}")
        to_server = [p for p in packets if p.payload and p.dst == server]
        return to_server, [p for p in packets if p.payload and p.src == server]
    if from_server is None:
        raise ValueError("the export has no addresses and ports: pass from_server")
    client: list[Packet] = []
    served: list[Packet] = []
    side: list[Packet] | None = None
    for p in packets:
        if not p.payload:
            continue
        verdict = from_server(p.payload)
        if verdict is not None:
            side = served if verdict else client
        elif side is None:
            raise ValueError(f"element {p.index}: cannot tell the direction of the first payload")
        side.append(p)
    return client, served


def _by_sequence(packets: Sequence[Packet]) -> Stream:
    """TCP reassembly by sequence number: overlaps dropped, holes wait for their bytes."""
    data = bytearray()
    offsets: list[int] = []
    times: list[float] = []
    indices: list[int] = []
    dropped: list[int] = []
    gaps: list[tuple[int, int]] = []
    seq0 = packets[0].seq or 0
    held: list[tuple[int, Packet]] = []  # (stream offset, packet) beyond a hole

    def offset_of(p: Packet) -> int:
        rel = ((p.seq or 0) - seq0) % _SEQ_MOD
        return rel + _SEQ_MOD * round((len(data) - rel) / _SEQ_MOD)

    def take(off: int, p: Packet, time_s: float) -> None:
        new = p.payload[len(data) - off :]
        if not new:
            dropped.append(p.index)
            return
        offsets.append(len(data))
        times.append(time_s)
        indices.append(p.index)
        data.extend(new)

    for p in packets:
        if not p.payload:
            continue
        off = offset_of(p)
        if off > len(data):
            held.append((off, p))
            continue
        take(off, p, p.time_s)
        while held:  # what this packet made contiguous is available now
            held.sort(key=lambda h: h[0])
            if held[0][0] > len(data):
                break
            off, q = held.pop(0)
            take(off, q, p.time_s)
    held.sort(key=lambda h: h[0])
    for off, q in held:  # holes never filled: the bytes after each, as captured
        if off > len(data):
            gaps.append((len(data), off - len(data)))
            offsets.append(len(data))
            times.append(q.time_s)
            indices.append(q.index)
            data.extend(q.payload)
        else:
            take(off, q, q.time_s)
    return _stream(data, offsets, times, indices, dropped, gaps)


def _by_repeats(packets: Sequence[Packet]) -> Stream:
    """Without sequence numbers: a packet flagged as a retransmission, or repeating the
    previous kept payload byte for byte, is a retransmission."""
    data = bytearray()
    offsets: list[int] = []
    times: list[float] = []
    indices: list[int] = []
    dropped: list[int] = []
    last = b""
    for p in packets:
        if not p.payload:
            continue
        if p.retransmission or p.payload == last:
            dropped.append(p.index)
            continue
        offsets.append(len(data))
        times.append(p.time_s)
        indices.append(p.index)
        data.extend(p.payload)
        last = p.payload
    return _stream(data, offsets, times, indices, dropped, [])


def _stream(
    data: bytearray,
    offsets: list[int],
    times: list[float],
    indices: list[int],
    dropped: list[int],
    gaps: list[tuple[int, int]],
) -> Stream:
    return Stream(
        data=bytes(data),
        offsets=np.array(offsets, dtype=np.int64),
        times_s=np.array(times, dtype=np.float64),
        indices=np.array(indices, dtype=np.int64),
        dropped=tuple(dropped),
        gaps=tuple(gaps),
    )


def reassemble(packets: Iterable[Packet]) -> Stream:
    """One direction's byte stream from its packets in capture order, as delivered.

    With sequence numbers on every packet: bytes already delivered are dropped (a
    retransmission, whole or partial), a packet beyond a hole waits until the hole is
    filled, and its bytes take the time of the packet that filled it. Without them
    (exports such as the LMS111 capture's), a packet that Wireshark flagged, or that
    repeats the previous kept payload exactly, is a retransmission: an application that
    sends the same bytes twice in a row loses the second copy there.
    """
    packets = [p for p in packets if p.payload]
    if not packets:
        return _stream(bytearray(), [], [], [], [], [])
    if all(p.seq is not None for p in packets):
        return _by_sequence(packets)
    return _by_repeats(packets)
