#!/usr/bin/env bash
# CI's check of the Debian package (.ci/run; as root, on the CI machine itself): build it,
# install it with dpkg -i, verify the installed unit with systemd-analyze, then walk the
# README's steps on the package as written (step 5: edit the packaged configuration; step 6:
# the dry run as the storage's owner, against a simulated rig; step 9: the daemon as the unit's
# user, until it is ready), check that a command run as root leaves nothing in the storage and
# that the daemon names a file it cannot open; remove it (not purge) and check that the history
# in /var/lib/handeye is still there; purge, reinstall (the storage is the new user's again)
# and purge.
#
#   packaging/deb/check.sh [BINARY]      (BINARY: as packaging/deb/build.sh)
#
# Addresses: the simulated rig on 127.0.0.190 (controller, standard ports) and 127.0.0.191
# (camera), the daemon's API on 127.0.0.192:8650 (tests/e2e.rs lists the addresses in use).
set -euo pipefail
root=$(cd "$(dirname "$0")/../.." && pwd)
cd "$root"
t0=$(date +%s)
deb=$(packaging/deb/build.sh "$@")
deb=$root/$deb
echo "built $deb ($(du -h "$deb" | cut -f1)) in $(( $(date +%s) - t0 )) s"
fail() { echo "packaging/deb/check.sh: $*" >&2; exit 1; }

# The package's own entries: `./` is / on the machine it is installed on.
top=$(dpkg-deb -c "$deb" | awk '$6 == "./" { print $1 }')
[ "$top" = drwxr-xr-x ] || fail "the package's ./ entry is $top, not drwxr-xr-x (0755)"
dpkg-deb -c "$deb" | grep -q ' ./usr/share/handeye/robots/ur/ur5e/ur5e.urdf$' \
  || fail "the package carries no UR models (/usr/share/handeye/robots/ur)"

if dpkg -s handeye >/dev/null 2>&1; then
  dpkg -P handeye >/dev/null
fi
rm -rf /var/lib/handeye

# What runs in the background (the simulated rig, the daemon) is stopped however this ends.
work=$(mktemp -d)
# The daemon (user handeye) reads its token from here, as from systemd's credentials folder.
chmod 0711 "$work"
pids=()
cleanup() {
  local p
  for p in "${pids[@]}"; do
    kill -TERM "$p" 2>/dev/null || true
    wait "$p" 2>/dev/null || true
  done
  rm -rf "$work"
}
trap cleanup EXIT

# The README's commands run as written. `sudo` is root's own here; where the machine has no
# sudo (a CI container), `sudo -u USER CMD…` is runuser, `sudo CMD…` is CMD.
if ! command -v sudo >/dev/null 2>&1; then
  sudo() {
    if [ "$1" = -u ]; then
      local user=$2
      shift 2
      runuser -u "$user" -- "$@"
    else
      "$@"
    fi
  }
fi
# A README step's command: fails when the README no longer says it, then runs it.
readme_says() {
  grep -qF -- "$1" README.md || fail "README.md no longer says \`$1\`: change this script with it"
}

# Install (the README's `sudo apt install ./handeye_*.deb`; dpkg -i is the same install
# without apt's index).
readme_says 'sudo apt install ./handeye_*.deb'
dpkg -i "$deb"
[ "$(handeye --version)" = "handeye $(dpkg-query -W -f='${Version}' handeye)" ] \
  || fail "handeye --version does not match the package: $(handeye --version)"
[ "$(command -v handeye)" = /usr/bin/handeye ] || fail "handeye is not /usr/bin/handeye"
getent passwd handeye >/dev/null || fail "no handeye system user"
[ "$(stat -c %U /var/lib/handeye)" = handeye ] || fail "/var/lib/handeye is not the handeye user's"
[ "$(stat -c %a /etc/handeye/token)" = 600 ] || fail "/etc/handeye/token is not mode 0600"
[ "$(stat -c %a /)" = 755 ] || fail "installing the package changed / to mode $(stat -c %a /)"
handeye config reference >/dev/null
grep -q '^dir = "/var/lib/handeye"' /etc/handeye/handeye.toml || fail "storage.dir is not /var/lib/handeye"
if command -v systemd-analyze >/dev/null 2>&1; then
  systemd-analyze verify /lib/systemd/system/handeye.service
elif [ -n "${CI:-}" ]; then
  fail "systemd-analyze is missing in CI: run .ci/install.d/systemd.sh"
fi
if command -v systemctl >/dev/null 2>&1; then
  [ "$(systemctl is-enabled handeye 2>/dev/null || true)" != enabled ] || fail "the package enabled the service"
fi
[ ! -e /etc/systemd/system/multi-user.target.wants/handeye.service ] || fail "the package enabled the service"

# The models are the package's: found from anywhere, without HANDEYE_ROBOTS (as a user's
# shell and the unit's Environment= have it).
models=$(cd / && env -u HANDEYE_ROBOTS handeye robot models --config /etc/handeye/handeye.toml) \
  || fail "handeye robot models: the configured model is missing: $models"
grep -q '^  /usr/share/handeye/robots (the package): used$' <<<"$models" \
  || fail "the packaged models are not the ones used: $models"

# The simulated rig the configuration is pointed at (README step 5 on a real cell: the
# controller's and the camera's addresses).
(cd / && exec env -u HANDEYE_ROBOTS handeye sim rig --robot-bind 127.0.0.190 --camera-bind 127.0.0.191) \
  2>"$work/rig.log" &
pids+=($!)

# Step 5: edit the packaged configuration (sudoedit there), never copy the example over it.
readme_says 'sudoedit /etc/handeye/handeye.toml'
readme_says 'edit the packaged `/etc/handeye/handeye.toml`'
sed -i -e 's|^host = "192.168.56.101" |host = "127.0.0.190" |' \
       -e 's|^address = "192.168.1.50" |address = "127.0.0.191" |' \
       -e 's|^listen = "127.0.0.1:8650" |listen = "127.0.0.192:8650" |' \
    /etc/handeye/handeye.toml
for want in '^host = "127.0.0.190"' '^address = "127.0.0.191"' '^listen = "127.0.0.192:8650"'; do
  grep -q "$want" /etc/handeye/handeye.toml || fail "editing /etc/handeye/handeye.toml: no line $want"
done
ready=""
for _ in $(seq 1 100); do
  if grep -q '^simulated rig' "$work/rig.log"; then ready=1; break; fi
  sleep 0.1
done
[ -n "$ready" ] || fail "the simulated rig did not start: $(cat "$work/rig.log")"

# Step 6 as root: refused before connecting, naming the command under sudo -u handeye, and
# nothing left in the storage that its owner cannot open.
if out=$(cd / && handeye calibrate --config /etc/handeye/handeye.toml --dry-run 2>&1); then
  fail "a dry run as root on the handeye user's storage ran: $out"
fi
grep -qF '`sudo -u handeye handeye calibrate --config /etc/handeye/handeye.toml --dry-run`' <<<"$out" \
  || fail "the refusal as root does not name sudo -u handeye: $out"
strays=$(find /var/lib/handeye ! -user handeye)
[ -z "$strays" ] || fail "a command run as root left files handeye does not own: $strays"

# Step 6 as written.
readme_says 'sudo -u handeye handeye calibrate --config /etc/handeye/handeye.toml --dry-run'
(cd / && sudo -u handeye handeye calibrate --config /etc/handeye/handeye.toml --dry-run) \
  > "$work/dry-run.txt" 2>&1 || fail "the README's dry run failed: $(cat "$work/dry-run.txt")"
grep -q ': planned$' "$work/dry-run.txt" || fail "the dry run did not plan: $(cat "$work/dry-run.txt")"
strays=$(find /var/lib/handeye ! -user handeye)
[ -z "$strays" ] || fail "the dry run as handeye left files handeye does not own: $strays"

# Step 9: the daemon as the unit's user. Without systemd as the init (a CI container has
# none, so `systemctl enable --now handeye` cannot run), it runs as systemd would start it:
# user handeye, the token handed over in $CREDENTIALS_DIRECTORY (LoadCredential=),
# HANDEYE_ROBOTS as the unit sets it. setpriv execs the daemon itself (runuser would stay its
# parent and answer SIGTERM by killing it), so the stop below is the daemon's own.
unit_env=$(sed -n 's/^Environment=//p' /lib/systemd/system/handeye.service)
exec_start=$(sed -n 's/^ExecStart=//p' /lib/systemd/system/handeye.service)
[ "$exec_start" = "/usr/bin/handeye daemon --config /etc/handeye/handeye.toml" ] \
  || fail "the unit's ExecStart= changed: $exec_start"
install -d -m 0700 -o handeye -g handeye "$work/credentials"
install -m 0400 -o handeye -g handeye /etc/handeye/token "$work/credentials/token"
start_daemon() {
  : > "$work/daemon.log"
  chown handeye: "$work/daemon.log"
  (cd / && exec setpriv --reuid=handeye --regid=handeye --init-groups -- \
      env CREDENTIALS_DIRECTORY="$work/credentials" $unit_env $exec_start) 2>>"$work/daemon.log" &
  daemon=$!
}
# A file left by an earlier root run (as README step 6 once said, with sudo): the daemon
# names it and the chown that gives it back, and does not start.
install -d /var/lib/handeye/runs
echo "root's" > /var/lib/handeye/runs/left-by-root
chmod 0600 /var/lib/handeye/runs/left-by-root
start_daemon
if wait "$daemon"; then
  fail "the daemon started with a file of root's in its storage: $(cat "$work/daemon.log")"
fi
grep -qF '/var/lib/handeye/runs/left-by-root (owner root, mode 0600)' "$work/daemon.log" \
  || fail "the daemon did not name the file it cannot open: $(cat "$work/daemon.log")"
fix=$(grep -o 'sudo chown -R handeye: /var/lib/handeye' "$work/daemon.log" | head -n 1)
[ -n "$fix" ] || fail "the daemon did not say how to give the files back: $(cat "$work/daemon.log")"
$fix
start_daemon
pids+=("$daemon")
ready=""
for _ in $(seq 1 300); do
  if grep -q '^handeye daemon ready' "$work/daemon.log"; then ready=1; break; fi
  kill -0 "$daemon" 2>/dev/null || break
  sleep 0.1
done
[ -n "$ready" ] || fail "the daemon did not become ready: $(cat "$work/daemon.log")"
grep -qF "API token from $work/credentials/token" "$work/daemon.log" \
  || fail "the daemon did not take the token from its credentials: $(cat "$work/daemon.log")"
# Step 10: the status answers (exit 0 or 1: a status; 2: no daemon).
readme_says 'handeye status --config'
code=0
handeye status --config /etc/handeye/handeye.toml > "$work/status.txt" 2>&1 || code=$?
[ "$code" -le 1 ] || fail "handeye status: $(cat "$work/status.txt")"
kill -TERM "$daemon"
wait "$daemon" || fail "the daemon did not stop cleanly: $(cat "$work/daemon.log")"
grep -q '^handeye daemon stopped' "$work/daemon.log" || fail "the daemon did not say it stopped: $(cat "$work/daemon.log")"
strays=$(find /var/lib/handeye ! -user handeye)
[ -z "$strays" ] || fail "the daemon left files handeye does not own: $strays"

# Removal (not purge) keeps the history.
[ -f /var/lib/handeye/history.sqlite ] || fail "no history after the dry run and the daemon"
dpkg -r handeye
[ ! -e /usr/bin/handeye ] || fail "dpkg -r left /usr/bin/handeye"
[ -f /var/lib/handeye/history.sqlite ] || fail "dpkg -r removed the history"
[ -f /etc/handeye/handeye.toml ] || fail "dpkg -r removed the configuration"
dpkg -P handeye 2>"$work/purge.log"
[ -f /var/lib/handeye/history.sqlite ] || fail "dpkg -P removed the history"
[ ! -e /etc/handeye/handeye.toml ] || fail "dpkg -P left the configuration"
strays=$(find /var/lib/handeye ! -user root)
[ -z "$strays" ] || fail "dpkg -P left files of the freed handeye uid: $strays"
grep -q 'rm -rf /var/lib/handeye' "$work/purge.log" || fail "dpkg -P did not say that it kept /var/lib/handeye"
# A reinstall gives the kept history to the new handeye user, every file of it.
dpkg -i "$deb" >/dev/null
strays=$(find /var/lib/handeye ! -user handeye)
[ -z "$strays" ] || fail "a reinstall left files handeye does not own: $strays"
dpkg -P handeye 2>/dev/null
rm -rf /var/lib/handeye
echo "the package installs, walks the README's steps (dry run, daemon), verifies and uninstalls, keeping the history"
