#!/usr/bin/env bash
# OPT-IN (not in CI): the project's systemd unit for real, with systemd as PID 1 in the VM.
#
# Boots the cached Debian kernel (tests/vm/setup.sh) with systemd as init, on an
# overlay of this machine's root (writes go to a tmpfs; the real root is never given
# to the guest read-write), installs systemd/railgw.service unchanged at the layout it
# expects (/opt/railgw/venv, /etc/railgw/railgw.toml) against vcan0, and checks:
#   1. 'systemctl start railgw' returns, i.e. the service sent READY=1;
#   2. its STATUS= shows estimates while the simulator feeds vcan0;
#   3. a stopped (SIGSTOP) main process is killed by the watchdog and restarted;
#   4. 'systemctl stop' is clean (Result=success);
#   5. 'systemd-analyze security railgw.service' exposure is at most 2.5.
# Results: <cache>/systemd-results/{results.txt,journal.txt}. Needs root (mounts).
# The only changes to the unit are a drop-in for TCG: longer start timeout and a
# generic numba CPU target (see docs/vcan.md, "systemd in the VM").
set -euo pipefail
cd "$(dirname "$0")/../.."
ROOT=$(pwd -P)
CACHE=${RAILGW_VM_CACHE:-${XDG_CACHE_HOME:-$HOME/.cache}/railgw-vm}
TIMEOUT_S=${RAILGW_SYSTEMD_TIMEOUT_S:-1500}
KVER=$(cat "$CACHE/kernel/current")
KIMG=$CACHE/kernel/$KVER/boot/vmlinuz-$KVER
MODS=$CACHE/kernel/$KVER/lib/modules/$KVER
PYVER=$(.venv/bin/python -c 'import sys; print(f"{sys.version_info[0]}.{sys.version_info[1]}")')
SITE=$ROOT/.venv/lib/python$PYVER/site-packages
[ "$(id -u)" = 0 ] || { echo "needs root (overlay and bind mounts)" >&2; exit 2; }
[ -f "$KIMG" ] || { echo "run tests/vm/setup.sh first" >&2; exit 2; }

W=$CACHE/systemd
M=$W/root
OUT=$CACHE/systemd-results
cleanup() {
  for m in "$M/opt/railgw/venv/lib/python$PYVER/site-packages" \
           "$M/usr/lib/modules/$KVER" "$M" "$W/t"; do
    mountpoint -q "$m" && umount -l "$m" || true
  done
}
trap cleanup EXIT
cleanup
mkdir -p "$W/t" "$M" "$OUT"
rm -f "$OUT"/*
echo "== systemd check: overlay root $M (upper on tmpfs)"
mount -t tmpfs -o size=4G railgw-vm-upper "$W/t"
mkdir -p "$W/t/upper" "$W/t/work"
mount -t overlay railgw-vm-root -o "lowerdir=/,upperdir=$W/t/upper,workdir=$W/t/work" "$M"
# Guest systemd must not think it runs in a container (it would ignore systemd.unit=).
rm -f "$M/.dockerenv"

# The layout the unit expects (/opt/railgw/venv), made of the project venv's packages
# on Debian's python of the same minor version, as a real install would be. (The
# project venv's own interpreter may live under /root, which the unit's DynamicUser and
# ProtectHome=yes cannot reach, and a pyenv build finds its libpython there.)
BASE=/usr/bin/python$PYVER
[ -x "$BASE" ] || { echo "needs Debian's python$PYVER (apt-get install python$PYVER)" >&2; exit 2; }
mkdir -p "$M/opt/railgw/venv/bin" "$M/opt/railgw/venv/lib/python$PYVER/site-packages" \
         "$M/usr/lib/modules/$KVER"
mount --bind -o ro "$SITE" "$M/opt/railgw/venv/lib/python$PYVER/site-packages"
mount --bind -o ro "$MODS" "$M/usr/lib/modules/$KVER"
ln -sf "$BASE" "$M/opt/railgw/venv/bin/python"
printf 'home = /usr/bin\ninclude-system-site-packages = false\nversion = %s\n' \
  "$("$BASE" -c 'import platform; print(platform.python_version())')" \
  > "$M/opt/railgw/venv/pyvenv.cfg"

# Warm numba on the host for the guest (generic CPU target): the simulator's kernels.
# (A numba kernel of the service that is cached (cache=True) and warmed in
# tests/vm/prewarm.py is found by the service too: its cache directory gets a copy.)
NUMBA_CACHE_DIR=$CACHE/numba NUMBA_CPU_NAME=generic .venv/bin/python tests/vm/prewarm.py
mkdir -p "$M/var/cache/private/railgw"
cp -a "$CACHE/numba" "$M/var/cache/private/railgw/numba"

install -D -m 644 systemd/railgw.service "$M/etc/systemd/system/railgw.service"
mkdir -p "$M/etc/systemd/system/railgw.service.d" "$M/etc/railgw"
cat > "$M/etc/systemd/system/railgw.service.d/vmtest.conf" <<'EOF'
# tests/vm/run-systemd-check.sh: qemu TCG is 20-50x slower than the host.
[Service]
TimeoutStartSec=900
Environment=NUMBA_CPU_NAME=generic
EOF
sed -e 's/^channel = "can0"/channel = "vcan0"/' -e 's/^particles = 1000/particles = 32/' \
  systemd/railgw.example.toml > "$M/etc/railgw/railgw.toml"

cat > "$M/etc/systemd/system/railgw-vmtest.service" <<EOF
[Unit]
Description=railgw systemd check (tests/vm/run-systemd-check.sh)
After=basic.target
[Service]
Type=oneshot
ExecStart=/bin/bash /railgw-vmtest/check.sh
StandardOutput=journal+console
EOF
mkdir -p "$M/railgw-vmtest"
cat > "$M/railgw-vmtest/check.sh" <<EOF
#!/bin/bash
# Runs in the guest under systemd as PID 1.
R=/railgw-vmtest
exec >> \$R/results.txt 2>&1
t() { echo "[\$(cut -d' ' -f1 /proc/uptime)] \$*"; }
ok() { echo "CHECK \$1 \$2"; }
finish() {
  systemctl status --no-pager -l railgw > \$R/status.txt 2>&1
  journalctl -b --no-pager > \$R/journal.txt 2>&1
  t done; sync; systemctl poweroff --force
  exit 0
}
until_s() {  # SECONDS COMMAND...: retry COMMAND every second until it succeeds
  local end=\$(( \$(date +%s) + \$1 )); shift
  until "\$@"; do [ "\$(date +%s)" -lt "\$end" ] || return 1; sleep 1; done
}
t "guest up"
modprobe vcan && ip link add dev vcan0 type vcan && ip link set up vcan0 || { ok vcan FAIL; finish; }
export NUMBA_CACHE_DIR=$CACHE/numba NUMBA_CPU_NAME=generic
cd $ROOT
if systemctl start railgw; then ok ready PASS; else ok ready FAIL; finish; fi
t "started: \$(systemctl show -p ActiveState,SubState,StatusText railgw | tr '\n' ' ')"
.venv/bin/python -m firmware_sim run --scenario nominal --duration 900 --bus socketcan:vcan0 > \$R/sim.log 2>&1 &
SIM=\$!
has_estimates() { case "\$(systemctl show -p StatusText --value railgw)" in Csy*) return 0;; esac; return 1; }
if until_s 600 has_estimates; then ok status PASS; else ok status FAIL; fi
t "status: \$(systemctl show -p StatusText --value railgw)"
pid=\$(systemctl show -p MainPID --value railgw)
n0=\$(systemctl show -p NRestarts --value railgw)
t "SIGSTOP main pid \$pid (NRestarts \$n0)"
kill -STOP "\$pid"
restarted() {
  [ "\$(systemctl show -p NRestarts --value railgw)" -gt "\$n0" ] \
    && [ "\$(systemctl is-active railgw)" = active ]
}
until_s 300 restarted
t "after watchdog: \$(systemctl show -p NRestarts,MainPID,ActiveState,SubState railgw | tr '\n' ' ')"
if restarted && journalctl -b -u railgw --no-pager | grep -qi watchdog; then ok watchdog PASS
else ok watchdog FAIL; fi
systemctl stop railgw
t "stopped: \$(systemctl show -p Result,ExecMainStatus,ActiveState railgw | tr '\n' ' ')"
[ "\$(systemctl show -p Result --value railgw)" = success ] && ok stop PASS || ok stop FAIL
kill \$SIM 2>/dev/null
systemd-analyze security --no-pager railgw.service > \$R/security.txt 2>&1
lvl=\$(sed -n 's/.*Overall exposure level for railgw.service: \([0-9.]*\).*/\1/p' \$R/security.txt)
t "exposure \$lvl"
awk -v l="\$lvl" 'BEGIN { exit !(l != "" && l <= 2.5) }' && ok security PASS || ok security FAIL
finish
EOF

echo "== systemd check: booting (systemd as PID 1, TCG; this takes several minutes)"
t0=$(date +%s)
PATH=$CACHE/venv/bin:$PATH timeout -k 10 "$TIMEOUT_S" vng --disable-kvm --run "$KIMG" \
  --root "$M" --rw --force-9p --systemd --memory 2G --verbose \
  --append systemd.unit=railgw-vmtest.service > "$OUT/vng.log" 2>&1 || true
echo "== systemd check: VM ran $(( $(date +%s) - t0 )) s"
cp "$M/railgw-vmtest/"*.txt "$M/railgw-vmtest/"*.log "$OUT/" 2>/dev/null || true
if [ ! -s "$OUT/results.txt" ]; then
  echo "no results came back; end of vng.log:"; tail -30 "$OUT/vng.log"; exit 1
fi
cat "$OUT/results.txt"
fails=$(grep -c '^CHECK .* FAIL' "$OUT/results.txt" || true)
passes=$(grep -c '^CHECK .* PASS' "$OUT/results.txt" || true)
echo "systemd: $passes passed, $fails failed"
[ "$fails" = 0 ] && [ "$passes" = 5 ]
