#!/usr/bin/env bash
# The wheel as a user installs it: built from the repository, installed (not editable)
# into a throwaway venv, and its commands run from a folder outside the checkout, so a
# module or data file the wheel lacks fails here. Usage: tests/smoke/wheel.sh PYTHON
set -euo pipefail
python=${1:?usage: tests/smoke/wheel.sh PYTHON}
root=$(cd "$(dirname "$0")/../.." && pwd)
work=$(mktemp -d "${TMPDIR:-/tmp}/acq-wheel.XXXXXX")
pids=()
cleanup() {
  for pid in "${pids[@]}"; do kill "$pid" 2>/dev/null || true; done
  wait 2>/dev/null || true
  rm -rf "$work"
}
trap cleanup EXIT
# bytecode written by the first process that imports a module (not all of every package
# compiled at install, twice: most of it these commands never import)
unset PYTHONDONTWRITEBYTECODE
step() { printf 'wheel smoke: %s\n' "$*"; }

step "build and install: every extra (acq[all]) in venv, the core alone in core"
# install VENV SPEC: the wheel as a user installs it, as make installs: uv, else pip
if "$python" -m uv --version > /dev/null 2>&1; then
  "$python" -m uv build --quiet --wheel --out-dir "$work/dist" "$root"
  install() {
    "$python" -m uv venv --quiet --python "$python" "$1"
    "$python" -m uv pip install --quiet --python "$1/bin/python" "$2"
  }
else
  "$python" -m pip wheel --quiet --no-deps --wheel-dir "$work/dist" "$root"
  install() { "$python" -m venv "$1" && "$1/bin/python" -m pip install --quiet "$2"; }
fi
wheel=$(echo "$work"/dist/acq-*.whl)
install "$work/venv" "$wheel[all]"
install "$work/core" "$wheel"
acq=$work/venv/bin/acq
site=$("$work/venv/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')
cd "$work"  # nothing of the checkout on sys.path from here on

step "one import root"
roots=$("$python" -c 'import sys, zipfile
names = zipfile.ZipFile(sys.argv[1]).namelist()
print(" ".join(sorted({n.split("/")[0] for n in names} - {n.split("/")[0] for n in names if ".dist-info/" in n})))' "$work"/dist/acq-*.whl)
[ "$roots" = "acq" ] || { echo "wheel smoke: the wheel installs $roots, not only acq" >&2; exit 1; }
"$work/venv/bin/python" -c 'import acq.drivers.scip, acq.sim.world, acq.cli'
for name in drivers sim config; do
  [ ! -e "$site/$name" ] || { echo "wheel smoke: $site/$name installed" >&2; exit 1; }
done

step "acq --version, every command's --help"
"$acq" --version
for cmd in demo "sim render" "sim scanner" "sim camera" "sim rig" "probe scanner" "probe camera" record \
    info status replay colorize "calibrate fisheye" "calibrate extrinsic" "calibrate time-offset" \
    "calibrate validate" "calibrate check" "analyze sensitivity" devices "export ros2" view; do
  # shellcheck disable=SC2086
  "$acq" $cmd --help > /dev/null || { echo "wheel smoke: acq $cmd --help failed" >&2; exit 1; }
done

step "acq demo --seconds 2"
"$acq" demo --seconds 2 --out demo > demo.txt || { cat demo.txt; exit 1; }
[ -s demo/demo.mcap ] && [ -s demo/cloud.ply ] && [ -s demo/preview.png ]

step "acq view serves the demo's cloud, its page and every vendored library"
: > view.log  # there before it is read: the job's own redirection may come later
"$acq" view demo/cloud.ply > view.log 2>&1 &
pids+=($!)
url=
for _ in $(seq 1 300); do
  url=$(sed -n 's/^serving .* at \(http[^ ]*\) .*/\1/p' view.log)
  [ -n "$url" ] && break
  sleep 0.1
done
[ -n "$url" ] || { echo "wheel smoke: acq view did not start" >&2; cat view.log >&2; exit 1; }
"$work/venv/bin/python" - "$url" <<'EOF'
import hashlib, json, sys, urllib.request
url = sys.argv[1]
get = lambda path: urllib.request.urlopen(url + path, timeout=10).read()
assert b"/static/viewer.js" in get("") and get("static/viewer.js")
assert json.loads(get("api/layers"))[0]["name"] == "cloud.ply"
for f in json.loads(get("static/vendor/VENDORED.json"))["files"]:
    assert hashlib.sha256(get("static/vendor/" + f["path"])).hexdigest() == f["sha256"], f
EOF

step "acq colorize on the demo's log"
"$acq" colorize demo/demo.mcap --calib demo/calib.yaml --camera left -o drive.las --no-preview \
  > /dev/null
[ -s drive.las ]

step "the core install colours the demo's log, and names the extra --dask needs"
"$work/core/bin/acq" colorize demo/demo.mcap --calib demo/calib.yaml --camera left -o core.las \
  --no-preview > /dev/null
[ -s core.las ]
status=0
"$work/core/bin/acq" colorize demo/demo.mcap --calib demo/calib.yaml -o core.ply \
  --dask tcp://127.0.0.1:9 2> dask.txt || status=$?
[ "$status" -eq 2 ] && [ "$(cat dask.txt)" = "acq colorize: --dask needs the cluster extra: \
pip install 'acq[cluster]'" ] && [ ! -e core.ply ] \
  || { echo "wheel smoke: core install, --dask: exit $status" >&2; cat dask.txt >&2; exit 1; }

step "acq export ros2 on the demo's log"
"$acq" export ros2 demo/demo.mcap -o drive_bag > /dev/null 2>&1
[ -s drive_bag/metadata.yaml ] && [ -s drive_bag/drive_bag.mcap ]

step "acq sim render, acq calibrate fisheye on its frame"
"$acq" sim render --out render > /dev/null
"$acq" calibrate fisheye render/frame.png --fov 185 -o fisheye.yaml > /dev/null
[ -s fisheye.yaml ]
"$acq" devices > /dev/null

step "acq record for 2 s with the default configuration, against acq sim"
ready() {  # a simulator's first line says where it serves
  local log=$1 i
  for i in $(seq 1 600); do grep -q '^simulated' "$log" 2>/dev/null && return 0; sleep 0.1; done
  echo "wheel smoke: $log: the simulator did not start" >&2; cat "$log" >&2; return 1
}
# 10940 is also the Hokuyo samples' fixed port, which their tests serve beside this run:
# held under their lock (tests/hokuyo_client.py: sample_port) until the simulator is gone
exec 9>> "${TMPDIR:-/tmp}/acq-tests-port-10940.lock"
flock -w 300 9
"$acq" sim scanner --model utm-30lx --listen tcp://127.0.0.1:10940 > scanner.log 2>&1 9>&- &
scanner=$!
pids+=($scanner)
"$acq" sim camera --listen http://127.0.0.1:8080/stream.mjpg > camera.log 2>&1 9>&- &
pids+=($!)
ready scanner.log && ready camera.log
"$acq" probe scanner --driver hokuyo --url socket://127.0.0.1:10940 --count 2 > /dev/null
"$acq" record --duration 2
"$acq" info logs/*.mcap > info.txt || { cat info.txt; exit 1; }
grep -q '/laser/scan' info.txt && grep -q '/camera/image/compressed' info.txt
kill "$scanner" 2> /dev/null || true; wait "$scanner" 2> /dev/null || true
flock -u 9

step "acq analyze sensitivity on that one-camera log"
"$acq" analyze sensitivity --calib "$site/acq/config/sim_calib.yaml" logs/*.mcap -o sensitivity \
  > /dev/null
[ -s sensitivity/sensitivity.json ]

step "the README's walkthrough: acq sim rig, acq record -c rig/rig.yaml, acq colorize"
"$acq" sim rig --out rig --prerender 8 > rig.log 2>&1 &
pids+=($!)
for i in $(seq 1 1200); do [ -e rig/rig.yaml ] && break; sleep 0.1; done
[ -e rig/rig.yaml ] || { echo "wheel smoke: acq sim rig did not start" >&2; cat rig.log >&2; exit 1; }
"$acq" record -c rig/rig.yaml --out riglogs --duration 2
"$acq" colorize riglogs --calib rig/calib.yaml -o rig.ply --no-preview > rig.txt \
  || { cat rig.txt; exit 1; }
grep -q 'CAN odometry' rig.txt || { cat rig.txt; exit 1; }
step "passed"
