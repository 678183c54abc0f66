"""``acq devices`` against a fake sysfs and /dev tree, and on this (device-less) machine.

The fake tree is laid out as the kernel and udev lay out the real one: devices under
``sys/devices/...``, ``sys/bus/usb/devices/*`` and ``sys/class/*/*/device`` as symlinks
to them, and the ``dev/serial/by-id``, ``dev/v4l/by-id`` links udev makes.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from types import SimpleNamespace

import pytest

from acq.record.devices import (
    NOTHING_FOUND,
    ResetError,
    format_devices,
    list_devices,
    parse_bus_addr,
    reset,
)
from tests.cli_calls import devices

PCI = "devices/pci0000:00/0000:00:14.0/usb1"


def _write(path: Path, **files: str) -> None:
    path.mkdir(parents=True, exist_ok=True)
    for name, text in files.items():
        (path / name).write_text(text + "\n")


def _link(link: Path, target: Path) -> None:
    link.parent.mkdir(parents=True, exist_ok=True)
    link.symlink_to(os.path.relpath(target, link.parent))


def usb_device(
    sys: Path, name: str, vid: str, pid: str, devnum: int, interfaces: dict[str, str],
    *, product: str = "", manufacturer: str = "", serial: str = "", device_class: str = "00",
) -> Path:  # fmt: skip
    d = sys / PCI / name
    files = {"idVendor": vid, "idProduct": pid, "busnum": "1", "devnum": str(devnum)}
    files["bDeviceClass"] = device_class
    if product:
        files["product"] = product
    if manufacturer:
        files["manufacturer"] = manufacturer
    if serial:
        files["serial"] = serial
    _write(d, **files)
    _link(sys / "bus/usb/devices" / name, d)
    for intf, cls in interfaces.items():
        _write(d / f"{name}:{intf}", bInterfaceClass=cls)
        _link(sys / "bus/usb/devices" / f"{name}:{intf}", d / f"{name}:{intf}")
    return d


@pytest.fixture
def rig(tmp_path: Path) -> tuple[str, str]:
    """A vehicle PC with a Hokuyo, a UVC camera, an FTDI cable, a candleLight, a PEAK
    adapter without its driver, a hub, a keyboard and two onboard UARTs."""
    sys, dev = tmp_path / "sys", tmp_path / "dev"
    _write(sys / "devices/pci0000:00/0000:00:14.0/usb1", idVendor="1d6b", idProduct="0002")
    _link(sys / "bus/usb/devices/usb1", sys / PCI)  # root hub: left out

    hokuyo = usb_device(sys, "1-1", "15d1", "0000", 4, {"1.0": "02", "1.1": "0a"},
                        manufacturer="Hokuyo Data Flex for USB",
                        product="URG-Series USB Driver", device_class="02")  # fmt: skip
    (hokuyo / "1-1:1.0/tty/ttyACM0").mkdir(parents=True)
    _link(sys / "class/tty/ttyACM0/device", hokuyo / "1-1:1.0")

    cam = usb_device(sys, "1-2", "32e4", "9230", 5, {"1.0": "0e", "1.1": "0e", "1.2": "01"},
                     manufacturer="Sonix", product="HD USB Camera", serial="SN0001",
                     device_class="ef")  # fmt: skip
    for n in (0, 1):
        v = sys / "class/video4linux" / f"video{n}"
        _write(v, name="HD USB Camera: HD USB Camera", index=str(n))
        _link(v / "device", cam / "1-2:1.0")

    ftdi = usb_device(sys, "1-3", "0403", "6001", 6, {"1.0": "ff"},
                      manufacturer="FTDI", product="FT232R USB UART", serial="A1B2C3")  # fmt: skip
    (ftdi / "1-3:1.0/ttyUSB0").mkdir(parents=True)
    _link(sys / "class/tty/ttyUSB0/device", ftdi / "1-3:1.0/ttyUSB0")

    candle = usb_device(sys, "1-4", "1d50", "606f", 7, {"1.0": "ff"},
                        manufacturer="bytewerk", product="candleLight USB to CAN adapter",
                        serial="0042")  # fmt: skip
    _write(sys / "class/net/can0", type="280", operstate="down")
    _link(sys / "class/net/can0/device", candle / "1-4:1.0")
    _write(sys / "class/net/eth0", type="1", operstate="up")

    usb_device(sys, "1-5", "0c72", "000c", 8, {"1.0": "00"}, product="PCAN-USB")
    usb_device(sys, "1-6", "05e3", "0610", 9, {"1.0": "09"}, device_class="09")  # a hub
    usb_device(sys, "1-7", "046d", "c31c", 10, {"1.0": "03"}, manufacturer="Logitech",
               product="USB Keyboard")  # fmt: skip

    # onboard UARTs: a real one (pnp) and a phantom 8250 port (platform)
    _write(sys / "devices/pnp0/00:01")
    _link(sys / "devices/pnp0/00:01/subsystem", sys / "bus/pnp")
    _link(sys / "class/tty/ttyS0/device", sys / "devices/pnp0/00:01")
    _write(sys / "devices/platform/serial8250")
    _link(sys / "devices/platform/serial8250/subsystem", sys / "bus/platform")
    _link(sys / "class/tty/ttyS1/device", sys / "devices/platform/serial8250")
    _write(sys / "class/tty/tty0")  # a virtual terminal: no device link

    _link(dev / "serial/by-id/usb-Hokuyo_Data_Flex_for_USB_URG-Series_USB_Driver-if00",
          dev / "ttyACM0")  # fmt: skip
    _link(dev / "serial/by-id/usb-FTDI_FT232R_USB_UART_A1B2C3-if00-port0", dev / "ttyUSB0")
    _link(dev / "v4l/by-id/usb-Sonix_HD_USB_Camera_SN0001-video-index0", dev / "video0")
    _link(dev / "v4l/by-id/usb-Sonix_HD_USB_Camera_SN0001-video-index1", dev / "video1")
    _write(dev / "bus/usb/001")
    return str(sys), str(dev)


def test_a_rig_is_listed_with_its_config_lines(rig: tuple[str, str]) -> None:
    sys, dev = rig
    found = list_devices(sys, dev)
    by = {(f.kind, f.usb_id): f for f in found}
    kinds = [f.kind for f in found]
    assert kinds == sorted(kinds, key=["scanner", "camera", "serial", "can",
                                       "onboard-serial", "usb"].index)  # fmt: skip

    hokuyo = by["scanner", "15d1:0000"]
    path = f"{dev}/serial/by-id/usb-Hokuyo_Data_Flex_for_USB_URG-Series_USB_Driver-if00"
    assert hokuyo.path == path and hokuyo.node == f"{dev}/ttyACM0"
    assert hokuyo.config == f"driver: hokuyo, url: {path}"
    assert hokuyo.bus_addr == "001:004" and hokuyo.name == "Hokuyo URG-Series USB Driver"

    cams = [f for f in found if f.kind == "camera"]
    assert len(cams) == 1  # the metadata node (index 1) is not offered
    cam = cams[0]
    assert (
        cam.config
        == f"driver: v4l2, source: {dev}/v4l/by-id/usb-Sonix_HD_USB_Camera_SN0001-video-index0"
    )
    assert cam.usb_id == "32e4:9230" and cam.serial == "SN0001" and cam.node == f"{dev}/video0"

    ftdi = by["serial", "0403:6001"]
    assert ftdi.config == f"url: {dev}/serial/by-id/usb-FTDI_FT232R_USB_UART_A1B2C3-if00-port0"
    assert ftdi.name.startswith("FTDI USB-serial")

    can0 = by["can", "1d50:606f"]
    assert can0.config == "can: {interface: socketcan, channel: can0}"
    assert any("ip link set can0 up" in n for n in can0.notes)
    peak = by["can", "0c72:000c"]
    assert peak.config == "" and "peak_usb" in peak.notes[0]

    onboard = [f for f in found if f.kind == "onboard-serial"]
    assert [f.path for f in onboard] == [f"{dev}/ttyS0"]  # ttyS1 is a phantom 8250 port
    others = [f for f in found if f.kind == "usb"]
    assert [f.usb_id for f in others] == ["046d:c31c"]  # the hub and root hub left out

    text = format_devices(found)
    assert NOTHING_FOUND not in text
    assert f"    config: driver: hokuyo, url: {path}" in text
    assert "Hokuyo URG-Series USB Driver  [15d1:0000, usb 001:004]" in text
    assert f"{path} -> {dev}/ttyACM0" in text
    assert "config: can: {interface: socketcan, channel: can0}" in text
    for title in ("Scanners:", "Cameras:", "Serial ports:", "CAN:", "Other USB devices:"):
        assert title in text


def test_json_form(rig: tuple[str, str], capsys: pytest.CaptureFixture[str]) -> None:
    sys, dev = rig
    assert devices(True, None, sysfs_root=sys, dev_root=dev) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["nothing_found"] is False
    kinds = {d["kind"] for d in out["devices"]}
    assert {"scanner", "camera", "serial", "can"} <= kinds
    scanner = next(d for d in out["devices"] if d["kind"] == "scanner")
    assert scanner["config"].startswith("driver: hokuyo, url: ")


def test_without_by_id_links_the_kernel_name_is_used_and_flagged(rig: tuple[str, str]) -> None:
    sys, dev = rig
    for sub in ("serial/by-id", "v4l/by-id"):
        for link in Path(dev, sub).iterdir():
            link.unlink()
    found = list_devices(sys, dev)
    hokuyo = next(f for f in found if f.kind == "scanner")
    assert hokuyo.config == f"driver: hokuyo, url: {dev}/ttyACM0"
    assert "may change" in hokuyo.notes[0]
    cam = next(f for f in found if f.kind == "camera")
    assert cam.config == f"driver: v4l2, source: {dev}/video0"


def test_a_hokuyo_without_its_serial_node_is_still_named(tmp_path: Path) -> None:
    sys = tmp_path / "sys"
    usb_device(sys, "2-1", "15d1", "0000", 3, {"1.0": "02"}, product="URG-Series USB Driver")
    found = list_devices(str(sys), str(tmp_path / "dev"))
    assert [(f.kind, f.config) for f in found] == [("scanner", "")]
    assert "cdc_acm" in found[0].notes[0]


def test_serial_ports_can_come_from_pyserial(rig: tuple[str, str]) -> None:
    sys, dev = rig
    ports = [SimpleNamespace(device=f"{dev}/ttyUSB0", description="FT232R USB UART")]
    found = list_devices(sys, dev, serial_ports=lambda: ports)
    serial = [f for f in found if f.kind in ("serial", "onboard-serial")]
    assert [f.usb_id for f in serial] == ["0403:6001"]
    # the Hokuyo was not among the ports: still listed from its USB device
    assert next(f for f in found if f.kind == "scanner").config == ""


def test_an_empty_machine_says_so(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert format_devices(list_devices(str(tmp_path / "sys"), str(tmp_path / "dev"))) == (
        NOTHING_FOUND
    )
    assert devices(False, None, sysfs_root=str(tmp_path), dev_root=str(tmp_path)) == 0
    assert capsys.readouterr().out.strip() == NOTHING_FOUND


def test_this_machine(capsys: pytest.CaptureFixture[str]) -> None:
    """The test machine has no scanner, camera, USB serial or CAN device attached."""
    found = list_devices()
    if any(f.kind in ("scanner", "camera", "serial", "can") for f in found):
        pytest.skip("this machine has devices attached")
    assert format_devices(found).startswith(NOTHING_FOUND)
    assert devices(False, None) == 0
    assert capsys.readouterr().out.startswith(NOTHING_FOUND)


# --- reset -----------------------------------------------------------------------------------


def test_bus_addr_forms() -> None:
    assert parse_bus_addr("001:004") == (1, 4)
    assert parse_bus_addr("3:17") == (3, 17)
    for bad in ("", "1", "1:4:5", "x:y", "0:4", "1:200"):
        with pytest.raises(ValueError, match="expected BUS:ADDR"):
            parse_bus_addr(bad)


def test_reset_of_a_missing_device_is_a_clear_error(rig: tuple[str, str]) -> None:
    _, dev = rig
    with pytest.raises(ResetError, match=r"no USB device at bus 001 address 099 .*acq devices"):
        reset("1:99", dev)


def test_reset_of_something_that_is_not_usbfs(tmp_path: Path) -> None:
    node = tmp_path / "bus/usb/001/004"
    node.parent.mkdir(parents=True)
    node.write_bytes(b"")
    with pytest.raises(ResetError, match="not a USB device node"):
        reset("001:004", str(tmp_path))


def test_main_devices_reset_exit_codes(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "bus/usb").mkdir(parents=True)
    assert devices(False, "1:4", dev_root=str(tmp_path)) == 1
    assert "no USB device at bus 001 address 004" in capsys.readouterr().err
    assert devices(False, "bogus", dev_root=str(tmp_path)) == 2
    assert "expected BUS:ADDR" in capsys.readouterr().err


def test_reset_on_this_machine_fails_clearly(capsys: pytest.CaptureFixture[str]) -> None:
    """No /dev/bus/usb/001/099 here (and no libusb): one clear line, exit 1."""
    if os.path.exists("/dev/bus/usb/001/099"):
        pytest.skip("a device sits at 001:099")
    assert devices(False, "001:099") == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("acq devices: ") and "\n" not in err
