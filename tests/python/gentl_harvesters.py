"""GenTL reference reads with harvesters (a GenTL consumer we did not write), for the e2e tests.

  gentl_harvesters.py probe CTI            -> JSON list of the producer's devices
  gentl_harvesters.py modules CTI         -> JSON: the system, interface, device and data stream
                                             node maps' SFNC features as harvesters reads them,
                                             after setting StreamBufferHandlingMode, and the
                                             parts of one buffer captured then
  gentl_harvesters.py capture CTI OUT [N] [--confidence]
                                          -> OUT: width, height (uint32 LE), then width*height
                                             points x, y, z as float32 LE in metres (NaN for
                                             invalid), from device N (default 0); stdout: JSON
                                             list of the buffer's parts (data format, size)

The capture enables the Range component (ComponentSelector = Range, ComponentEnable = True; with
--confidence also Confidence) and converts each coordinate as the handeye decoders document: in
float64, (raw * Scan3dCoordinateScale + Scan3dCoordinateOffset) * metres per Scan3dDistanceUnit,
then rounded once to float32. Range may be planar (Coord3D_A32f/B32f/C32f parts, viky) or
packed (one Coord3D_ABC32f part, handeye's producer).
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


def capture(cti, out, index, confidence):
    h = Harvester()
    h.add_file(cti)
    h.update()
    ia = h.create(index)
    try:
        nm = ia.remote_device.node_map
        nm.ComponentSelector.value = "Range"
        nm.ComponentEnable.value = True
        if confidence:
            nm.ComponentSelector.value = "Confidence"
            nm.ComponentEnable.value = True
        unit = UNIT_M[nm.Scan3dDistanceUnit.value]
        scale, offset = [], []
        for c in ("CoordinateA", "CoordinateB", "CoordinateC"):
            nm.Scan3dCoordinateSelector.value = c
            scale.append(nm.Scan3dCoordinateScale.value)
            offset.append(nm.Scan3dCoordinateOffset.value)
        ia.start()
        with ia.fetch(timeout=10) as buf:
            parts = [
                {"format": c.data_format, "width": c.width, "height": c.height}
                for c in buf.payload.components
            ]
            planes = {c.data_format: c for c in buf.payload.components}
            if "Coord3D_ABC32f" in planes:
                packed = planes["Coord3D_ABC32f"]
                w, hgt = packed.width, packed.height
                coords = packed.data.reshape(-1, 3).T
            else:
                a, b, c = (planes[f] for f in ("Coord3D_A32f", "Coord3D_B32f", "Coord3D_C32f"))
                w, hgt = a.width, a.height
                coords = [a.data, b.data, c.data]
            xyz = np.stack(
                [
                    ((p.astype(np.float64) * scale[k] + offset[k]) * unit).astype(np.float32)
                    for k, p in enumerate(coords)
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
    print(json.dumps(parts))


def modules(cti):
    h = Harvester()
    h.add_file(cti)
    h.update()
    ia = h.create(0)
    out = {}
    try:
        wanted = {
            "system": (ia.system, ["TLVendorName", "TLModelName", "TLID", "TLVersion", "TLType"]),
            "interface": (ia.interface, ["InterfaceID", "InterfaceType", "DeviceAccessStatus"]),
            "device": (ia.device, ["DeviceID", "DeviceVendorName", "DeviceModelName",
                                   "DeviceSerialNumber", "DeviceAccessStatus"]),
            "stream": (ia.data_streams[0], ["StreamID", "StreamType", "StreamBufferHandlingMode",
                                            "StreamAnnounceBufferMinimum"]),
        }
        for module, (m, names) in wanted.items():
            out[module] = {n: getattr(m.node_map, n).value for n in names}
        ds = ia.data_streams[0].node_map
        ds.StreamBufferHandlingMode.value = "OldestFirst"
        out["set"] = ds.StreamBufferHandlingMode.value
        try:
            ds.StreamBufferHandlingMode.value = "NewestOnly"
            out["newest_only"] = "accepted"
        except Exception as e:
            out["newest_only"] = type(e).__name__
        nm = ia.remote_device.node_map
        nm.ComponentSelector.value = "Range"
        nm.ComponentEnable.value = True
        ia.start()
        out["announced"] = ds.StreamAnnouncedBufferCount.value
        with ia.fetch(timeout=10) as buf:
            out["parts"] = [c.data_format for c in buf.payload.components]
        ia.stop()
    finally:
        ia.destroy()
        h.reset()
    print(json.dumps(out))


if __name__ == "__main__":
    if sys.argv[1] == "probe":
        probe(sys.argv[2])
    elif sys.argv[1] == "modules":
        modules(sys.argv[2])
    else:
        rest = sys.argv[4:]
        confidence = "--confidence" in rest
        rest = [a for a in rest if a != "--confidence"]
        capture(sys.argv[2], sys.argv[3], int(rest[0]) if rest else 0, confidence)
