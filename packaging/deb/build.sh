#!/usr/bin/env bash
# Builds the Debian package of handeye with dpkg-deb: target/debian/handeye_<version>_<arch>.deb.
#
#   packaging/deb/build.sh [BINARY]
#
# BINARY defaults to target/release/handeye (built here with `cargo build --release --locked`
# when absent). The package holds the binary (/usr/bin/handeye), the systemd unit
# (/lib/systemd/system/handeye.service, derived from systemd/handeye.service: the packaged
# binary's path and the package's `handeye` system user instead of DynamicUser), an example
# configuration (/etc/handeye/handeye.toml, a conffile, storage.dir = /var/lib/handeye) and the
# maintainer scripts beside this file. The scripts neither enable nor start the service.
# The robot models are not packaged: copy the arm's folder to /usr/share/handeye/robots.
set -euo pipefail
root=$(cd "$(dirname "$0")/../.." && pwd)
cd "$root"
bin=${1:-target/release/handeye}
if [ ! -x "$bin" ]; then
  cargo build --release --locked --bin handeye
fi
version=$(sed -n 's/^version = "\(.*\)"/\1/p' Cargo.toml | head -n 1)
arch=$(dpkg --print-architecture)
out=target/debian
stage=$(mktemp -d)
trap 'rm -rf "$stage"' EXIT

install -D -m 0755 "$bin" "$stage/usr/bin/handeye"
strip --strip-debug "$stage/usr/bin/handeye" 2>/dev/null || true

# The unit: the packaged binary, a static system user (the package creates it, so the token
# file and the storage have an owner an operator can see), the models under /usr/share.
install -d "$stage/lib/systemd/system"
sed -e 's|^ExecStart=/usr/local/bin/handeye |ExecStart=/usr/bin/handeye |' \
    -e 's|^DynamicUser=yes$|User=handeye\nGroup=handeye|' \
    -e 's|^Environment=HANDEYE_ROBOTS=/usr/local/share/handeye/robots$|Environment=HANDEYE_ROBOTS=/usr/share/handeye/robots|' \
    systemd/handeye.service > "$stage/lib/systemd/system/handeye.service"
for want in 'ExecStart=/usr/bin/handeye ' '^User=handeye$' 'HANDEYE_ROBOTS=/usr/share/handeye/robots'; do
  grep -q "$want" "$stage/lib/systemd/system/handeye.service" || {
    echo "build.sh: the unit derived from systemd/handeye.service lacks $want" >&2
    exit 1
  }
done

# The example configuration, with the packaged storage.
install -d "$stage/etc/handeye"
sed -e 's|^dir = "handeye-data" .*|dir = "/var/lib/handeye"          # the package'"'"'s storage (the unit may write only there)|' \
    config/handeye.example.toml > "$stage/etc/handeye/handeye.toml"
grep -q '^dir = "/var/lib/handeye"' "$stage/etc/handeye/handeye.toml" || {
  echo "build.sh: storage.dir not found in config/handeye.example.toml" >&2
  exit 1
}
install -d "$stage/usr/share/handeye/robots"
install -D -m 0644 README.md "$stage/usr/share/doc/handeye/README.md"

install -d "$stage/DEBIAN"
for s in postinst postrm; do
  install -m 0755 "packaging/deb/$s" "$stage/DEBIAN/$s"
done
echo /etc/handeye/handeye.toml > "$stage/DEBIAN/conffiles"
size=$(du -sk --exclude=DEBIAN "$stage" | cut -f1)
cat > "$stage/DEBIAN/control" <<CONTROL
Package: handeye
Version: $version
Architecture: $arch
Maintainer: handeye developers <handeye@localhost>
Installed-Size: $size
Depends: libc6, adduser
Section: science
Priority: optional
Description: target-free hand-eye calibration for a Universal Robots arm's 3D camera
 Calibrates the wrist (or fixed) 3D camera of a UR arm against the robot's own CAD
 model from one scan, writes the result back to the controller, and runs as a daemon
 with drift checks, an HTTP API, a web page and Prometheus metrics. The service is
 installed but neither enabled nor started: edit /etc/handeye/handeye.toml, then
 systemctl enable --now handeye.
CONTROL
mkdir -p "$out"
deb="$out/handeye_${version}_${arch}.deb"
dpkg-deb --root-owner-group --build "$stage" "$deb" >/dev/null
echo "$deb"
