//! The simulated camera's XML loads in the EMVA reference GenApi (PyPI `genicam`, installed in
//! `$REPO/.venv` by `.ci/install.d/aravis.sh`). Skips with a message without the venv, unless
//! env `CI` is set.

mod common;
use common::reference_python;

use std::process::Command;

use handeye_gige::sim::{SimCamera, SimOptions};

const SCRIPT: &str = r#"
import sys
from genicam import genapi
nm = genapi.NodeMap()
nm.load_xml_from_string(open(sys.argv[1]).read())
names = {n.node.name for n in nm.nodes}
need = ["Width", "Height", "PixelFormat", "PayloadSize", "AcquisitionMode", "AcquisitionStart",
        "AcquisitionStop", "TLParamsLocked", "Scan3dCoordinateScale", "Scan3dInvalidDataValue",
        "Scan3dFocalLength", "ComponentSelector", "GevSCPSPacketSize", "DeviceVendorName"]
missing = [n for n in need if n not in names]
assert not missing, missing
entries = [e.symbolic for e in nm.get_node("PixelFormat").entries]
assert sorted(entries) == ["Coord3D_ABC32f", "Coord3D_C16"], entries
print("genicam-ok", len(names))
"#;

#[test]
fn simulated_camera_xml_passes_the_emva_reference_genapi() {
    let Some(python) = reference_python() else {
        return;
    };
    let dir = std::env::temp_dir().join(format!("handeye-gige-xml-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("tmp");
    let xml = dir.join("sim.xml");
    std::fs::write(
        &xml,
        SimCamera::xml(&SimOptions {
            vendor: "V & Co <test>".into(),
            ..SimOptions::default()
        }),
    )
    .expect("write");
    let out = Command::new(&python)
        .args(["-c", SCRIPT])
        .arg(&xml)
        .output()
        .expect("python");
    let _ = std::fs::remove_dir_all(&dir);
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        out.status.success() && text.contains("genicam-ok"),
        "{text}"
    );
}
