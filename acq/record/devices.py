"""``acq devices``: what a rig has attached, and the configuration line for each.

Everything is read from sysfs and the ``/dev`` symlinks udev makes, so it works without
libusb (pyusb is used only where sysfs has no USB tree and pyusb has a backend):

- USB devices (``/sys/bus/usb/devices/*/idVendor`` ...), recognised by vendor and
  product id: Hokuyo scanners (15d1:*), UVC cameras (an interface of class 0x0e),
  USB-serial adapters (FTDI 0403:*, CP210x 10c4:ea60, CH340 1a86:7523, Prolific
  067b:2303), CAN adapters (PEAK 0c72:*, Kvaser 0bfd:*, candleLight 1d50:606f);
- serial ports (pyserial's ``serial.tools.list_ports`` on the real machine) with their
  stable ``/dev/serial/by-id/...`` names;
- V4L2 nodes (``/sys/class/video4linux/video*``) with their ``/dev/v4l/by-id`` names;
- CAN interfaces (``/sys/class/net/*/type`` == 280, ARPHRD_CAN).

:func:`reset` resets a wedged USB device (the USBDEVFS_RESET ioctl on
``/dev/bus/usb/BBB/DDD``), as ``usbreset`` does.
"""

from __future__ import annotations

import errno
import fcntl
import os
import re
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass, field
from typing import Any

from acq import json_text
from acq.errors import AcqError, InputValueError

__all__ = [
    "Found",
    "ResetError",
    "UsbDevice",
    "format_devices",
    "list_devices",
    "reset",
]

USBDEVFS_RESET = 0x5514  # _IO('U', 20), linux/usbdevice_fs.h
ARPHRD_CAN = 280  # /sys/class/net/*/type of a CAN interface
USB_CLASS_VIDEO = 0x0E
USB_CLASS_HUB = 0x09

USB_SERIAL = {  # (vendor, product or None for any) -> chip
    ("0403", None): "FTDI USB-serial",
    ("10c4", "ea60"): "Silicon Labs CP210x USB-serial",
    ("1a86", "7523"): "QinHeng CH340 USB-serial",
    ("067b", "2303"): "Prolific PL2303 USB-serial",
}
USB_CAN = {
    ("0c72", None): "PEAK-System PCAN-USB",
    ("0bfd", None): "Kvaser CAN adapter",
    ("1d50", "606f"): "candleLight / gs_usb CAN adapter",
}

# the order of sections in the text output
KINDS = {
    "scanner": "Scanners",
    "camera": "Cameras",
    "serial": "Serial ports",
    "can": "CAN",
    "onboard-serial": "Onboard serial ports",
    "usb": "Other USB devices",
}
PLUGGABLE = {"scanner", "camera", "serial", "can"}  # what "nothing found" is about


@dataclass(frozen=True)
class UsbDevice:
    """One USB device as sysfs describes it."""

    sysfs: str  # real path of its sysfs directory
    vendor_id: str  # 4 hex digits, lower case
    product_id: str
    busnum: int
    devnum: int
    manufacturer: str = ""
    product: str = ""
    serial: str = ""
    device_class: int = 0
    interface_classes: tuple[int, ...] = ()

    @property
    def usb_id(self) -> str:
        return f"{self.vendor_id}:{self.product_id}"

    @property
    def bus_addr(self) -> str:
        """``BBB:DDD``, what :func:`reset` takes (and ``lsusb`` shows)."""
        return f"{self.busnum:03d}:{self.devnum:03d}"

    @property
    def label(self) -> str:
        text = " ".join(s for s in (self.manufacturer, self.product) if s)
        return text or f"USB device {self.usb_id}"


@dataclass(frozen=True)
class Found:
    """One thing acq can use, and how to configure it."""

    kind: str  # scanner | camera | serial | can | onboard-serial | usb
    name: str  # what it is, for people
    path: str = ""  # what to open: a stable /dev path, a net interface; "" for none
    node: str = ""  # the kernel's name the path resolves to (/dev/ttyACM0, /dev/video0)
    use_as: str = ""  # what acq would use it as
    config: str = ""  # the configuration line to paste ("" where there is none)
    usb_id: str = ""  # vendor:product
    bus_addr: str = ""  # BBB:DDD, for ``acq devices --reset``
    serial: str = ""
    notes: tuple[str, ...] = field(default_factory=tuple)


class ResetError(AcqError):
    """A USB reset that could not be done; the message says why and what to try."""


# --- sysfs helpers ------------------------------------------------------------------------


def _read(path: str) -> str:
    try:
        with open(path, encoding="utf-8", errors="replace") as f:
            return f.read().strip()
    except OSError:
        return ""


def _int(text: str, base: int = 10, default: int = 0) -> int:
    try:
        return int(text, base)
    except ValueError:
        return default


def _usb_devices(sysfs_root: str) -> dict[str, UsbDevice]:
    """USB devices by the real path of their sysfs directory (root hubs and hubs left out)."""
    base = os.path.join(sysfs_root, "bus", "usb", "devices")
    try:
        names = sorted(os.listdir(base))
    except OSError:
        return {}
    found: dict[str, UsbDevice] = {}
    for name in names:
        if ":" in name or name.startswith("usb"):
            continue  # interfaces; root hubs
        d = os.path.realpath(os.path.join(base, name))
        vendor = _read(os.path.join(d, "idVendor")).lower()
        if not vendor:
            continue
        device_class = _int(_read(os.path.join(d, "bDeviceClass")), 16)
        if device_class == USB_CLASS_HUB:
            continue
        classes: list[int] = []
        try:
            entries = sorted(os.listdir(d))
        except OSError:
            entries = []
        for entry in entries:
            if entry.startswith(name + ":"):
                text = _read(os.path.join(d, entry, "bInterfaceClass"))
                if text:
                    classes.append(_int(text, 16))
        found[d] = UsbDevice(
            sysfs=d,
            vendor_id=vendor,
            product_id=_read(os.path.join(d, "idProduct")).lower(),
            busnum=_int(_read(os.path.join(d, "busnum"))),
            devnum=_int(_read(os.path.join(d, "devnum"))),
            manufacturer=_read(os.path.join(d, "manufacturer")),
            product=_read(os.path.join(d, "product")),
            serial=_read(os.path.join(d, "serial")),
            device_class=device_class,
            interface_classes=tuple(classes),
        )
    return found


def _usb_devices_pyusb() -> dict[str, UsbDevice]:
    """USB devices through pyusb (no sysfs USB tree); empty without a libusb backend."""
    try:
        import usb.core

        devices = list(usb.core.find(find_all=True) or [])
    except Exception:  # no backend (libusb missing), no permission
        return {}
    found: dict[str, UsbDevice] = {}
    for dev in devices:
        key = f"pyusb:{dev.bus}:{dev.address}"
        classes: list[int] = []
        try:
            for cfg in dev:
                classes.extend(int(intf.bInterfaceClass) for intf in cfg)
        except Exception:
            pass
        if int(dev.bDeviceClass) == USB_CLASS_HUB:
            continue
        found[key] = UsbDevice(
            sysfs=key,
            vendor_id=f"{dev.idVendor:04x}",
            product_id=f"{dev.idProduct:04x}",
            busnum=int(dev.bus or 0),
            devnum=int(dev.address or 0),
            device_class=int(dev.bDeviceClass),
            interface_classes=tuple(classes),
        )
    return found


def _owner(sysfs_root: str, link: str, usb: dict[str, UsbDevice]) -> UsbDevice | None:
    """The USB device above the sysfs ``device`` link ``link``, if it is on USB."""
    if not os.path.lexists(link):
        return None
    path = os.path.realpath(link)
    stop = os.path.realpath(sysfs_root)
    while path.startswith(stop) and path != stop:
        if path in usb:
            return usb[path]
        path = os.path.dirname(path)
    return None


def _by_id(dev_root: str, subdir: str) -> dict[str, str]:
    """Kernel node name (``ttyACM0``, ``video0``) -> its stable ``/dev/.../by-id`` path."""
    base = os.path.join(dev_root, *subdir.split("/"))
    try:
        names = sorted(os.listdir(base))
    except OSError:
        return {}
    found: dict[str, str] = {}
    for name in names:
        link = os.path.join(base, name)
        try:
            target = os.readlink(link)
        except OSError:
            continue
        node = os.path.basename(os.path.normpath(os.path.join(base, target)))
        # several links can name one node (if00 / port0): keep the first, sorted
        found.setdefault(node, link)
    return found


def _match(table: dict[tuple[str, str | None], str], dev: UsbDevice) -> str | None:
    return table.get((dev.vendor_id, dev.product_id)) or table.get((dev.vendor_id, None))


# --- serial ports ---------------------------------------------------------------------------


@dataclass(frozen=True)
class _Port:
    device: str  # /dev/ttyACM0
    description: str = ""


def _ports_from_sysfs(sysfs_root: str, dev_root: str) -> list[_Port]:
    """Serial ports the way pyserial finds them on Linux, in a given sysfs tree."""
    base = os.path.join(sysfs_root, "class", "tty")
    try:
        names = sorted(os.listdir(base))
    except OSError:
        return []
    ports = []
    for name in names:
        device = os.path.join(base, name, "device")
        if not os.path.lexists(device):
            continue  # virtual terminals, pseudo-terminals
        subsystem = os.path.basename(os.path.realpath(os.path.join(device, "subsystem")))
        if subsystem == "platform":
            continue  # legacy 8250 ports with no hardware behind them
        ports.append(_Port(os.path.join(dev_root, name)))
    return ports


def _ports_from_pyserial() -> list[_Port]:
    from serial.tools import list_ports

    return [
        _Port(p.device, "" if p.description in ("n/a", None) else str(p.description))
        for p in list_ports.comports()
        if p.subsystem != "platform"
    ]


# --- listing ---------------------------------------------------------------------------------


def list_devices(
    sysfs_root: str = "/sys",
    dev_root: str = "/dev",
    *,
    serial_ports: Callable[[], Iterable[Any]] | None = None,
) -> list[Found]:
    """Everything under ``sysfs_root``/``dev_root`` that acq can use, in KINDS order.

    ``serial_ports`` lists the serial ports (objects with ``device`` and optionally
    ``description``); by default pyserial's ``list_ports.comports`` on the real
    ``/sys``, and the same rules applied to ``sysfs_root`` otherwise (for tests).
    """
    usb = _usb_devices(sysfs_root)
    if not usb and sysfs_root == "/sys" and not os.path.isdir("/sys/bus/usb"):
        usb = _usb_devices_pyusb()
    serial_ids = _by_id(dev_root, "serial/by-id")
    v4l_ids = _by_id(dev_root, "v4l/by-id")
    found: list[Found] = []
    claimed: set[str] = set()  # USB devices already described by a node of theirs

    # serial ports: Hokuyo scanners, USB-serial adapters, the rest
    if serial_ports is not None:
        ports = [
            _Port(str(p.device), str(getattr(p, "description", "") or "")) for p in serial_ports()
        ]
    elif sysfs_root == "/sys":
        ports = _ports_from_pyserial()
    else:
        ports = _ports_from_sysfs(sysfs_root, dev_root)
    for port in ports:
        node = os.path.basename(port.device)
        dev = _owner(sysfs_root, os.path.join(sysfs_root, "class", "tty", node, "device"), usb)
        stable = serial_ids.get(node, "")
        path = stable or os.path.join(dev_root, node)
        notes = () if stable else ("no /dev/serial/by-id name: the name may change",)
        if dev is not None:
            claimed.add(dev.sysfs)
        if dev is not None and dev.vendor_id == "15d1":
            found.append(Found(
                "scanner", f"Hokuyo {dev.product or 'scanner'}", path, port.device,
                "hokuyo scanner (SCIP 2.0 over USB)", f"driver: hokuyo, url: {path}",
                dev.usb_id, dev.bus_addr, dev.serial, notes,
            ))  # fmt: skip
        elif dev is not None:
            chip = _match(USB_SERIAL, dev) or dev.label
            found.append(Found(
                "serial", f"{chip} ({dev.label})" if chip != dev.label else chip, path,
                port.device, "serial port: a Hokuyo over RS-232 (driver: hokuyo) or a GNSS "
                "receiver (gnss:, NMEA)", f"url: {path}",
                dev.usb_id, dev.bus_addr, dev.serial, notes,
            ))  # fmt: skip
        else:
            found.append(Found(
                "onboard-serial", port.description or f"serial port {node}", path, port.device,
                "serial port, if a device is wired to it", f"url: {path}",
            ))  # fmt: skip

    # V4L2 nodes
    vbase = os.path.join(sysfs_root, "class", "video4linux")
    try:
        vnames = sorted(os.listdir(vbase), key=lambda n: (len(n), n))
    except OSError:
        vnames = []
    for vname in vnames:
        d = os.path.join(vbase, vname)
        dev = _owner(sysfs_root, os.path.join(d, "device"), usb)
        index = _int(_read(os.path.join(d, "index")))
        if index != 0:
            continue  # a UVC camera's second node carries metadata, not images
        card = _read(os.path.join(d, "name")) or vname
        stable = v4l_ids.get(vname, "")
        node = os.path.join(dev_root, vname)
        path = stable or node
        notes = () if stable else ("no /dev/v4l/by-id name: the number may change",)
        if dev is not None:
            claimed.add(dev.sysfs)
        found.append(Found(
            "camera", card if dev is None else f"{card} ({dev.label})", path, node,
            "v4l2 camera", f"driver: v4l2, source: {path}",
            dev.usb_id if dev else "", dev.bus_addr if dev else "", dev.serial if dev else "",
            notes,
        ))  # fmt: skip

    # CAN interfaces
    nbase = os.path.join(sysfs_root, "class", "net")
    try:
        nets = sorted(os.listdir(nbase))
    except OSError:
        nets = []
    for net in nets:
        if _int(_read(os.path.join(nbase, net, "type")), default=-1) != ARPHRD_CAN:
            continue
        dev = _owner(sysfs_root, os.path.join(nbase, net, "device"), usb)
        state = _read(os.path.join(nbase, net, "operstate"))
        notes = ()
        if state and state != "up":
            notes = (f"{state}: sudo ip link set {net} up type can bitrate 500000",)
        if dev is not None:
            claimed.add(dev.sysfs)
        label = (_match(USB_CAN, dev) or dev.label) if dev is not None else "CAN interface"
        found.append(Found(
            "can", f"{label} ({net})", net, net, "CAN bus (python-can socketcan)",
            f"can: {{interface: socketcan, channel: {net}}}",
            dev.usb_id if dev else "", dev.bus_addr if dev else "", dev.serial if dev else "",
            notes,
        ))  # fmt: skip

    # USB devices with no node of theirs found above
    for dev in usb.values():
        if dev.sysfs in claimed:
            continue
        can = _match(USB_CAN, dev)
        adapter = _match(USB_SERIAL, dev)
        if dev.vendor_id == "15d1":
            found.append(Found(
                "scanner", f"Hokuyo {dev.product or 'scanner'}", "", "",
                "hokuyo scanner", "", dev.usb_id, dev.bus_addr, dev.serial,
                ("no serial node: is the cdc_acm module loaded?",),
            ))  # fmt: skip
        elif dev.vendor_id == "19a2":
            found.append(Found(
                "scanner", f"SICK {dev.product or 'scanner'}", "", "",
                "sick scanner: acq talks to it over Ethernet", "driver: sick, url: "
                "tcp://<its IP>:2112", dev.usb_id, dev.bus_addr, dev.serial,
            ))  # fmt: skip
        elif USB_CLASS_VIDEO in dev.interface_classes:
            found.append(Found(
                "camera", f"UVC camera {dev.label}", "", "", "v4l2 camera", "",
                dev.usb_id, dev.bus_addr, dev.serial,
                ("no /dev/video node: is the uvcvideo module loaded?",),
            ))  # fmt: skip
        elif can:
            found.append(Found(
                "can", can, "", "", "CAN bus", "", dev.usb_id, dev.bus_addr, dev.serial,
                ("no CAN interface: load its kernel driver (peak_usb, kvaser_usb, gs_usb), "
                 "then use can: {interface: socketcan, channel: can0}",),
            ))  # fmt: skip
        elif adapter:
            found.append(Found(
                "serial", adapter, "", "", "serial port", "", dev.usb_id, dev.bus_addr, dev.serial,
                ("no tty node: is its kernel module (ftdi_sio, cp210x, ch341, pl2303) loaded?",),
            ))  # fmt: skip
        else:
            found.append(Found("usb", dev.label, usb_id=dev.usb_id, bus_addr=dev.bus_addr,
                               serial=dev.serial))  # fmt: skip
    order = list(KINDS)
    return sorted(found, key=lambda f: order.index(f.kind))


NOTHING_FOUND = "No scanners, cameras, USB serial adapters or CAN interfaces found."


def format_devices(found: list[Found]) -> str:
    """The listing as text: one section per kind, each device with its config line."""
    lines: list[str] = []
    if not any(f.kind in PLUGGABLE for f in found):
        lines.append(NOTHING_FOUND)
    for kind, title in KINDS.items():
        items = [f for f in found if f.kind == kind]
        if not items:
            continue
        if lines:
            lines.append("")
        lines.append(f"{title}:")
        for f in items:
            ids = ", ".join(
                s
                for s in (
                    f.usb_id,
                    f"usb {f.bus_addr}" if f.bus_addr else "",
                    f"serial {f.serial}" if f.serial else "",
                )
                if s
            )
            lines.append(f"  {f.name}" + (f"  [{ids}]" if ids else ""))
            if f.path:
                lines.append(
                    f"    {f.path}" + (f" -> {f.node}" if f.node and f.node != f.path else "")
                )
            if f.use_as:
                lines.append(f"    use as: {f.use_as}")
            if f.config:
                lines.append(f"    config: {f.config}")
            lines.extend(f"    note: {n}" for n in f.notes)
    return "\n".join(lines)


def devices_json(found: list[Found]) -> str:
    """The listing as JSON: ``{"devices": [...], "nothing_found": bool}``."""
    return json_text.dumps(
        {
            "devices": [asdict(f) for f in found],
            "nothing_found": not any(f.kind in PLUGGABLE for f in found),
        },
        indent=2,
    )


# --- reset -----------------------------------------------------------------------------------


def parse_bus_addr(text: str) -> tuple[int, int]:
    """``'001:004'`` or ``'1:4'`` -> (1, 4); InputValueError naming the expected form."""
    m = re.fullmatch(r"\s*(\d{1,3})[:/.](\d{1,3})\s*", text)
    if not m or not (1 <= int(m.group(1)) <= 255 and 1 <= int(m.group(2)) <= 127):
        raise InputValueError(f"bad USB address {text!r}: expected BUS:ADDR, e.g. 001:004")
    return int(m.group(1)), int(m.group(2))


def reset(bus_addr: str, dev_root: str = "/dev") -> str:
    """Reset the USB device at ``BUS:ADDR`` (as if re-plugged); returns what was reset.

    Raises InputValueError for a malformed address and ResetError when the device is absent,
    not accessible, or refuses the reset.
    """
    bus, addr = parse_bus_addr(bus_addr)
    usbfs = os.path.join(dev_root, "bus", "usb")
    node = os.path.join(usbfs, f"{bus:03d}", f"{addr:03d}")
    if not os.path.isdir(usbfs) and dev_root == "/dev":
        return _reset_pyusb(bus, addr)
    if not os.path.exists(node):
        raise ResetError(
            f"no USB device at bus {bus:03d} address {addr:03d} ({node} does not exist); "
            "`acq devices` lists the attached devices with their BUS:ADDR"
        )
    try:
        fd = os.open(node, os.O_WRONLY | os.O_CLOEXEC)
    except PermissionError:
        raise ResetError(
            f"permission denied opening {node}: run as root, or install systemd/99-acq.rules "
            "so the rig's devices belong to your group"
        ) from None
    except OSError as e:
        raise ResetError(f"cannot open {node}: {os.strerror(e.errno or 0)}") from e
    try:
        fcntl.ioctl(fd, USBDEVFS_RESET, 0)
    except OSError as e:
        if e.errno == errno.ENOTTY:
            raise ResetError(f"{node} is not a USB device node") from e
        raise ResetError(
            f"USB reset of {bus:03d}:{addr:03d} failed: {os.strerror(e.errno or 0)}"
        ) from e
    finally:
        os.close(fd)
    return f"{bus:03d}:{addr:03d}"


def _reset_pyusb(bus: int, addr: int) -> str:
    """Reset through pyusb, where there is no usbfs (needs libusb)."""
    try:
        import usb.core

        dev = usb.core.find(bus=bus, address=addr)
    except Exception as e:  # usb.core.NoBackendError and friends
        raise ResetError(
            f"no /dev/bus/usb here and pyusb cannot help ({e}); install libusb-1.0"
        ) from e
    if dev is None:
        raise ResetError(f"no USB device at bus {bus:03d} address {addr:03d}")
    try:
        dev.reset()
    except Exception as e:
        raise ResetError(f"USB reset of {bus:03d}:{addr:03d} failed: {e}") from e
    return f"{bus:03d}:{addr:03d}"
