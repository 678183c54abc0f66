"""systemd/acq.service: what the recorder relies on, and systemd's own checks of it.

``systemd-analyze verify`` must print nothing. It checks that ExecStart's binary exists,
so it runs on a copy whose ExecStart names an executable stub in a temporary directory
(everything else byte-identical): the command systemd/README.md documents.
``systemd-analyze security --offline=true`` must score at most :data:`MAX_EXPOSURE`, the
figure recorded in the README, and every exposure it still reports must be justified in
a ``# Key= [exposed ...]`` comment in the unit.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
UNIT = ROOT / "systemd" / "acq.service"
README = ROOT / "systemd" / "README.md"
EXEC = "/opt/acq/.venv/bin/acq"
MAX_EXPOSURE = 1.6  # systemd 252; the README records the line verbatim
SCORE_RE = re.compile(r"Overall exposure level for acq\.service: (\d+(?:\.\d+)?) (\S+)")


def _directives() -> dict[str, list[str]]:
    """Every ``Key=value`` of the unit (all sections), values in order."""
    out: dict[str, list[str]] = {}
    for raw in UNIT.read_text().splitlines():
        line = raw.strip()
        if not line or line.startswith(("#", ";", "[")):
            continue
        key, _, value = line.partition("=")
        out.setdefault(key.strip(), []).append(value.strip())
    return out


def _one(key: str) -> str:
    values = _directives()[key]
    assert len(values) == 1, f"{key} set {len(values)} times"
    return values[0]


def _analyze() -> str:
    path = shutil.which("systemd-analyze")
    if path is None:
        pytest.skip("systemd-analyze is not installed (apt install systemd)")
    return path


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "SYSTEMD_COLORS": "0", "SYSTEMD_PAGER": "", "LC_ALL": "C.UTF-8"}
    return subprocess.run(
        [_analyze(), *args], capture_output=True, text=True, timeout=120, env=env, check=False
    )


def test_verify_prints_nothing(tmp_path: Path) -> None:
    stub = tmp_path / "acq"
    stub.write_text("#!/bin/sh\n")
    stub.chmod(0o755)
    text = UNIT.read_text()
    copy, n = re.subn(rf"^ExecStart={re.escape(EXEC)} ", f"ExecStart={stub} ", text, flags=re.M)
    assert n == 1
    (tmp_path / "acq.service").write_text(copy)
    result = _run("verify", str(tmp_path / "acq.service"))
    assert (result.stdout + result.stderr) == ""
    assert result.returncode == 0


def test_security_score_at_most_recorded() -> None:
    version = _run("--version").stdout.split()
    if len(version) < 2 or not version[1].isdigit() or int(version[1]) < 250:
        pytest.skip(f"systemd-analyze security --offline needs systemd >= 250: {version[:2]}")
    result = _run("security", "--offline=true", str(UNIT))
    match = SCORE_RE.search(result.stdout)
    assert match, result.stdout + result.stderr
    assert float(match.group(1)) <= MAX_EXPOSURE, match.group(0)
    # every exposure left is justified in the unit: "# Key=... [exposed ..."
    comments = "\n".join(
        line for line in UNIT.read_text().splitlines() if line.lstrip().startswith("#")
    )
    for line in result.stdout.splitlines():
        if line.startswith("✗"):
            key = line.split()[1].split("=")[0]
            assert re.search(rf"^# {key}=.*\[exposed", comments, re.M), f"unjustified: {line}"


def test_readme_records_the_score() -> None:
    text = README.read_text()
    match = SCORE_RE.search(text)
    assert match, "systemd/README.md does not record the exposure level"
    assert float(match.group(1)) == MAX_EXPOSURE
    assert "systemd-analyze verify" in text


def test_life_cycle() -> None:
    assert _one("Type") == "notify"
    assert _one("NotifyAccess") == "main"
    assert _one("WatchdogSec") == "10"
    assert _one("TimeoutStopSec") == "5"
    assert _one("KillSignal") == "SIGTERM"
    assert _one("Restart") == "on-failure"
    assert {"2", "3"} <= set(_one("RestartPreventExitStatus").split())
    assert _one("ExecStart") == f"{EXEC} record -c /etc/acq/acq.yaml"
    assert _one("User") == "acq"
    assert set(_one("SupplementaryGroups").split()) == {"dialout", "video"}
    assert _one("StateDirectory") == "acq"
    assert "PYTHONUNBUFFERED=1" in _directives()["Environment"]


def test_hardening_keeps_the_devices() -> None:
    d = _directives()
    assert _one("PrivateDevices") == "no"
    assert _one("DevicePolicy") == "closed"
    allowed = {v.split()[0] for v in d["DeviceAllow"]}
    assert {"char-ttyACM", "char-ttyUSB", "char-video4linux"} <= allowed
    families = set(_one("RestrictAddressFamilies").split())
    assert families == {"AF_UNIX", "AF_INET", "AF_INET6", "AF_NETLINK", "AF_CAN"}
    assert _one("PrivateNetwork") == "no"  # socketcan interfaces live in the host's netns
    assert _one("MemoryDenyWriteExecute") == "no"  # numba is a JIT
    assert _one("ProtectSystem") == "strict"
    assert _one("NoNewPrivileges") == "yes"
    assert _one("CapabilityBoundingSet") == ""
    assert _one("AmbientCapabilities") == ""
    assert _one("UMask") == "0027"
