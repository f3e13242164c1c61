# Sourced by .ci/install.d/*.sh: installs Debian packages, or fails saying what is missing
# where there is no apt-get.
#
#   apt_install "WHAT is missing" PACKAGE...
apt_install() {
  local missing="$1"
  shift
  if ! command -v apt-get >/dev/null 2>&1; then
    echo "${0##*/}: $missing and apt-get is unavailable" >&2
    exit 1
  fi
  export DEBIAN_FRONTEND=noninteractive
  apt-get update
  apt-get install -y --no-install-recommends "$@"
}
