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
# The UR robot models (URDF and meshes, /usr/share/handeye/robots/ur) are copied at build time
# from ../shared/robots/ur beside the checkout (or $HANDEYE_ROBOTS_SRC/ur): never from the
# project tree, which holds none. Their licences allow it: BSD-3-Clause (ur/LICENSE, packaged)
# and, for the UR20 and UR30 meshes, Universal Robots' terms for graphical documentation, which
# allow a downloadable software package that includes a copy of them (section 1.4; packaged
# beside the meshes as meshes/ur20/LICENSE.txt and meshes/ur30/LICENSE.txt).
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
models=${HANDEYE_ROBOTS_SRC:-$root/../shared/robots}
for f in ur/LICENSE ur/ur5e/ur5e.urdf ur/ur20/meshes/ur20/LICENSE.txt ur/ur30/meshes/ur30/LICENSE.txt; do
  [ -f "$models/$f" ] || {
    echo "build.sh: $models/$f not found: the package carries the UR models from ../shared/robots/ur (set HANDEYE_ROBOTS_SRC to the folder that holds ur/)" >&2
    exit 1
  }
done
stage=$(mktemp -d)
trap 'rm -rf "$stage"' EXIT
# mktemp -d makes the folder 0700, and it becomes the package's `./`: dpkg would apply that
# mode to / of the machine it is installed on.
chmod 0755 "$stage"

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
cp -r "$models/ur" "$stage/usr/share/handeye/robots/ur"
find "$stage/usr/share/handeye/robots" -type d -exec chmod 0755 {} +
find "$stage/usr/share/handeye/robots" -type f -exec chmod 0644 {} +
install -D -m 0644 README.md "$stage/usr/share/doc/handeye/README.md"
cat > "$stage/usr/share/doc/handeye/copyright" <<COPYRIGHT
handeye: see README.md.

/usr/share/handeye/robots/ur: the Universal Robots arms' URDF descriptions and meshes from
UniversalRobots/Universal_Robots_ROS2_Description (tag 2.4.5), BSD-3-Clause: the licence is
/usr/share/handeye/robots/ur/LICENSE. The UR20 and UR30 meshes are also subject to Universal
Robots A/S' Terms and Conditions for Use of Graphical Documentation, included beside them:
/usr/share/handeye/robots/ur/ur20/meshes/ur20/LICENSE.txt and
/usr/share/handeye/robots/ur/ur30/meshes/ur30/LICENSE.txt.
© 2023 Universal Robots A/S. Use hereof is subject to Universal Robots A/S' Terms and
Conditions for Use of Graphical Documentation.
COPYRIGHT

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
 systemctl enable --now handeye. Carries the UR arms' models (URDF and meshes).
 Commands that write the storage (/var/lib/handeye) run as its owner:
 sudo -u handeye handeye calibrate --config /etc/handeye/handeye.toml
CONTROL
mkdir -p "$out"
deb="$out/handeye_${version}_${arch}.deb"
dpkg-deb --root-owner-group --build "$stage" "$deb" >/dev/null
echo "$deb"
