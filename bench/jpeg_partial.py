"""Colour JPEGs decoded only where they are read, by the system's libjpeg-turbo (ctypes on
``libjpeg.so.62``: no compiler at install). The decoder of ``partial_decode.py``'s
experiment, not the product's: on the demo's frames it saves about 7 % of the decoding's
CPU (the entropy decoding of every row up to the last one read cannot be skipped), so
``acq colorize`` decodes whole frames with simplejpeg.

Colouring reads a few hundred pixels of a frame, in a band of its rows. Here the rows
asked for are decoded whole iMCU rows at a time; the iMCU rows between them are skipped
(``jpeg_skip_scanlines``: their entropy-coded data is read, their inverse DCT, upsampling
and colour conversion are not), none after the last one is read at all, and only the
columns asked for are decoded (``jpeg_crop_scanline``, widened to whole iMCUs and by two
pixels each side, so the pixels asked for are never at the crop's edge, where fancy
upsampling treats them as the image's). The pixels asked for are those of a whole
decode (libjpeg's defaults: the accurate integer inverse DCT, fancy upsampling);
the others are left as they were.

libjpeg reports an error by calling a handler that must not return (it ends the process
by default, or jumps out with longjmp, which ctypes cannot do). So a JPEG is given to it
only when :func:`plain_header` passed its header: one baseline or extended sequential
8-bit frame of three components (Y sampled 1x1, 2x1 or 2x2, the others 1x1), one
interleaved scan, every table it uses defined and valid: the checks libjpeg makes up to
the scan that end in an error. What follows (the entropy-coded data) can only raise
warnings (damage, truncation): the frame is then said not decoded here, for the caller
to decode it whole, as it would have. Should the error handler still be called, the
frame is marked failed and the handler returns (libjpeg goes on with what it has).

Units: pixels; images (H,W,3) BGR uint8.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import threading
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = [
    "Header",
    "available",
    "decode_rows",
    "errors_caught",
    "plain_header",
    "why_unavailable",
]

_LIB_VERSION = 62  # the libjpeg API the struct below is laid out for
_JCS_YCBCR = 3
_JCS_EXT_BGR = 8  # libjpeg-turbo's BGR output
_MAX_DIMENSION = 65500  # libjpeg's JPEG_MAX_DIMENSION
_P, _I, _U, _B = ctypes.c_void_p, ctypes.c_int, ctypes.c_uint, ctypes.c_ubyte


class _ErrorMgr(ctypes.Structure):
    _fields_ = [
        ("error_exit", _P), ("emit_message", _P), ("output_message", _P),
        ("format_message", _P), ("reset_error_mgr", _P), ("msg_code", _I),
        ("msg_parm", _I * 20), ("trace_level", _I), ("num_warnings", ctypes.c_long),
        ("jpeg_message_table", _P), ("last_jpeg_message", _I),
        ("addon_message_table", _P), ("first_addon_message", _I),
        ("last_addon_message", _I),
    ]  # fmt: skip


class _Decompress(ctypes.Structure):
    """``struct jpeg_decompress_struct`` of libjpeg-turbo's JPEG_LIB_VERSION 62 API
    (632 bytes on x86-64; ``jpeg_CreateDecompress`` checks the size given)."""

    _fields_ = [
        ("err", ctypes.POINTER(_ErrorMgr)), ("mem", _P), ("progress", _P),
        ("client_data", _P), ("is_decompressor", _I), ("global_state", _I), ("src", _P),
        ("image_width", _U), ("image_height", _U), ("num_components", _I),
        ("jpeg_color_space", _I), ("out_color_space", _I), ("scale_num", _U),
        ("scale_denom", _U), ("output_gamma", ctypes.c_double), ("buffered_image", _I),
        ("raw_data_out", _I), ("dct_method", _I), ("do_fancy_upsampling", _I),
        ("do_block_smoothing", _I), ("quantize_colors", _I), ("dither_mode", _I),
        ("two_pass_quantize", _I), ("desired_number_of_colors", _I),
        ("enable_1pass_quant", _I), ("enable_external_quant", _I),
        ("enable_2pass_quant", _I), ("output_width", _U), ("output_height", _U),
        ("out_color_components", _I), ("output_components", _I),
        ("rec_outbuf_height", _I), ("actual_number_of_colors", _I), ("colormap", _P),
        ("output_scanline", _U), ("input_scan_number", _I), ("input_iMCU_row", _U),
        ("output_scan_number", _I), ("output_iMCU_row", _U), ("coef_bits", _P),
        ("quant_tbl_ptrs", _P * 4), ("dc_huff_tbl_ptrs", _P * 4),
        ("ac_huff_tbl_ptrs", _P * 4), ("data_precision", _I), ("comp_info", _P),
        ("progressive_mode", _I), ("arith_code", _I), ("arith_dc_L", _B * 16),
        ("arith_dc_U", _B * 16), ("arith_ac_K", _B * 16), ("restart_interval", _U),
        ("saw_JFIF_marker", _I), ("JFIF_major_version", _B), ("JFIF_minor_version", _B),
        ("density_unit", _B), ("X_density", ctypes.c_ushort),
        ("Y_density", ctypes.c_ushort), ("saw_Adobe_marker", _I), ("Adobe_transform", _B),
        ("CCIR601_sampling", _I), ("marker_list", _P), ("max_h_samp_factor", _I),
        ("max_v_samp_factor", _I), ("min_DCT_scaled_size", _I), ("total_iMCU_rows", _U),
        ("sample_range_limit", _P), ("comps_in_scan", _I), ("cur_comp_info", _P * 4),
        ("MCUs_per_row", _U), ("MCU_rows_in_scan", _U), ("blocks_in_MCU", _I),
        ("MCU_membership", _I * 10), ("Ss", _I), ("Se", _I), ("Ah", _I), ("Al", _I),
        ("unread_marker", _I), ("master", _P), ("main", _P), ("coef", _P), ("post", _P),
        ("inputctl", _P), ("marker", _P), ("entropy", _P), ("idct", _P),
        ("upsample", _P), ("cconvert", _P), ("cquantize", _P),
    ]  # fmt: skip


_EXIT = ctypes.CFUNCTYPE(None, _P)
_SILENT = ctypes.CFUNCTYPE(None, _P)
_local = threading.local()  # each thread's decompressor (libjpeg's objects are not shared)


errors_caught = 0  # libjpeg errors its handler saw (none for a header plain_header passed)


def _error_exit(cinfo: Any) -> None:
    global errors_caught
    errors_caught += 1
    _local.failed = True


def _silent(cinfo: Any) -> None:
    pass


_error_exit_c = _EXIT(_error_exit)
_silent_c = _SILENT(_silent)


@dataclass(frozen=True)
class Header:
    """What decoding needs from a JPEG's header: its size (px) and the height of its iMCU
    rows (8 times Y's vertical sampling factor)."""

    width: int
    height: int
    imcu_rows: int


def _load() -> tuple[ctypes.CDLL | None, str]:
    """(the library, "") or (None, why not)."""
    name = ctypes.util.find_library("jpeg") or "libjpeg.so.62"
    try:
        lib = ctypes.CDLL(name)
    except OSError as e:
        return None, f"no system libjpeg ({e})"
    for fn in ("jpeg_skip_scanlines", "jpeg_crop_scanline", "jpeg_mem_src"):
        if not hasattr(lib, fn):
            return None, f"{name} has no {fn} (not libjpeg-turbo >= 1.5)"
    lib.jpeg_std_error.restype = ctypes.POINTER(_ErrorMgr)
    lib.jpeg_std_error.argtypes = [ctypes.POINTER(_ErrorMgr)]
    lib.jpeg_CreateDecompress.argtypes = [_P, _I, ctypes.c_size_t]
    lib.jpeg_mem_src.argtypes = [_P, ctypes.c_char_p, ctypes.c_ulong]
    lib.jpeg_read_header.argtypes = [_P, _I]
    lib.jpeg_start_decompress.argtypes = [_P]
    lib.jpeg_crop_scanline.argtypes = [_P, ctypes.POINTER(_U), ctypes.POINTER(_U)]
    lib.jpeg_skip_scanlines.argtypes = [_P, _U]
    lib.jpeg_skip_scanlines.restype = _U
    lib.jpeg_read_scanlines.argtypes = [_P, _P, _U]
    lib.jpeg_read_scanlines.restype = _U
    lib.jpeg_abort_decompress.argtypes = [_P]
    lib.jpeg_destroy_decompress.argtypes = [_P]
    _lib[0] = lib
    try:
        _decompressor()
    except RuntimeError as e:
        _lib[0] = None
        return None, f"{name}: {e}"
    return lib, ""


class _Decompressor:
    """One thread's libjpeg decompressor, kept from frame to frame."""

    def __init__(self, lib: ctypes.CDLL) -> None:
        self.lib = lib
        self.err = _ErrorMgr()
        lib.jpeg_std_error(ctypes.byref(self.err))
        self.err.error_exit = ctypes.cast(_error_exit_c, _P).value
        self.err.output_message = ctypes.cast(_silent_c, _P).value
        # room beyond the struct: libjpeg clears its own size of it before checking ours
        self.raw = ctypes.create_string_buffer(ctypes.sizeof(_Decompress) + 4096)
        self.cinfo = _Decompress.from_buffer(self.raw)
        self.cinfo.err = ctypes.pointer(self.err)
        self.ptr = ctypes.addressof(self.cinfo)
        _local.failed = False
        lib.jpeg_CreateDecompress(self.ptr, _LIB_VERSION, ctypes.sizeof(_Decompress))
        if _local.failed:
            parm = self.err.msg_parm
            raise RuntimeError(
                f"libjpeg refused the decompressor (error {self.err.msg_code}: "
                f"{parm[0]} against {parm[1]}; not the JPEG_LIB_VERSION 62 layout)"
            )

    def __del__(self) -> None:
        self.lib.jpeg_destroy_decompress(self.ptr)


_lib: list[ctypes.CDLL | None] = [None]


def _decompressor() -> _Decompressor:
    d: _Decompressor | None = getattr(_local, "decompressor", None)
    if d is None:
        lib = _lib[0]
        if lib is None:
            raise RuntimeError("no libjpeg")
        d = _Decompressor(lib)
        _local.decompressor = d
    return d


_LOADED = _load()


def available() -> bool:
    """Whether partial decoding is possible here (the system libjpeg-turbo loads)."""
    return _LOADED[0] is not None


def why_unavailable() -> str:
    """Why :func:`available` is False ("" when it is not)."""
    return _LOADED[1]


_SEGMENT = frozenset((0xC4, 0xDB, 0xDD, 0xFE, *range(0xE0, 0xF0)))  # DHT DQT DRI COM APPn


def plain_header(jpeg: bytes) -> Header | None:
    """The header of a JPEG this module decodes (see the module docstring), None for
    any other (or damaged) one: then it is not given to libjpeg."""
    n = len(jpeg)
    if n < 4 or jpeg[0] != 0xFF or jpeg[1] != 0xD8:
        return None
    quant = [False] * 4
    dc = [True, True, False, False]  # libjpeg-turbo's standard tables fill 0 and 1
    ac = [True, True, False, False]
    frame: tuple[int, int, dict[int, int], int] | None = None  # w, h, id -> quant, Y's v
    i = 2
    while i + 4 <= n:
        if jpeg[i] != 0xFF:
            return None
        marker = jpeg[i + 1]
        if marker == 0xFF:  # fill byte
            i += 1
            continue
        length = (jpeg[i + 2] << 8) | jpeg[i + 3]
        body, end = i + 4, i + 2 + length
        if length < 2 or end > n:
            return None
        if marker in (0xC0, 0xC1):  # SOF0, SOF1
            if frame is not None:
                return None
            frame = _frame(jpeg, body, end)
            if frame is None:
                return None
        elif marker == 0xDA:  # SOS
            if frame is None or not _scan(jpeg, body, end, frame[2], quant, dc, ac):
                return None
            return Header(frame[0], frame[1], 8 * frame[3])
        elif marker == 0xDB and not _dqt(jpeg, body, end, quant):
            return None
        elif marker == 0xC4 and not _dht(jpeg, body, end, dc, ac):
            return None
        elif marker == 0xDD and length != 4:
            return None
        elif marker not in _SEGMENT and marker not in (0xC0, 0xC1):
            return None
        i = end
    return None


def _frame(jpeg: bytes, i: int, end: int) -> tuple[int, int, dict[int, int], int] | None:
    """A SOF0/SOF1 segment's body [i, end): (width, height, component id -> its quant
    table, Y's vertical sampling) when libjpeg accepts it and this module decodes it."""
    if end - i != 15 or jpeg[i] != 8 or jpeg[i + 5] != 3:
        return None
    height = (jpeg[i + 1] << 8) | jpeg[i + 2]
    width = (jpeg[i + 3] << 8) | jpeg[i + 4]
    if not (0 < width <= _MAX_DIMENSION and 0 < height <= _MAX_DIMENSION):
        return None
    tables: dict[int, int] = {}
    v_y = 0
    for k in range(3):
        cid, hv, tq = jpeg[i + 6 + 3 * k], jpeg[i + 7 + 3 * k], jpeg[i + 8 + 3 * k]
        if cid in tables or tq > 3:
            return None
        if k == 0:
            if hv not in (0x11, 0x21, 0x22):
                return None
            v_y = hv & 0x0F
        elif hv != 0x11:
            return None
        tables[cid] = tq
    return width, height, tables, v_y


def _dqt(jpeg: bytes, i: int, end: int, quant: list[bool]) -> bool:
    """A DQT segment's body: whole tables that fill it exactly (marked in ``quant``)."""
    while i < end:
        precision, slot = jpeg[i] >> 4, jpeg[i] & 0x0F
        if precision > 1 or slot > 3:
            return False
        i += 1 + 64 * (precision + 1)
        quant[slot] = True
    return i == end


def _dht(jpeg: bytes, i: int, end: int, dc: list[bool], ac: list[bool]) -> bool:
    """A DHT segment's body: tables that fill it exactly and that libjpeg's
    ``jpeg_make_d_derived_tbl`` accepts (marked in ``dc`` / ``ac``)."""
    while i < end:
        if i + 17 > end:
            return False
        kind, slot = jpeg[i] >> 4, jpeg[i] & 0x0F
        if kind > 1 or slot > 3:
            return False
        bits = jpeg[i + 1 : i + 17]
        count = sum(bits)
        if count > 256 or i + 17 + count > end:
            return False
        code, longest = 0, max((k + 1 for k, b in enumerate(bits) if b), default=0)
        for size in range(1, longest + 1):
            code += bits[size - 1]
            if code >= 1 << size:
                return False
            code <<= 1
        if kind == 0 and any(v > 15 for v in jpeg[i + 17 : i + 17 + count]):
            return False
        (ac if kind else dc)[slot] = True
        i += 17 + count
    return i == end


def _scan(
    jpeg: bytes, i: int, end: int, tables: dict[int, int], quant: list[bool],
    dc: list[bool], ac: list[bool],
) -> bool:  # fmt: skip
    """A SOS segment's body: one sequential scan of the frame's three components, every
    table it uses defined."""
    if end - i != 10 or jpeg[i] != 3:
        return False
    seen = set()
    for k in range(3):
        cid, tt = jpeg[i + 1 + 2 * k], jpeg[i + 2 + 2 * k]
        if cid not in tables or cid in seen or not quant[tables[cid]]:
            return False
        seen.add(cid)
        td, ta = tt >> 4, tt & 0x0F
        if td > 3 or ta > 3 or not dc[td] or not ac[ta]:
            return False
    return bytes(jpeg[i + 7 : i + 10]) == b"\x00\x3f\x00"


def decode_rows(
    jpeg: bytes, header: Header, rows: np.ndarray, x0: int, x1: int, out: np.ndarray
) -> bool:
    """Decode into ``out`` ((H,W,3) BGR uint8, C-contiguous, of ``header``'s size) the
    pixels of ``jpeg`` in the rows ``rows`` ((H,) bool) and columns [``x0``, ``x1``):
    those are the whole decode's; the others are left as they were (some hold the
    decode too). ``header``: :func:`plain_header`'s of these bytes. False when libjpeg
    warned (damage, truncation) or failed: decode the frame whole then."""
    d = _decompressor()
    lib, ptr, cinfo = d.lib, d.ptr, d.cinfo
    H, W = header.height, header.width
    step = header.imcu_rows
    # whole iMCU rows: the rows of one are decoded together anyway
    blocks = np.flatnonzero(np.add.reduceat(rows, np.arange(0, H, step)))
    if blocks.size == 0:
        return True
    _local.failed = False
    d.err.num_warnings = 0
    lib.jpeg_mem_src(ptr, jpeg, len(jpeg))
    try:
        if lib.jpeg_read_header(ptr, 1) != 1 or _local.failed:
            return False
        if (
            cinfo.jpeg_color_space != _JCS_YCBCR
            or (cinfo.image_width, cinfo.image_height) != (W, H)
            or cinfo.progressive_mode
        ):
            return False
        cinfo.out_color_space = _JCS_EXT_BGR
        lib.jpeg_start_decompress(ptr)
        if _local.failed or cinfo.output_components != 3:
            return False
        lo = min(max(0, x0 - 2), W - 1)
        hi = max(min(W, x1 + 2), lo + 1)
        if lo > 0 or hi < W:
            xoff, width = _U(lo), _U(hi - lo)
            lib.jpeg_crop_scanline(ptr, ctypes.byref(xoff), ctypes.byref(width))
            lo = xoff.value
        pointers = out.ctypes.data + lo * 3 + np.arange(H, dtype=np.uint64) * (W * 3)
        base = pointers.ctypes.data
        # runs of iMCU rows: [start, stop) in rows
        starts = blocks[np.r_[True, np.diff(blocks) > 1]] * step
        stops = np.minimum((blocks[np.r_[np.diff(blocks) > 1, True]] + 1) * step, H)
        for a, b in zip(starts.tolist(), stops.tolist(), strict=True):
            if cinfo.output_scanline < a:
                lib.jpeg_skip_scanlines(ptr, a - cinfo.output_scanline)
            while cinfo.output_scanline < b and not _local.failed:
                y = cinfo.output_scanline
                if lib.jpeg_read_scanlines(ptr, base + 8 * y, b - y) == 0:
                    return False
        return not _local.failed and d.err.num_warnings == 0
    finally:
        lib.jpeg_abort_decompress(ptr)
