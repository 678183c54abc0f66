"""The recorder's configuration: shipped files load, bad files say where in one line."""

from __future__ import annotations

import copy
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from acq.record import config
from acq.record.config import CameraConfig, Config, ConfigError, ScannerConfig

ROOT = Path(__file__).resolve().parents[2]
SHIPPED = ["sim.yaml", "utm30lx.yaml", "lms111.yaml", "vehicle_example.yaml"]

GOOD: dict[str, Any] = {
    "version": 1,
    "scanners": [
        {"name": "laser", "driver": "hokuyo", "url": "socket://127.0.0.1:10940", "latency_s": 0.0}
    ],
    "cameras": [
        {
            "name": "camera",
            "driver": "opencv",
            "source": "http://127.0.0.1:8080/stream.mjpg",
            "fps": 25,
            "latency_s": 0.0,
        }
    ],
    "calibration": "calib.yaml",
    "output": {"dir": "./logs", "split_minutes": 10},
}


def error_of(data: Any, source: str = "rig.yaml") -> str:
    with pytest.raises(ConfigError) as info:
        config.parse(data, source)
    text = str(info.value)
    assert "\n" not in text
    return text


def changed(change: Callable[[dict[str, Any]], object]) -> dict[str, Any]:
    data = copy.deepcopy(GOOD)
    change(data)
    return data


def write(tmp_path: Path, text: str, name: str = "rig.yaml") -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


# --- the shipped files ---------------------------------------------------------------------


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_configs_load(name: str) -> None:
    path = config.shipped(name)  # package data, the repository's config/ folder
    assert path == ROOT / "config" / name
    cfg = config.load(path)
    assert cfg.source == path
    assert cfg.devices() == ["laser", "camera"]
    calib = "sim_calib.yaml" if name == config.DEFAULT else "calib.yaml"
    assert cfg.calibration == ROOT / "config" / calib
    assert cfg.output.dir.is_absolute()


def test_the_default_records_the_simulated_rigs_true_calibration() -> None:
    from acq.camera import calibfile
    from acq.sim.demo_rig import true_calibration
    from acq.sim.world import default_rig

    cfg = config.load(config.shipped())
    assert cfg.calibration is not None
    shipped, truth = calibfile.load(cfg.calibration), true_calibration(default_rig())
    assert shipped.cameras.keys() == truth.cameras.keys()
    for name, cam in truth.cameras.items():
        assert shipped.cameras[name].model == cam.model
        for a, b in ((shipped.cameras[name].camera_to_laser, cam.camera_to_laser),
                     (shipped.laser_to_vehicle, truth.laser_to_vehicle)):  # fmt: skip
            assert a is not None and b is not None
            np.testing.assert_allclose(a.rotation, b.rotation, atol=1e-12)
            np.testing.assert_allclose(a.translation, b.translation, atol=1e-12)


def test_sim_is_the_simulated_rig() -> None:
    cfg = config.load(config.shipped())
    (laser,) = cfg.scanners
    (camera,) = cfg.cameras
    assert (laser.driver, laser.url, laser.protocol) == ("hokuyo", "socket://127.0.0.1:10940", None)
    assert (camera.driver, camera.source) == ("opencv", "http://127.0.0.1:8080/stream.mjpg")
    assert cfg.output.dir == ROOT / "config" / "logs"
    assert cfg.output.split_minutes == 10 and cfg.output.reserve_megabytes == 512


def test_scanner_latency_is_measured_unless_configured() -> None:
    # every scanner driver measures it: SCIP with TM round trips, SICK from its telegrams
    cfg = config.load(config.shipped())
    assert cfg.scanners[0].latency_s == "auto"
    for driver, url in (("hokuyo", "socket://h:10940"), ("sick", "tcp://h:2112")):
        plain = {"name": "laser", "driver": driver, "url": url}
        assert config.ScannerConfig.model_validate(plain).latency_s == "auto"
        given = config.ScannerConfig.model_validate(plain | {"latency_s": 0.004})
        assert given.latency_s == 0.004


def test_real_rig_examples() -> None:
    utm = config.load(ROOT / "config" / "utm30lx.yaml")
    assert utm.scanners[0].latency_s == "auto"
    assert utm.scanners[0].url.startswith("/dev/serial/by-id/")
    assert utm.scanners[0].options["intensity"] is True
    assert utm.cameras[0].driver == "v4l2" and utm.cameras[0].fps == 25
    lms = config.load(ROOT / "config" / "lms111.yaml")
    assert (lms.scanners[0].driver, lms.scanners[0].protocol) == ("sick", "cola-b")
    assert lms.scanners[0].latency_s == "auto"
    assert lms.scanners[0].url == "tcp://192.168.0.1:2112"


def test_vehicle_example() -> None:
    cfg = config.load(ROOT / "config" / "vehicle_example.yaml")
    assert cfg.can is not None and cfg.gnss is not None
    assert (cfg.can.interface, cfg.can.channel) == ("socketcan", "can0")
    assert cfg.can.dbc == ROOT / "sim" / "vehicle.dbc" and cfg.can.dbc.is_file()
    assert cfg.can.wheel_speeds[3] == "WHEEL_SPEEDS.WHEEL_SPEED_RR" and cfg.can.speed is None
    assert cfg.gnss.url.startswith("/dev/serial/by-id/") and cfg.gnss.baudrate == 115200
    assert (cfg.gnss.time, cfg.gnss.latency_s) == ("auto", 0.0)
    assert config.parse(yaml.safe_load(config.dump(cfg)), "dumped") == cfg.model_copy(
        update={"source": None}
    )


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (
            {"interface": "socketcn"},
            "rig.yaml: can.interface: unknown python-can interface 'socketcn'; "
            "did you mean socketcan?",
        ),
        (
            {"yaw_rate": "YAW"},
            "rig.yaml: can.yaw_rate: expected MESSAGE.SIGNAL as named in the DBC, got 'YAW'",
        ),
        (
            {"wheel_speeds": ["A.B"]},
            "rig.yaml: can.wheel_speeds: expected 4 signals (front left, front right, "
            "rear left, rear right), got 1",
        ),
        (
            {"wheel_speeds": ["A.B", "A.C", "A.D", "A E"]},
            "rig.yaml: can.wheel_speeds[3]: expected MESSAGE.SIGNAL as named in the DBC, got 'A E'",
        ),
        ({"bitrat": 500000}, "rig.yaml: can.bitrat: unknown key; did you mean bitrate?"),
    ],
)
def test_bad_can_sections(change: dict[str, Any], message: str) -> None:
    can = {"interface": "socketcan", "channel": "can0", "dbc": "car.dbc", **change}
    assert error_of(changed(lambda d: d.update(can=can))) == message


def test_gnss_section_and_reserved_names() -> None:
    gnss = {"url": "tcp://192.168.1.5:2947", "latency_s": 0.05}
    cfg = config.parse(changed(lambda d: d.update(gnss=gnss)))
    assert cfg.gnss is not None and cfg.gnss.url == "socket://192.168.1.5:2947"
    assert cfg.gnss.time == "auto"  # the fix time when the host clock is disciplined
    assert error_of(changed(lambda d: d.update(gnss={"url": "/dev/ttyUSB0", "latency_s": -1}))) == (
        "rig.yaml: gnss.latency_s: must be >= 0, got -1"
    )
    assert error_of(changed(lambda d: d.update(gnss={"url": "/dev/ttyUSB0", "time": "utc"}))) == (
        "rig.yaml: gnss.time: expected one of: auto, fix, receipt, got 'utc'"
    )
    clash = changed(lambda d: d.update(gnss={"url": "/dev/ttyUSB0"}))
    clash["cameras"][0]["name"] = "gnss"
    assert error_of(clash) == (
        "rig.yaml: cameras[0].name: 'gnss' names the gnss section's topics (/gnss/...); "
        "rename this device"
    )


def test_architecture_example_parses(shared_dir: Path) -> None:
    text = (shared_dir / "ARCHITECTURE.md").read_text(encoding="utf-8")
    block = re.search(r"```yaml\n(# config/sim\.yaml.*?)```", text, re.S)
    assert block, "ARCHITECTURE.md has no configuration example"
    cfg = config.parse(yaml.safe_load(block.group(1)), "ARCHITECTURE.md")
    assert cfg.devices() == ["laser", "camera"]


# --- values ----------------------------------------------------------------------------------


def test_defaults_and_normalisation() -> None:
    cfg = config.parse(
        {
            "version": 1,
            "scanners": [
                {"name": "front", "driver": "sick", "url": "tcp://10.0.0.2:2112"},
                {"name": "rear", "driver": "hokuyo", "url": "tcp://10.0.0.3:10940"},
            ],
            "cameras": [{"name": "cam0", "driver": "v4l2", "source": 0}],
        }
    )
    front, rear = cfg.scanners
    assert front.protocol == "cola-b"  # the SICK default
    assert rear.url == "socket://10.0.0.3:10940"  # pyserial's spelling
    assert cfg.cameras[0].source == "0" and cfg.cameras[0].fps == 25.0
    assert cfg.output == config.OutputConfig()
    assert cfg.calibration is None and cfg.can is None and cfg.gnss is None
    assert cfg.source is None
    assert cfg.devices() == ["front", "rear", "cam0"]


def test_options_are_checked_and_kept() -> None:
    cfg = config.parse(
        changed(lambda d: d["scanners"][0].update(options={"intensity": True, "cluster": 2}))
    )
    assert cfg.scanners[0].options == {"intensity": True, "cluster": 2}
    sick = ScannerConfig(
        name="s", driver="sick", url="tcp://h:2112", options={"login": [3, 0xF4724744]}
    )
    assert sick.options == {"login": (3, 0xF4724744)}
    cam = CameraConfig(name="c", driver="v4l2", source="/dev/video0", options={"gain": 4})
    assert cam.options == {"gain": 4}


def test_empty_sections_are_their_defaults(tmp_path: Path) -> None:
    text = (
        "version: 1\n"
        "scanners:\n"
        "  - {name: laser, driver: hokuyo, url: /dev/ttyACM0}\n"
        "cameras:\n"
        "#  - {name: camera, driver: v4l2, source: /dev/video0}\n"
        "output:\n"
    )
    cfg = config.load(write(tmp_path, text))
    assert cfg.cameras == [] and cfg.output.prefix == "acq"
    assert cfg.output.dir == tmp_path / "logs"


def test_models_are_frozen() -> None:
    cfg = config.parse(GOOD)
    with pytest.raises(ValueError):
        cfg.scanners[0].name = "other"


# --- errors: one line, the file, the key path ---------------------------------------------


@pytest.mark.parametrize(
    ("change", "expected"),
    [
        (
            lambda d: d.update(scaners=[]),
            "rig.yaml: scaners: unknown key; did you mean scanners?",
        ),
        (
            lambda d: d["cameras"][0].update(fsp=30),
            "rig.yaml: cameras[0].fsp: unknown key; did you mean fps?",
        ),
        (
            lambda d: d["output"].update(split_minuts=5),
            "rig.yaml: output.split_minuts: unknown key; did you mean split_minutes?",
        ),
        (
            lambda d: d["scanners"][0].update(drivr=d["scanners"][0].pop("driver")),
            "rig.yaml: scanners[0].drivr: unknown key; did you mean driver?",
        ),
        (
            lambda d: d["cameras"][0].update(fps="fast"),
            "rig.yaml: cameras[0].fps: expected a number, got 'fast'",
        ),
        (
            lambda d: d["cameras"][0].update(width=640.5),
            "rig.yaml: cameras[0].width: expected a whole number, got 640.5",
        ),
        (
            lambda d: d["scanners"][0].update(driver="hokuyoo"),
            "rig.yaml: scanners[0].driver: expected one of: hokuyo, sick, got 'hokuyoo'",
        ),
        (
            lambda d: d["output"].update(split_minutes=-1),
            "rig.yaml: output.split_minutes: must be >= 0.01, got -1",
        ),
        (
            lambda d: d["output"].update(reserve_megabytes=-5),
            "rig.yaml: output.reserve_megabytes: must be >= 0, got -5",
        ),
        (
            lambda d: d["cameras"][0].update(latency_s=-0.1),
            "rig.yaml: cameras[0].latency_s: must be >= 0, got -0.1",
        ),
        (
            lambda d: d["scanners"][0].update(latency_s=-0.1),
            "rig.yaml: scanners[0].latency_s: expected a number of seconds 0..10 or auto, got -0.1",
        ),
        (
            lambda d: d["cameras"][0].update(fps=float("inf")),
            "rig.yaml: cameras[0].fps: expected a finite number, got inf",
        ),
        (
            lambda d: d["scanners"][0].pop("url"),
            "rig.yaml: scanners[0].url: required key missing",
        ),
        (lambda d: d.pop("version"), "rig.yaml: version: required key missing"),
        (
            lambda d: d.update(version=2),
            "rig.yaml: version: expected 1 (the version this acq reads), got 2",
        ),
        (
            lambda d: d["cameras"][0].update(name="laser"),
            "rig.yaml: cameras[0].name: 'laser' is already the name of scanners[0]; "
            "device names must be unique",
        ),
        (
            lambda d: d["scanners"][0].update(name="my laser"),
            "rig.yaml: scanners[0].name: expected letters, digits or '_' (it names topics), "
            "got 'my laser'",
        ),
        (
            lambda d: d["scanners"][0].update(options={"intensty": True}),
            "rig.yaml: scanners[0].options.intensty: unknown option of the hokuyo driver; "
            "did you mean intensity?",
        ),
        (
            lambda d: d["scanners"][0].update(options={"cluster": "two"}),
            "rig.yaml: scanners[0].options.cluster: expected a whole number, got 'two'",
        ),
        (
            lambda d: d["scanners"][0].update(options={"protocol": "cola-a"}),
            "rig.yaml: scanners[0].options.protocol: set protocol on the scanner itself, "
            "not under options",
        ),
        (
            lambda d: d["cameras"][0].update(options={"verfy": "decode"}),
            "rig.yaml: cameras[0].options.verfy: unknown option of the opencv driver; "
            "did you mean verify?",
        ),
        (
            lambda d: d["scanners"][0].update(protocol="cola-b"),
            "rig.yaml: scanners[0].protocol: only for driver sick (a hokuyo speaks SCIP); "
            "remove it",
        ),
        (
            lambda d: d["scanners"][0].update(driver="sick", url="http://h:2112"),
            "rig.yaml: scanners[0].url: expected tcp://host:port or host[:port] for driver sick, "
            "got 'http://h:2112'",
        ),
        (
            lambda d: d["scanners"][0].update(url="socket://127.0.0.1"),
            "rig.yaml: scanners[0].url: expected socket://host:port, got 'socket://127.0.0.1'",
        ),
        (
            lambda d: d["cameras"][0].update(fourcc="MJPEG"),
            "rig.yaml: cameras[0].fourcc: expected 4 characters such as MJPG or YUYV, got 'MJPEG'",
        ),
        (
            lambda d: d.update(scanners=[], cameras=[]),
            "rig.yaml: scanners: no device; expected at least one scanner or camera",
        ),
        (
            lambda d: d.update(scanners={"laser": {}}),
            "rig.yaml: scanners: expected a list, got a mapping",
        ),
        (lambda d: d.update(output=[]), "rig.yaml: output: expected a mapping, got a list"),
        (
            lambda d: d.update(can={"interface": "socketcan", "channel": "can0"}),
            "rig.yaml: can.dbc: required key missing",
        ),
        (
            lambda d: d.update(gnss={"url": "/dev/ttyUSB0", "baudrate": 0}),
            "rig.yaml: gnss.baudrate: must be > 0, got 0",
        ),
        (
            lambda d: d.update(source="other.yaml"),
            "rig.yaml: source: unknown key",
        ),
        (lambda d: d.update({3: "x"}), "rig.yaml: 3: expected a string key, got 3"),
    ],
)
def test_errors(change: Callable[[dict[str, Any]], object], expected: str) -> None:
    assert error_of(changed(change)) == expected


def _camera(**entry: Any) -> Callable[[dict[str, Any]], object]:
    return lambda d: d["cameras"][0].update(entry)


def _scanner(**entry: Any) -> Callable[[dict[str, Any]], object]:
    return lambda d: d["scanners"][0].update(entry)


_OPENCV = (
    "expected an index (0), /dev/videoN, a video file, a GStreamer pipeline (with '!') or a "
    "URL (http://, https://, rtsp://, rtsps://, rtmp://, rtmps://, rtp://, udp://, tcp://, "
    "srt://) for driver opencv"
)
_V4L2 = "expected an index (0) or a device path (/dev/videoN, /dev/v4l/by-id/...) for driver v4l2"
_CAN = {"interface": "socketcan", "channel": "can0", "dbc": "car.dbc"}


@pytest.mark.parametrize(
    ("change", "expected"),
    [
        (_scanner(driver="sick", url="socket://10.0.0.2:2112"),
         "rig.yaml: scanners[0].url: expected tcp://host:port or host[:port] for driver sick "
         "(a TCP device); socket:// is a pyserial URL, for serial drivers: write "
         "tcp://10.0.0.2:2112"),
        (_scanner(latency_s=1e300),
         "rig.yaml: scanners[0].latency_s: expected a number of seconds 0..10 or auto, "
         "got 1e+300"),
        (_camera(latency_s=1e6), "rig.yaml: cameras[0].latency_s: must be <= 10, got 1000000.0"),
        (_camera(fps=1e-300), "rig.yaml: cameras[0].fps: must be >= 0.01, got 1e-300"),
        (_camera(fps=1e9), "rig.yaml: cameras[0].fps: must be <= 1000, got 1000000000.0"),
        (_camera(width=10**9), "rig.yaml: cameras[0].width: must be <= 65535, got 1000000000"),
        (lambda d: d["output"].update(split_megabytes=1e308),
         "rig.yaml: output.split_megabytes: must be <= 1e+09, got 1e+308"),
        (lambda d: d["output"].update(split_megabytes=1e-300),
         "rig.yaml: output.split_megabytes: must be >= 1, got 1e-300"),
        (lambda d: d["output"].update(split_minutes=1e-300),
         "rig.yaml: output.split_minutes: must be >= 0.01, got 1e-300"),
        (lambda d: d["output"].update(reserve_megabytes=1e308),
         "rig.yaml: output.reserve_megabytes: must be <= 1e+09, got 1e+308"),
        (lambda d: d.update(gnss={"url": "/dev/ttyUSB0", "baudrate": 10**12}),
         "rig.yaml: gnss.baudrate: must be <= 10000000, got 1000000000000"),
        (lambda d: d.update(gnss={"url": "/dev/ttyUSB0", "latency_s": 1e3}),
         "rig.yaml: gnss.latency_s: must be <= 10, got 1000.0"),
        (lambda d: d.update(can={**_CAN, "bitrate": 10**12}),
         "rig.yaml: can.bitrate: must be <= 10000000, got 1000000000000"),
        (_scanner(options={"timeout": -1}),
         "rig.yaml: scanners[0].options.timeout: must be >= 0.01, got -1"),
        (_scanner(options={"cluster": 0}),
         "rig.yaml: scanners[0].options.cluster: must be >= 1, got 0"),
        (_scanner(driver="sick", url="tcp://h:2112", options={"login": [3, 2**40]}),
         "rig.yaml: scanners[0].options.login[1]: must be <= 4294967295, got 1099511627776"),
        (_camera(driver="v4l2", source="/dev/video0", options={"buffers": 10**6}),
         "rig.yaml: cameras[0].options.buffers: must be <= 32, got 1000000"),
        (_camera(options={"timeout": 1e300}),
         "rig.yaml: cameras[0].options.timeout: must be <= 60, got 1e+300"),
    ],
)  # fmt: skip
def test_sources_and_numbers_out_of_range_name_the_key(
    change: Callable[[dict[str, Any]], object], expected: str
) -> None:
    assert error_of(changed(change)) == expected


def test_a_camera_source_is_what_its_driver_opens() -> None:
    for driver, source in [
        ("opencv", "0"),
        ("opencv", "/dev/video2"),
        ("opencv", "drive/front_%04d.jpg"),
        ("opencv", "rtsp://admin@10.0.0.9:554/stream1"),
        ("opencv", "rtspsrc location=rtsp://10.0.0.9/s ! decodebin ! videoconvert ! appsink"),
        ("v4l2", "2"),
        ("v4l2", "/dev/v4l/by-id/usb-Fisheye_USB_Camera_0001-video-index0"),
    ]:
        cfg = config.parse(changed(_camera(driver=driver, source=source)))
        assert cfg.cameras[0].source == source
    refused = [
        (_camera(source="gopher://cam/stream"),
         f"rig.yaml: cameras[0].source: {_OPENCV}; unknown scheme gopher://"),
        (_camera(source="http:///stream.mjpg"),
         f"rig.yaml: cameras[0].source: {_OPENCV}; no host in 'http:///stream.mjpg'"),
        (_camera(source="http://cam:99999/x"),
         f"rig.yaml: cameras[0].source: {_OPENCV}; a bad host or port in "
         "'http://cam:99999/x'"),
        (_camera(driver="v4l2", source="http://cam/stream"),
         f"rig.yaml: cameras[0].source: {_V4L2}, got 'http://cam/stream'"),
        (_camera(driver="v4l2", source="video0"),
         f"rig.yaml: cameras[0].source: {_V4L2}, got 'video0'"),
    ]  # fmt: skip
    for change, expected in refused:
        assert error_of(changed(change)) == expected


@pytest.mark.parametrize(
    ("data", "expected"),
    [
        (None, "rig.yaml: empty file; expected a mapping with version: 1 and devices"),
        ([1, 2], "rig.yaml: expected a mapping with version: 1 and devices, got a list"),
        ("text", "rig.yaml: expected a mapping with version: 1 and devices, got 'text'"),
    ],
)
def test_not_a_mapping(data: Any, expected: str) -> None:
    assert error_of(data) == expected


def test_load_errors_name_the_file(tmp_path: Path) -> None:
    missing = tmp_path / "nope.yaml"
    with pytest.raises(ConfigError, match=rf"^{re.escape(str(missing))}: no such file$"):
        config.load(missing)
    empty = write(tmp_path, "")
    with pytest.raises(ConfigError, match=rf"^{re.escape(str(empty))}: empty file"):
        config.load(empty)
    bad = write(tmp_path, yaml.safe_dump(changed(lambda d: d["cameras"][0].update(fsp=1))))
    with pytest.raises(ConfigError, match=r"rig\.yaml: cameras\[0\]\.fsp: unknown key; did"):
        config.load(bad)
    binary = write(tmp_path, "")
    binary.write_bytes(b"version: 1\nname: \xff\xfe\n")
    with pytest.raises(ConfigError, match=r"rig\.yaml: not UTF-8 text"):
        config.load(binary)
    with pytest.raises(ConfigError, match=r": cannot read"):
        config.load(tmp_path)


def test_yaml_syntax_error_has_line_and_column(tmp_path: Path) -> None:
    path = write(tmp_path, "version: 1\nscanners:\n  - name: laser\n    driver: [hokuyo\n")
    with pytest.raises(ConfigError) as info:
        config.load(path)
    text = str(info.value)
    assert "\n" not in text
    assert re.fullmatch(rf"{re.escape(str(path))}:5:1: invalid YAML: .+", text), text
    path = write(tmp_path, "version: 1\noutput:\n  dir: a\n dir: b\n")
    with pytest.raises(ConfigError, match=r"rig\.yaml:4:\d+: invalid YAML: "):
        config.load(path)


def test_duplicate_yaml_key_is_an_error(tmp_path: Path) -> None:
    text = yaml.safe_dump(GOOD, sort_keys=False) + "cameras: []\n"
    path = write(tmp_path, text)
    line = text.count("\n")
    with pytest.raises(ConfigError) as info:
        config.load(path)
    assert str(info.value) == f"{path}:{line}:1: invalid YAML: duplicate key cameras"


def test_merge_keys_may_be_overridden(tmp_path: Path) -> None:
    text = (
        "version: 1\n"
        "cameras:\n"
        "  - &cam {name: left, driver: opencv, source: '0', fps: 25}\n"
        "  - {<<: *cam, name: right, fps: 30}\n"
    )
    cfg = config.load(write(tmp_path, text))
    assert [(c.name, c.fps) for c in cfg.cameras] == [("left", 25.0), ("right", 30.0)]


# --- paths -------------------------------------------------------------------------------------


def test_relative_paths_are_relative_to_the_file(tmp_path: Path, monkeypatch: Any) -> None:
    folder = tmp_path / "rigs" / "van"
    folder.mkdir(parents=True)
    data = changed(
        lambda d: d.update(
            calibration="../calib/van.yaml",
            output={"dir": "logs"},
            can={"interface": "socketcan", "channel": "can0", "dbc": "car.dbc"},
        )
    )
    path = write(folder, yaml.safe_dump(data))
    monkeypatch.chdir(tmp_path)  # not the file's folder
    cfg = config.load(Path("rigs/van/rig.yaml"))
    assert cfg.source == folder / "rig.yaml"
    assert cfg.calibration == tmp_path / "rigs" / "calib" / "van.yaml"
    assert cfg.output.dir == folder / "logs"
    assert cfg.can is not None and cfg.can.dbc == folder / "car.dbc"
    # parse leaves them as written; absolute paths stay as they are
    assert config.parse(data).calibration == Path("../calib/van.yaml")
    data["output"]["dir"] = "/var/lib/acq/logs"
    assert config.load(write(folder, yaml.safe_dump(data))).output.dir == Path("/var/lib/acq/logs")
    assert path.exists()


# --- writing ----------------------------------------------------------------------------------


@pytest.mark.parametrize("name", SHIPPED)
def test_dump_round_trips(name: str) -> None:
    cfg = config.load(ROOT / "config" / name)
    again = config.parse(yaml.safe_load(config.dump(cfg)))
    assert again == cfg.model_copy(update={"source": None})
    assert "source" not in yaml.safe_load(config.dump(cfg))


def test_dump_round_trips_everything() -> None:
    cfg = config.parse(
        {
            "version": 1,
            "scanners": [
                {
                    "name": "s",
                    "driver": "sick",
                    "url": "tcp://h",
                    "protocol": "cola-a",
                    "latency_s": 0.001,
                    "options": {"login": [3, 1234], "intensity": False},
                }
            ],
            "cameras": [
                {
                    "name": "c",
                    "driver": "v4l2",
                    "source": "/dev/video0",
                    "width": 640,
                    "height": 480,
                    "fourcc": "YUYV",
                    "options": {"exposure_s": None, "gain": 3},
                }
            ],
            "calibration": "/etc/acq/calib.yaml",
            "output": {"dir": "/data", "prefix": "van-1", "split_megabytes": 100},
            "can": {"interface": "socketcan", "channel": "can0", "dbc": "a.dbc", "bitrate": 500000},
            "gnss": {"url": "/dev/ttyUSB0", "baudrate": 115200},
        }
    )
    assert config.parse(yaml.safe_load(config.dump(cfg))) == cfg


# --- nothing but ConfigError ------------------------------------------------------------------

KEYS = sorted(
    {f for m in (Config, ScannerConfig, CameraConfig, config.OutputConfig) for f in m.model_fields}
    | {"can", "gnss", "dbc", "intensity", "cluster", "verify", "login", "fsp", "<<"}
)
SCALARS = (
    st.none()
    | st.booleans()
    | st.integers(-(2**70), 2**70)
    | st.floats()
    | st.text(max_size=8)
    | st.sampled_from(["hokuyo", "sick", "opencv", "v4l2", "auto", "cola-a", "tcp://h:1", "x"])
)
TREES = st.recursive(
    SCALARS,
    lambda inner: (
        st.lists(inner, max_size=3)
        | st.dictionaries(
            st.sampled_from(KEYS) | st.text(max_size=4) | st.integers(), inner, max_size=4
        )
    ),
    max_leaves=25,
)


@st.composite
def mutated(draw: st.DrawFn) -> Any:
    """A good configuration with one value somewhere replaced by a random tree."""
    data: Any = copy.deepcopy(GOOD)
    data["scanners"][0]["options"] = {"intensity": True}
    node = data
    while True:
        keys = list(node) if isinstance(node, dict) else list(range(len(node)))
        key = draw(st.sampled_from(keys))
        child = node[key]
        if isinstance(child, dict | list) and child and draw(st.booleans()):
            node = child
            continue
        node[key] = draw(SCALARS | TREES)
        return data


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.one_of(TREES, mutated()))
def test_parse_raises_only_config_errors(data: Any) -> None:
    try:
        cfg = config.parse(data, "fuzz.yaml")
    except ConfigError as e:
        text = str(e)
        assert text.startswith("fuzz.yaml: ") and "\n" not in text
        return
    text = config.dump(cfg)
    assert config.parse(yaml.safe_load(text)) == cfg


def test_a_path_with_a_control_character_is_refused() -> None:
    # found by hypothesis: YAML would write U+0085 as a line break and read back a space
    base = {"version": 1, "scanners": [{"name": "laser", "driver": "hokuyo", "url": "/dev/x"}]}
    with pytest.raises(ConfigError, match=r"calibration: expected a path.*control character"):
        config.parse({**base, "calibration": "\x85"}, "rig.yaml")
