#!/usr/bin/env bash
# CI's check of the Debian package (.ci/run; as root, on the CI machine itself): build it,
# install it with dpkg -i, verify the installed unit with systemd-analyze, run the installed
# binary, check that the maintainer scripts neither enabled nor started the service, remove
# it (not purge) and check that the history in /var/lib/handeye is still there; then purge.
set -euo pipefail
root=$(cd "$(dirname "$0")/../.." && pwd)
cd "$root"
t0=$(date +%s)
deb=$(packaging/deb/build.sh "$@")
echo "built $deb ($(du -h "$deb" | cut -f1)) in $(( $(date +%s) - t0 )) s"
if dpkg -s handeye >/dev/null 2>&1; then
  dpkg -P handeye >/dev/null
fi
dpkg -i "$deb"
fail() { echo "packaging/deb/check.sh: $*" >&2; exit 1; }
[ "$(handeye --version)" = "handeye $(dpkg-query -W -f='${Version}' handeye)" ] \
  || fail "handeye --version does not match the package: $(handeye --version)"
[ "$(command -v handeye)" = /usr/bin/handeye ] || fail "handeye is not /usr/bin/handeye"
getent passwd handeye >/dev/null || fail "no handeye system user"
[ "$(stat -c %U /var/lib/handeye)" = handeye ] || fail "/var/lib/handeye is not the handeye user's"
[ "$(stat -c %a /etc/handeye/token)" = 600 ] || fail "/etc/handeye/token is not mode 0600"
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
# Removal (not purge) keeps the history.
echo "a run's record" > /var/lib/handeye/history.sqlite
dpkg -r handeye
[ ! -e /usr/bin/handeye ] || fail "dpkg -r left /usr/bin/handeye"
[ -f /var/lib/handeye/history.sqlite ] || fail "dpkg -r removed the history"
[ -f /etc/handeye/handeye.toml ] || fail "dpkg -r removed the configuration"
dpkg -P handeye
[ -f /var/lib/handeye/history.sqlite ] || fail "dpkg -P removed the history"
[ ! -e /etc/handeye/handeye.toml ] || fail "dpkg -P left the configuration"
rm -rf /var/lib/handeye
echo "the package installs, verifies and uninstalls, keeping the history"
