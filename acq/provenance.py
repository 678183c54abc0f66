"""Which files acq wrote. Every image, cloud and JSON report acq writes carries a mark (a
PNG text chunk, a JPEG comment, a PLY header comment, the LAS header's generating
software, an E57 scan's sensor software version, a glTF's ``asset.generator``, an OBJ's
first comment, a ``"software"`` key), so a later run
may replace its own product while a file of anyone else is kept (the rule of
:mod:`acq.cli.output_files`).
"""

from __future__ import annotations

import json
import os
import re
import struct
import zlib
from pathlib import Path

import numpy as np

from acq import __version__
from acq.atomic_write import discard, temporary_beside

__all__ = ["SOFTWARE", "made_by_acq", "marked_image", "write_image"]

SOFTWARE = f"acq {__version__}"  # as the marks give it

_HEAD_BYTES = 64 * 1024  # where a mark must be: headers, the first chunks
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_PNG_TEXT = b"Software\x00" + SOFTWARE.encode()
_JPEG_COMMENT = b"\xff\xfe" + (2 + len(SOFTWARE)).to_bytes(2, "big") + SOFTWARE.encode()
_JSON_KEY = re.compile(rb'\A\s*\{\s*"software"\s*:\s*"acq[ "]')
_E57_MARK = re.compile(rb"<sensorSoftwareVersion[^>]*>(<!\[CDATA\[)?acq ")
_E57_XML_BYTES = 16 * 2**20  # a larger XML section is not one acq wrote


def marked_image(data: bytes) -> bytes:
    """An encoded PNG or JPEG with acq's mark added (a ``Software`` text chunk after the
    header; a comment after the JFIF segment); other bytes as they are."""
    if data.startswith(_PNG_SIGNATURE):
        end_of_ihdr = len(_PNG_SIGNATURE) + 8 + int.from_bytes(data[8:12], "big") + 4
        chunk = b"tEXt" + _PNG_TEXT
        crc = zlib.crc32(chunk).to_bytes(4, "big")
        text = len(_PNG_TEXT).to_bytes(4, "big") + chunk + crc
        return data[:end_of_ihdr] + text + data[end_of_ihdr:]
    if data.startswith(b"\xff\xd8"):
        at = 2
        if data[2:4] == b"\xff\xe0":  # JFIF's APP0 stays first
            at = 4 + int.from_bytes(data[4:6], "big")
        return data[:at] + _JPEG_COMMENT + data[at:]
    return data


def write_image(path: str | os.PathLike[str], image: np.ndarray) -> None:
    """Write ``image`` (BGR or grey, uint8) in the format of ``path``'s suffix (PNG when
    it has none that OpenCV knows), marked as acq's; whole or not at all (a temporary
    file beside it, then renamed). OSError naming ``path`` when it cannot."""
    import cv2  # 0.3 s to import: only where an image is written

    path = Path(path)
    suffix = path.suffix.lower() if path.suffix.lower() in (".png", ".jpg", ".jpeg") else ".png"
    try:
        ok, buf = cv2.imencode(suffix, image)
    except cv2.error:
        ok = False
    if not ok:
        raise OSError(f"{path}: cannot encode the image ({image.shape}, {image.dtype})")
    tmp = temporary_beside(path, suffix)
    try:
        tmp.write_bytes(marked_image(buf.tobytes()))
        os.replace(tmp, path)
    except OSError as e:
        raise OSError(e.errno, e.strerror or str(e), str(path)) from e
    finally:
        discard(tmp)


def _glb_generator(head: bytes) -> str:
    """The ``asset.generator`` of a glb whose first bytes are ``head`` ("" for none, or
    a JSON chunk that is not whole in them or not JSON)."""
    (length,) = struct.unpack_from("<I", head, 12) if len(head) >= 20 else (0,)
    try:
        tree = json.loads(head[20 : 20 + length]) if 20 + length <= len(head) else None
    except ValueError:
        return ""
    asset = tree.get("asset") if isinstance(tree, dict) else None
    generator = asset.get("generator") if isinstance(asset, dict) else None
    return generator if isinstance(generator, str) else ""


def made_by_acq(path: str | os.PathLike[str]) -> bool:
    """Whether the existing file ``path`` carries acq's mark (any version of acq)."""
    with open(path, "rb") as f:
        head = f.read(_HEAD_BYTES)
    if head.startswith(_PNG_SIGNATURE):
        return b"tEXtSoftware\x00acq " in head
    if head.startswith(b"\xff\xd8"):
        return re.search(rb"\xff\xfe..acq ", head, re.DOTALL) is not None
    if head.startswith(b"ply"):
        header = head.split(b"end_header", 1)[0]
        return b"\ncomment acq " in header
    if head.startswith(b"LASF"):
        return head[58:90].startswith(b"acq ")  # the header's generating software
    if head.startswith(b"glTF"):  # the JSON chunk follows the 20 bytes of headers
        return _glb_generator(head).startswith("acq ")
    if head.startswith(b"# acq "):  # an OBJ: its first comment
        return True
    if head.startswith(b"ASTM-E57"):
        return _E57_MARK.search(_e57_xml(path, head)) is not None
    return _JSON_KEY.match(head) is not None


def _e57_xml(path: str | os.PathLike[str], head: bytes) -> bytes:
    """The XML section of an E57 file (at its end; every page of ``pageSize`` bytes ends
    in a 4-byte CRC, ASTM E2807 §8); empty when the header or the file is short."""
    if len(head) < 48:
        return b""
    offset, length, page = struct.unpack_from("<QQQ", head, 24)
    if not (64 <= page <= 1 << 20 and length <= _E57_XML_BYTES):
        return b""
    start = offset - offset % page
    with open(path, "rb") as f:
        f.seek(start)
        raw = f.read(offset % page + length + (length // (page - 4) + 2) * 4)
    data = b"".join(raw[i : i + page - 4] for i in range(0, len(raw), page))
    return data[offset % page : offset % page + length]
