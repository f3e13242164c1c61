//! Issue 44: bounds that come through a Converter/IntConverter, and nodes behind
//! `pIsAvailable = false`, as the EMVA reference GenApi (PyPI `genicam`) has them. Our side
//! always runs; the reference's verdicts on the same descriptions are checked too when
//! `$REPO/.venv` has `genicam` (required when env `CI` is set).

mod common;
use common::reference_python;

use std::collections::HashMap;
use std::process::Command;

use handeye_gige::genicam::NodeMap;

const HEAD: &str = r#"<?xml version="1.0" encoding="utf-8"?>
<RegisterDescription ModelName="T" VendorName="V" ToolTip="t" StandardNameSpace="None" SchemaMajorVersion="1" SchemaMinorVersion="1" SchemaSubMinorVersion="0" MajorVersion="1" MinorVersion="0" SubMinorVersion="0" ProductGuid="11111111-1111-1111-1111-111111111111" VersionGuid="11111111-1111-1111-1111-111111111112" xmlns="http://www.genicam.org/GenApi/Version_1_1" xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance" xsi:schemaLocation="http://www.genicam.org/GenApi/Version_1_1 http://www.genicam.org/GenApi/GenApiSchema_Version_1_1.xsd">
"#;

fn reg(name: &str, address: u32, mode: &str, extra: &str) -> String {
    format!(
        "<IntReg Name=\"{name}\">{extra}<Address>{address:#x}</Address><Length>4</Length>\
         <AccessMode>{mode}</AccessMode><pPort>Device</pPort><Sign>Unsigned</Sign>\
         <Endianess>LittleEndian</Endianess></IntReg>\n"
    )
}

/// A description of `body` whose root category lists `feature`.
fn xml(feature: &str, body: &str) -> String {
    format!(
        "{HEAD}<Category Name=\"Root\" NameSpace=\"Standard\"><pFeature>{feature}</pFeature>\
         </Category>\n{body}<Port Name=\"Device\"/>\n</RegisterDescription>\n"
    )
}

/// A real U3V camera's shape: a Float `ExposureTime` without its own bounds, whose value goes
/// through a Converter to an Integer with pMin/pMax (raw units of 10 µs: 10..=100 raw is
/// 100..=1000 µs); an IntConverter the same way; a decreasing Converter.
fn converters() -> String {
    xml(
        "ExposureTime",
        &format!(
            r#"<Float Name="ExposureTime"><pValue>ExposureConv</pValue><Unit>us</Unit></Float>
<Converter Name="ExposureConv"><FormulaTo>FROM/10</FormulaTo><FormulaFrom>TO*10</FormulaFrom><pValue>ExposureRaw</pValue><Slope>Increasing</Slope></Converter>
<Integer Name="ExposureRaw"><pValue>RawReg</pValue><pMin>MinReg</pMin><pMax>MaxReg</pMax></Integer>
<Integer Name="Doubled"><pValue>DoubledConv</pValue></Integer>
<IntConverter Name="DoubledConv"><FormulaTo>FROM/2</FormulaTo><FormulaFrom>TO*2</FormulaFrom><pValue>ExposureRaw</pValue><Slope>Increasing</Slope></IntConverter>
<Converter Name="Decreasing"><FormulaTo>1000-FROM</FormulaTo><FormulaFrom>1000-TO</FormulaFrom><pValue>ExposureRaw</pValue><Slope>Automatic</Slope></Converter>
{}{}{}"#,
            reg("RawReg", 0x100, "RW", ""),
            reg("MinReg", 0x104, "RO", ""),
            reg("MaxReg", 0x108, "RO", "")
        ),
    )
}

/// A register behind `pIsAvailable = false` and what depends on it.
fn unavailable() -> String {
    xml(
        "ViaValue",
        &format!(
            r#"<Integer Name="Avail"><Value>0</Value></Integer>
<Integer Name="ViaValue"><pValue>R</pValue></Integer>
<IntSwissKnife Name="ViaSwissKnife"><pVariable Name="X">R</pVariable><Formula>X*2</Formula></IntSwissKnife>
<Converter Name="ViaConverterVariable"><pVariable Name="X">R</pVariable><FormulaTo>FROM</FormulaTo><FormulaFrom>TO*X</FormulaFrom><pValue>Three</pValue></Converter>
<Integer Name="Three"><Value>3</Value></Integer>
<Integer Name="ViaMax"><pValue>Three</pValue><pMax>R</pMax></Integer>
<Enumeration Name="ViaEnum"><EnumEntry Name="A"><Value>0</Value></EnumEntry><EnumEntry Name="B"><Value>1</Value></EnumEntry><pValue>R</pValue></Enumeration>
<StructReg Comment="s"><pIsAvailable>Avail</pIsAvailable><Address>0x200</Address><Length>4</Length><AccessMode>RW</AccessMode><pPort>Device</pPort><Endianess>LittleEndian</Endianess>
<StructEntry Name="ViaStruct"><Bit>0</Bit></StructEntry></StructReg>
{}"#,
            reg("R", 0x100, "RW", "<pIsAvailable>Avail</pIsAvailable>")
        ),
    )
}

/// Registers as little-endian u32 words; writes land in memory.
#[derive(Debug, Default)]
struct Port(HashMap<i64, u8>);

impl Port {
    fn with(words: &[(i64, u32)]) -> Self {
        let mut p = Port::default();
        for &(a, v) in words {
            for (i, b) in v.to_le_bytes().into_iter().enumerate() {
                p.0.insert(a + i as i64, b);
            }
        }
        p
    }
}

type DevResult = Result<(), Box<dyn std::error::Error + Send + Sync>>;

impl cameleon_genapi::Device for Port {
    fn read_mem(&mut self, address: i64, buf: &mut [u8]) -> DevResult {
        for (i, b) in buf.iter_mut().enumerate() {
            *b = self.0.get(&(address + i as i64)).copied().unwrap_or(0);
        }
        Ok(())
    }
    fn write_mem(&mut self, address: i64, data: &[u8]) -> DevResult {
        for (i, b) in data.iter().enumerate() {
            self.0.insert(address + i as i64, *b);
        }
        Ok(())
    }
}

fn converter_port() -> Port {
    Port::with(&[(0x100, 50), (0x104, 10), (0x108, 100)])
}

/// Issue 44: a Float ExposureTime without pMin/pMax whose bounds come through pValue →
/// Converter → Integer with pMin/pMax was written out of range (the Converter had no bounds:
/// f64::MIN..=f64::MAX) where the reference refuses; IntConverter the same.
#[test]
fn issue_44_converter_bounds_are_followed_as_the_reference_does() {
    let mut nm = NodeMap::from_xml(&converters()).expect("loads");
    let mut p = converter_port();
    let float_bounds = |nm: &mut NodeMap, p: &mut Port, n: &str| nm.allowed(p, n);
    assert_eq!(
        float_bounds(&mut nm, &mut p, "ExposureTime").as_deref(),
        Some("100..=1000 us")
    );
    assert_eq!(
        float_bounds(&mut nm, &mut p, "ExposureConv").as_deref(),
        Some("100..=1000")
    );
    assert_eq!(
        float_bounds(&mut nm, &mut p, "Decreasing").as_deref(),
        Some("900..=990")
    );
    assert_eq!(
        float_bounds(&mut nm, &mut p, "Doubled").as_deref(),
        Some("20..=200")
    );
    let e = nm
        .set_float(&mut p, "ExposureTime", 5e6)
        .expect_err("out of range");
    assert!(e.to_string().contains("outside 100..=1000"), "{e}");
    assert_eq!(p.0.get(&0x100), Some(&50), "nothing written");
    nm.set_float(&mut p, "ExposureTime", 1000.0)
        .expect("in range");
    assert_eq!(p.0.get(&0x100), Some(&100), "raw 100 written");
    assert!(nm.set_float(&mut p, "ExposureConv", 5000.0).is_err());
    assert!(nm.set_float(&mut p, "Decreasing", 100.0).is_err());
    assert!(nm.set_integer(&mut p, "Doubled", 500).is_err());
    assert!(nm.set_integer(&mut p, "DoubledConv", 500).is_err());
    nm.set_integer(&mut p, "Doubled", 40).expect("in range");
    assert_eq!(p.0.get(&0x100), Some(&20));
}

/// Issue 44: what depends on a register behind `pIsAvailable = false` is not accessible (the
/// reference: "Node is not readable"), through pValue, a SwissKnife's or Converter's
/// pVariable, a pMax, an enumeration and a StructReg's entries.
#[test]
fn issue_44_nodes_behind_unavailable_registers_are_not_accessible() {
    let mut nm = NodeMap::from_xml(&unavailable()).expect("loads");
    let mut p = Port::with(&[(0x100, 7), (0x200, 1)]);
    for n in ["R", "ViaValue", "ViaSwissKnife", "ViaMax", "ViaStruct"] {
        let r = nm.integer(&mut p, n);
        assert!(r.is_err(), "{n} read as {r:?}");
    }
    assert!(nm.float(&mut p, "ViaConverterVariable").is_err());
    assert!(nm.enum_symbol(&mut p, "ViaEnum").is_err());
    assert!(nm.set_integer(&mut p, "ViaMax", 2).is_err());
    for n in ["ViaValue", "ViaMax", "ViaEnum"] {
        assert_eq!(
            nm.state(&mut p, n).expect("present").access,
            "not available",
            "{n}"
        );
    }
}

const ORACLE: &str = r#"
import sys, json
from genicam import genapi
class Port(genapi.AbstractPort):
    def __init__(self, mem): super().__init__(); self.mem = mem
    def is_open(self): return True
    def get_access_mode(self): return genapi.EAccessMode.RW
    def read(self, a, n): return bytes(self.mem.get(a + i, 0) for i in range(n))
    def write(self, a, v):
        for i, b in enumerate(bytes(v)): self.mem[a + i] = b
def load(path, words):
    nm = genapi.NodeMap(); nm.load_xml_from_string(open(path).read())
    mem = {}
    for a, v in words:
        for i, b in enumerate(v.to_bytes(4, "little")): mem[a + i] = b
    p = Port(mem); nm.connect(p, "Device"); return nm, p
out = {}
nm, p = load(sys.argv[1], [(0x100, 50), (0x104, 10), (0x108, 100)])
for n in ["ExposureTime", "ExposureConv", "Decreasing", "Doubled"]:
    node = nm.get_node(n); out[n] = [node.min, node.max]
for n, v in [("ExposureTime", 5e6), ("ExposureConv", 5000.0), ("Decreasing", 100.0),
             ("Doubled", 500), ("DoubledConv", 500)]:
    try:
        nm.get_node(n).value = v; out["set " + n] = "ok"
    except Exception as e:
        out["set " + n] = type(e).__name__
nm, p = load(sys.argv[2], [(0x100, 7), (0x200, 1)])
for n in ["R", "ViaValue", "ViaSwissKnife", "ViaMax", "ViaStruct", "ViaConverterVariable", "ViaEnum"]:
    try:
        nm.get_node(n).value; out["read " + n] = "ok"
    except Exception as e:
        out["read " + n] = type(e).__name__
print(json.dumps(out))
"#;

/// The expectations above are the reference's: its bounds and refusals on the same files.
#[test]
fn issue_44_the_expectations_are_the_references() {
    let Some(python) = reference_python() else {
        return;
    };
    let dir = std::env::temp_dir().join(format!("handeye-genapi-bounds-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("tmp");
    let (a, b) = (dir.join("conv.xml"), dir.join("avail.xml"));
    std::fs::write(&a, converters()).expect("write");
    std::fs::write(&b, unavailable()).expect("write");
    let out = Command::new(&python)
        .args(["-c", ORACLE])
        .arg(&a)
        .arg(&b)
        .output()
        .expect("python");
    let _ = std::fs::remove_dir_all(&dir);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let got: serde_json::Value = serde_json::from_slice(&out.stdout).expect("json");
    let want = serde_json::json!({
        "ExposureTime": [100.0, 1000.0], "ExposureConv": [100.0, 1000.0],
        "Decreasing": [900.0, 990.0], "Doubled": [20, 200],
        "set ExposureTime": "OutOfRangeException", "set ExposureConv": "OutOfRangeException",
        "set Decreasing": "OutOfRangeException", "set Doubled": "OutOfRangeException",
        "set DoubledConv": "OutOfRangeException",
        "read R": "AccessException", "read ViaValue": "AccessException",
        "read ViaSwissKnife": "AccessException", "read ViaMax": "AccessException",
        "read ViaStruct": "AccessException", "read ViaConverterVariable": "AccessException",
        "read ViaEnum": "AccessException",
    });
    assert_eq!(got, want);
}
