"""The driver registry: every kind, our drivers, a third party's driver installed through
an entry point (a distribution's dist-info on sys.path, as pip would leave it), and a
driver whose module does not import, reported by name."""

from __future__ import annotations

import textwrap
from collections.abc import Iterator
from pathlib import Path

import pytest

from acq.drivers.registry import KINDS, REGISTRIES, DriverImportError, UnknownDriver
from acq.drivers.scanner import Scanner, driver_names, scanner_for
from acq.record import config

FAKE_LIDAR = '''
from acq.drivers.scanner import Scanner


class FakeLidar(Scanner):
    """A third party's scanner driver: only what the registry and the configuration see."""

    driver = "fakelidar"
    url_kind = "tcp"

    def __init__(self, url: str, *, name: str = "laser", timeout: float = 1.0,
                 spin_hz: float = 10.0) -> None:
        super().__init__(url, name=name, timeout=timeout)
        self.spin_hz = spin_hz

    def connect(self):
        raise NotImplementedError

    start = read_scan = stop = connect

    def close(self) -> None:
        pass
'''


def _distribution(site: Path, name: str, entry_points: str, modules: dict[str, str]) -> None:
    info = site / f"{name}-1.0.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {name}\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text(textwrap.dedent(entry_points))
    for module, text in modules.items():
        (site / f"{module}.py").write_text(text)


@pytest.fixture
def installed(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """Two third-party distributions: a working scanner driver and a camera driver whose
    vendor library is missing."""
    site = tmp_path / "site"
    _distribution(
        site,
        "acq_fakelidar",
        """
        [acq.scanners]
        fakelidar = acq_fakelidar:FakeLidar
        hokuyo = acq_fakelidar:FakeLidar
        """,
        {"acq_fakelidar": FAKE_LIDAR},
    )
    _distribution(
        site,
        "acq_brokencam",
        """
        [acq.cameras]
        brokencam = acq_brokencam:Cam
        """,
        {"acq_brokencam": "import vendor_sdk_that_is_not_installed\n"},
    )
    monkeypatch.syspath_prepend(str(site))
    for registry in REGISTRIES.values():
        registry.reload()
    yield
    monkeypatch.undo()
    for registry in REGISTRIES.values():
        registry.reload()


def _rig(**device: object) -> dict[str, object]:
    kind = "cameras" if "source" in device else "scanners"
    return {"version": 1, kind: [{"name": "dev", **device}]}


def test_every_kind_and_our_drivers() -> None:
    assert {k: r.names() for k, r in REGISTRIES.items()} == {
        "scanner": ["hokuyo", "sick"],
        "camera": ["opencv", "v4l2"],
        "can": ["python-can"],
        "gnss": ["nmea"],
    }
    assert [k.group for k in KINDS.values()] == [
        "acq.scanners",
        "acq.cameras",
        "acq.can",
        "acq.gnss",
    ]
    for registry in REGISTRIES.values():
        for name in registry.names():
            assert registry.get(name).driver == name  # importable, and named as registered
    with pytest.raises(UnknownDriver, match="unknown scanner driver 'velodyne'; expected one of"):
        REGISTRIES["scanner"].get("velodyne")


def test_a_third_party_driver_through_its_entry_point(installed: None) -> None:
    assert "fakelidar" in driver_names()
    cfg = config.parse(_rig(driver="fakelidar", url="tcp://10.0.0.7:2368",
                            options={"spin_hz": 20}))  # fmt: skip
    scanner = cfg.scanners[0]
    assert scanner.driver == "fakelidar" and scanner.options == {"spin_hz": 20.0}
    made = scanner_for(scanner.driver, scanner.url, name=scanner.name, **scanner.options)
    assert isinstance(made, Scanner) and type(made).__name__ == "FakeLidar"
    assert (made.url, made.name, made.spin_hz) == ("tcp://10.0.0.7:2368", "dev", 20.0)  # type: ignore[attr-defined]
    # checked like ours: its url kind, its options, no protocol of another driver's
    with pytest.raises(config.ConfigError, match=r"scanners\[0\]\.url: expected tcp://host:port"):
        config.parse(_rig(driver="fakelidar", url="http://h:1"))
    with pytest.raises(config.ConfigError, match="unknown option of the fakelidar driver"):
        config.parse(_rig(driver="fakelidar", url="tcp://h:1", options={"spinhz": 20}))
    with pytest.raises(config.ConfigError, match=r"protocol: only for driver sick; remove it"):
        config.parse(_rig(driver="fakelidar", url="tcp://h:1", protocol="cola-b"))
    # an entry point cannot replace one of ours
    assert REGISTRIES["scanner"].get("hokuyo").__name__ == "ScipScanner"


def test_a_driver_that_does_not_import_is_named_with_its_error(installed: None) -> None:
    assert "brokencam" in REGISTRIES["camera"].names()  # listed without importing it
    with pytest.raises(DriverImportError) as e:
        REGISTRIES["camera"].create("brokencam", "0")
    assert str(e.value) == (
        "the camera driver 'brokencam' (acq_brokencam:Cam) cannot be imported: "
        "ModuleNotFoundError: No module named 'vendor_sdk_that_is_not_installed'"
    )
    with pytest.raises(config.ConfigError) as c:
        config.parse(_rig(driver="brokencam", source="0"), "rig.yaml")
    assert str(c.value) == f"rig.yaml: cameras[0].driver: {e.value}"
    # and the others still work
    assert config.parse(_rig(driver="opencv", source="0")).cameras[0].driver == "opencv"
