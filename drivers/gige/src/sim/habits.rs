//! Vendors' habits the simulated camera can imitate: how its description and frames differ
//! from SFNC's letter.

use super::device::SimOptions;

const TEMPLATE: &str = include_str!("camera.xml");

/// Ways real cameras describe themselves and stream that differ from SFNC's letter, which the
/// simulated camera can imitate so the driver meets them on the wire.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct VendorHabits {
    /// `TLParamsLocked` is a Boolean (five Allied Vision cameras do so) instead of an Integer.
    pub tl_params_locked_boolean: bool,
    /// Offers an Intensity component (Mono16, `ComponentIDValue` 1, enabled from power-on) and
    /// sends it as the first part of a multi-part payload, before Range; without multi-part it
    /// streams the intensity image alone (Photoneo sends its other components as chunks then,
    /// which this simulator leaves out).
    pub intensity_first: bool,
    /// Streams chunk data only (GVSP payload type 0x0004): Range, and Intensity / Confidence
    /// when enabled, each a chunk whose id is its `ComponentIDValue` (Photoneo's other mode).
    pub chunk_only: bool,
    /// No `Scan3dCoordinateSelector`: one `Scan3dCoordinateScale`/`Offset` for the camera
    /// (Nerian's SceneScan/Scarlet description).
    pub no_coordinate_selector: bool,
    /// No `Scan3dDistanceUnit` (Nerian's description).
    pub no_distance_unit: bool,
    /// Publishes `Scan3dAspectRatio`, the frame source's
    /// ([`FrameSource::aspect_ratio`](super::FrameSource::aspect_ratio)).
    pub aspect_ratio: bool,
    /// `Scan3dOutputMode` is `ProjectedC`: depth values that need the camera's coordinate maps.
    pub projected_c: bool,
}

pub(super) fn xml_for(opts: &SimOptions) -> String {
    let esc = |s: &str| {
        s.replace('&', "&amp;")
            .replace('<', "&lt;")
            .replace('"', "&quot;")
    };
    let mut xml = TEMPLATE
        .replace("@MODEL@", &esc(&opts.model))
        .replace("@VENDOR@", &esc(&opts.vendor));
    let h = &opts.habits;
    if h.intensity_first {
        xml = xml.replace(
            "<pValue>ComponentSelectorReg</pValue>",
            r#"<EnumEntry Name="Intensity" NameSpace="Standard">
      <Value>2</Value>
    </EnumEntry>
    <pValue>ComponentSelectorReg</pValue>"#,
        );
    }
    if h.projected_c {
        xml = xml.replace(
            "<pValue>Scan3dOutputModeReg</pValue>",
            r#"<EnumEntry Name="ProjectedC" NameSpace="Standard">
      <Value>2</Value>
    </EnumEntry>
    <pValue>Scan3dOutputModeReg</pValue>"#,
        );
    }
    if h.no_distance_unit {
        xml = remove_feature(&xml, "Enumeration", "Scan3dDistanceUnit");
    }
    if h.no_coordinate_selector {
        xml = remove_feature(&xml, "Enumeration", "Scan3dCoordinateSelector");
    }
    if h.aspect_ratio {
        xml = xml
            .replace(
                "<pFeature>Scan3dPrincipalPointV</pFeature>",
                "<pFeature>Scan3dPrincipalPointV</pFeature>\n    <pFeature>Scan3dAspectRatio</pFeature>",
            )
            .replace(
                "</RegisterDescription>",
                r#"  <FloatReg Name="Scan3dAspectRatio" NameSpace="Standard">
    <Address>0xA130</Address>
    <Length>8</Length>
    <AccessMode>RO</AccessMode>
    <pPort>Device</pPort>
    <Endianess>BigEndian</Endianess>
  </FloatReg>
</RegisterDescription>"#,
            );
    }
    if h.tl_params_locked_boolean {
        xml = xml.replace(
            TL_LOCKED_INTEGER,
            r#"<Boolean Name="TLParamsLocked" NameSpace="Standard">
    <Visibility>Invisible</Visibility>
    <pValue>TLParamsLockedReg</pValue>
    <OnValue>1</OnValue>
    <OffValue>0</OffValue>
  </Boolean>"#,
        );
    }
    xml
}

/// `xml` without the `kind` node `name` and the references to it.
fn remove_feature(xml: &str, kind: &str, name: &str) -> String {
    let open = format!("<{kind} Name=\"{name}\"");
    let close = format!("</{kind}>");
    let mut out = xml.replace(&format!("<pFeature>{name}</pFeature>"), "");
    if let Some(start) = out.find(&open) {
        if let Some(len) = out[start..].find(&close) {
            out.replace_range(start..start + len + close.len(), "");
        }
    }
    out
}

/// SFNC's `TLParamsLocked` in the template (replaced by a vendor's habit).
const TL_LOCKED_INTEGER: &str = r#"<Integer Name="TLParamsLocked" NameSpace="Standard">
    <Visibility>Invisible</Visibility>
    <pValue>TLParamsLockedReg</pValue>
    <Min>0</Min>
    <Max>1</Max>
  </Integer>"#;
