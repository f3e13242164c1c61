#!/usr/bin/env python3
"""Capture one Zivid 3D frame and write it as an organized binary PLY in metres.

Example capture command for handeye's `exec` camera backend, which runs it once per frame:

    handeye camera capture --exec "python3 config/zivid_capture.py {out}" --timeout-s 60

handeye replaces `{out}` with the path to write (also in $HANDEYE_OUTPUT) and `{frame}` with the
0-based frame index (also in $HANDEYE_FRAME); when an exposure is requested, $HANDEYE_EXPOSURE_US
holds it in microseconds. Exit status 0 means the file was written; anything else is reported by
handeye together with the end of what this script printed on stderr.

UNTESTED ON HARDWARE. This script has never been run here: the machines that develop and test
handeye have neither the Zivid SDK nor a Zivid camera. handeye's tests only check that it is valid
Python. It follows the zivid-python API of SDK 2.x (zivid.Application, connect_camera,
zivid.Settings with acquisitions, camera.capture_3d / camera.capture, point_cloud().copy_data)
and needs `pip install zivid numpy` on top of an installed Zivid SDK. Check it against your SDK
version before relying on it.

Output (what handeye's PLY reader expects):
- binary_little_endian PLY, `float x`, `float y`, `float z`, in METRES (Zivid gives millimetres;
  this script divides by 1000 and says `comment unit m`);
- organized: `obj_info width W` and `obj_info height H`, one vertex per pixel, row-major;
- invalid pixels are NaN (as Zivid reports them);
- camera frame = Zivid's camera frame (x right, y down, z forward: the OpenCV convention).

Options:
    --settings FILE.yml   capture settings exported from Zivid Studio (default: one acquisition
                          with the SDK's defaults, exposure from $HANDEYE_EXPOSURE_US if set)
    --serial SERIAL       which camera, when several are connected (default: the first one)
"""

import argparse
import datetime
import os
import sys


def _write_ply(path, xyz_m):
    """Writes an H x W x 3 float32 array (metres, NaN = invalid) as an organized binary PLY."""
    import numpy as np

    height, width, _ = xyz_m.shape
    header = (
        "ply\n"
        "format binary_little_endian 1.0\n"
        "comment written by handeye config/zivid_capture.py\n"
        "comment unit m\n"
        f"obj_info width {width}\n"
        f"obj_info height {height}\n"
        f"element vertex {width * height}\n"
        "property float x\n"
        "property float y\n"
        "property float z\n"
        "end_header\n"
    )
    data = np.ascontiguousarray(xyz_m, dtype="<f4").reshape(-1, 3)
    # Write next to the target, then rename: handeye never sees a half-written file.
    tmp = f"{path}.partial"
    with open(tmp, "wb") as f:
        f.write(header.encode("ascii"))
        f.write(data.tobytes())
    os.replace(tmp, path)


def _settings(zivid, settings_file):
    if settings_file:
        return zivid.Settings.load(settings_file)
    acquisition = zivid.Settings.Acquisition()
    exposure_us = os.environ.get("HANDEYE_EXPOSURE_US")
    if exposure_us:
        acquisition.exposure_time = datetime.timedelta(microseconds=int(exposure_us))
    return zivid.Settings(acquisitions=[acquisition])


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "out",
        nargs="?",
        default=os.environ.get("HANDEYE_OUTPUT"),
        help="PLY file to write (default: $HANDEYE_OUTPUT)",
    )
    parser.add_argument("--settings", help="Zivid settings .yml file")
    parser.add_argument("--serial", help="camera serial number")
    args = parser.parse_args()
    if not args.out:
        parser.error("no output path: pass it as an argument or set HANDEYE_OUTPUT")

    try:
        import zivid
    except ImportError as e:
        print(
            f"cannot import zivid ({e}); install the Zivid SDK, then `pip install zivid numpy`",
            file=sys.stderr,
        )
        return 2

    app = zivid.Application()
    print("connecting to the Zivid camera", file=sys.stderr)
    if args.serial:
        camera = app.connect_camera(serial_number=args.serial)
    else:
        camera = app.connect_camera()
    settings = _settings(zivid, args.settings)
    print(f"capturing frame {os.environ.get('HANDEYE_FRAME', '0')}", file=sys.stderr)
    # SDK 2.12+ has capture_3d; older versions only capture.
    capture = getattr(camera, "capture_3d", None) or camera.capture
    with capture(settings) as frame:
        xyz_mm = frame.point_cloud().copy_data("xyz")  # H x W x 3 float32, mm, NaN invalid
    _write_ply(args.out, xyz_mm / 1000.0)
    print(f"wrote {args.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
