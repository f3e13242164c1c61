"""GenTL reference reads with harvesters (a GenTL consumer we did not write), for the e2e tests.

  gentl_harvesters.py probe CTI            -> JSON list of the producer's devices
  gentl_harvesters.py capture CTI OUT [N]  -> OUT: width, height (uint32 LE), then width*height
                                             points x, y, z as float32 LE in metres (NaN for
                                             invalid), from device N (default 0)

The capture enables the Range component (ComponentSelector = Range, ComponentEnable = True) and
converts each coordinate as the handeye decoders document: in float64,
(raw * Scan3dCoordinateScale + Scan3dCoordinateOffset) * metres per Scan3dDistanceUnit, then
rounded once to float32.
"""
import json
import struct
import sys

import numpy as np
from harvesters.core import Harvester

UNIT_M = {"Millimeter": 0.001, "Inch": 0.0254, "Meter": 1.0}


def probe(cti):
    h = Harvester()
    h.add_file(cti)
    h.update()
    out = [
        {"id": d.id_, "vendor": d.vendor, "model": d.model, "serial": d.serial_number}
        for d in h.device_info_list
    ]
    h.reset()
    print(json.dumps(out))


def capture(cti, out, index):
    h = Harvester()
    h.add_file(cti)
    h.update()
    ia = h.create(index)
    try:
        nm = ia.remote_device.node_map
        nm.ComponentSelector.value = "Range"
        nm.ComponentEnable.value = True
        unit = UNIT_M[nm.Scan3dDistanceUnit.value]
        scale, offset = [], []
        for c in ("CoordinateA", "CoordinateB", "CoordinateC"):
            nm.Scan3dCoordinateSelector.value = c
            scale.append(nm.Scan3dCoordinateScale.value)
            offset.append(nm.Scan3dCoordinateOffset.value)
        ia.start()
        with ia.fetch(timeout=10) as buf:
            planes = {c.data_format: c for c in buf.payload.components}
            a, b, c = (planes[f] for f in ("Coord3D_A32f", "Coord3D_B32f", "Coord3D_C32f"))
            w, hgt = a.width, a.height
            xyz = np.stack(
                [
                    ((p.data.astype(np.float64) * scale[k] + offset[k]) * unit).astype(np.float32)
                    for k, p in enumerate((a, b, c))
                ],
                axis=1,
            )
        ia.stop()
    finally:
        ia.destroy()
        h.reset()
    with open(out, "wb") as f:
        f.write(struct.pack("<II", w, hgt))
        f.write(xyz.astype("<f4").tobytes())


if __name__ == "__main__":
    if sys.argv[1] == "probe":
        probe(sys.argv[2])
    else:
        capture(sys.argv[2], sys.argv[3], int(sys.argv[4]) if len(sys.argv) > 4 else 0)
