"""The EMVA reference GenApi (PyPI `genicam`) side of tests/genapi_corpus.rs.

stdin: JSON {"files": [path, ...], "seeds": [int, ...], "ops": [op, ...]}.
stdout: one JSON object per line: {"file", "seed", "loads", "error", "results": [...]}.

Each file's node map is connected to a simulated register port whose bytes come from the seed
(the same function as `SeededPort` in the Rust test; seed 0 = all bytes zero), and the ops (what
the driver reads and writes) run in order. A result is {"absent": true}, {"err": text} or
{"ok": value, "writes": [[address, hex], ...]} (the port writes the op made).
"""

import json
import math
import sys
import zipfile

from genicam import genapi

MASK = 0xFFFFFFFFFFFFFFFF


def seeded_byte(seed, address):
    if seed == 0:
        return 0
    x = ((address ^ seed) * 0x9E3779B97F4A7C15) & MASK
    x ^= x >> 29
    return x & 0xFF


class Port(genapi.AbstractPort):
    def __init__(self, seed):
        super().__init__()
        self.seed = seed
        self.mem = {}
        self.writes = []

    def is_open(self):
        return True

    def get_access_mode(self):
        return genapi.EAccessMode.RW

    def read(self, address, length):
        return bytes(self.mem.get(address + i, seeded_byte(self.seed, address + i))
                     for i in range(length))

    def write(self, address, value):
        data = bytes(value)
        self.writes.append([address, data.hex()])
        for i, b in enumerate(data):
            self.mem[address + i] = b


def read_text(path):
    if path.endswith(".zip"):
        with zipfile.ZipFile(path) as z:
            data = z.read(z.namelist()[0])
    else:
        with open(path, "rb") as f:
            data = f.read()
    return data.decode("utf-8").rstrip("\0")


def kind(node):
    t = type(node).__name__
    return {"IInteger": "int", "IFloat": "float", "IBoolean": "bool", "IEnumeration": "enum",
            "IString": "string", "ICommand": "command"}.get(t, t)


def number(v):
    if isinstance(v, float) and not math.isfinite(v):
        return repr(v)
    return v


def run_op(nm, port, op):
    name = op["name"]
    if not nm.has_node(name):
        return {"absent": True}
    node = nm.get_node(name)
    k = kind(node)
    port.writes = []
    what = op["op"]
    try:
        if what == "read":
            if k == "enum":
                v = node.value
            elif k in ("int", "float", "bool", "string"):
                v = number(node.value)
            else:
                return {"ok": k, "writes": []}
        elif what == "entries":
            v = sorted(e.symbolic for e in node.entries) if k == "enum" else k
        elif what == "set":
            value = op["value"]
            if k == "enum":
                node.value = str(value)
            elif k == "int":
                node.value = int(value)
            elif k == "bool":
                node.value = bool(value)
            elif k == "float":
                node.value = float(value)
            else:
                return {"err": f"{name} is a {k}"}
            v = None
        elif what == "execute":
            if k != "command":
                return {"err": f"{name} is a {k}"}
            node.execute()
            v = None
        else:
            raise ValueError(what)
        return {"ok": v, "writes": port.writes}
    except Exception as e:  # the reference's refusal is a result to compare
        return {"err": f"{type(e).__name__}: {str(e)[:200]}"}


def main():
    job = json.load(sys.stdin)
    for path in job["files"]:
        for seed in job["seeds"]:
            out = {"file": path, "seed": seed, "loads": False, "error": None, "results": []}
            try:
                nm = genapi.NodeMap()
                nm.load_xml_from_string(read_text(path))
                out["loads"] = True
            except Exception as e:
                out["error"] = f"{type(e).__name__}: {str(e)[:300]}"
            if out["loads"]:
                # One register space behind every port of the description (a camera's
                # `Device`, a GenTL module's `TLPort`/`StreamPort`, ...), as on our side.
                port = Port(seed)
                ports = [n.node.name for n in nm.nodes if type(n).__name__ == "IPort"]
                for name in ports or ["Device"]:
                    nm.connect(port, name)
                out["results"] = [run_op(nm, port, op) for op in job["ops"]]
            print(json.dumps(out), flush=True)


main()
