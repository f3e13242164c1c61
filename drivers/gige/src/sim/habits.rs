//! Vendors' habits the simulated camera can imitate: how its description and frames differ
//! from SFNC's letter.

use super::device::SimOptions;
use crate::decode::pfnc;

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
    /// `Scan3dOutputMode` is `ProjectedC` (SICK Visionary's depth maps; for an XYZ format
    /// this is a wrong setting the driver refuses).
    pub projected_c: bool,
    /// A multi-part payload carries one more part after the components: chunk data (Photoneo:
    /// n components, n + 1 parts; SICK sends its intrinsics as chunks).
    pub chunk_part: bool,
    /// `TriggerSelector` (FrameStart), `TriggerMode`, `TriggerSource` and `TriggerSoftware`,
    /// with `TriggerMode = On`, `TriggerSource = Software` from power-on (as Photoneo's examples
    /// leave the camera): while on, a frame is sent only per `TriggerSoftware`.
    pub software_trigger: bool,
    /// Lucid Helios2: `PixelFormat` offers Coord3D_ABCY16 (power-on), Coord3D_ABC16 and
    /// Coord3D_C16 with 0.25 mm steps, A and B offset by −8192 mm, 65535 the invalid value of
    /// each coordinate; intrinsics only as `CalibFocalLengthX/Y`, `CalibOpticalCenterX/Y`.
    pub lucid: bool,
    /// `Scan3dCoordinateSelector` lists only `CoordinateC` (a depth-only camera).
    pub only_coordinate_c: bool,
    /// Basler blaze: `Scan3dInvalidDataFlag`/`Value` per coordinate; Coord3D_ABC32f marks an
    /// invalid point (0, 0, 0) and flags only C (value 0), so a valid X or Y of 0 is a point.
    pub per_coordinate_invalid: bool,
    /// `GenDCStreamingMode` (Off, On), On from power-on: the GenTL producer then labels its
    /// buffers GenDC containers (payload type 11; the content stays multi-part, enough for a
    /// consumer's refusal). The GigE Vision streamer ignores it.
    pub gendc: bool,
}

/// How the simulated camera codes each coordinate of a pixel format: `raw · scale + offset`
/// millimetres, and the raw value of an invalid point (`None`: not flagged, sent as 0).
#[derive(Debug, Clone, Copy)]
pub(super) struct Coding {
    pub(super) scale: [f64; 3],
    pub(super) offset: [f64; 3],
    pub(super) invalid: [Option<f64>; 3],
}

/// The same coding: bit for bit (a NaN marker equals itself, so a frame rendered under one
/// coding is recognised as current).
impl PartialEq for Coding {
    fn eq(&self, other: &Self) -> bool {
        let bits = |c: &Coding| {
            (
                c.scale.map(f64::to_bits),
                c.offset.map(f64::to_bits),
                c.invalid.map(|v| v.map(f64::to_bits)),
            )
        };
        bits(self) == bits(other)
    }
}

/// Depth steps of Coord3D_C16, mm.
pub(super) const C16_SCALE_MM: f64 = 0.1;
/// Lucid's steps of its 16-bit formats, mm, and the A/B offset that centres them.
const LUCID_SCALE_MM: f64 = 0.25;
const LUCID_OFFSET_MM: f64 = -8192.0;

/// The vendors the simulated camera imitates as a whole (`handeye sim camera --imitate`),
/// each with what it imitates (imitated from the vendors' public documentation and examples,
/// not measured on their cameras).
pub const IMITATIONS: &[(&str, &str)] = &[
    (
        "photoneo",
        "Photoneo: intensity first, chunk data as a last part, TriggerMode On with a software source",
    ),
    (
        "lucid",
        "Lucid Helios2: Coord3D_ABCY16 (also ABC16, C16) with CalibFocalLength*/CalibOpticalCenter*",
    ),
    (
        "sick",
        "SICK Visionary: Coord3D_C16 in ProjectedC, only CoordinateC, aspect ratio, chunk data",
    ),
    (
        "blaze",
        "Basler blaze: Scan3dInvalidDataFlag/Value per coordinate (only C flagged)",
    ),
    (
        "gendc",
        "a camera streaming GenDC containers (GenDCStreamingMode On; GenTL producer only)",
    ),
];

impl VendorHabits {
    /// The habits of one of the [`IMITATIONS`] (`None` for another name).
    pub fn imitating(vendor: &str) -> Option<Self> {
        let d = Self::default();
        Some(match vendor {
            "photoneo" => Self {
                intensity_first: true,
                chunk_part: true,
                software_trigger: true,
                ..d
            },
            "lucid" => Self { lucid: true, ..d },
            "sick" => Self {
                projected_c: true,
                only_coordinate_c: true,
                aspect_ratio: true,
                chunk_part: true,
                intensity_first: true,
                ..d
            },
            "blaze" => Self {
                per_coordinate_invalid: true,
                ..d
            },
            "gendc" => Self { gendc: true, ..d },
            _ => return None,
        })
    }

    /// The `PixelFormat` entries (PFNC codes), the power-on one first.
    pub(super) fn pixel_formats(&self) -> &'static [u32] {
        if self.lucid {
            &[pfnc::COORD3D_ABCY16, pfnc::COORD3D_ABC16, pfnc::COORD3D_C16]
        } else {
            &[pfnc::COORD3D_ABC32F, pfnc::COORD3D_C16]
        }
    }

    /// How `pixel_format`'s coordinates are coded.
    pub(super) fn coding(&self, pixel_format: u32) -> Coding {
        match pixel_format {
            pfnc::COORD3D_C16 => Coding {
                scale: [
                    1.0,
                    1.0,
                    if self.lucid {
                        LUCID_SCALE_MM
                    } else {
                        C16_SCALE_MM
                    },
                ],
                offset: [0.0; 3],
                invalid: [Some(if self.lucid { 65535.0 } else { 0.0 }); 3],
            },
            pfnc::COORD3D_ABC16 | pfnc::COORD3D_ABCY16 => Coding {
                scale: [LUCID_SCALE_MM; 3],
                offset: [LUCID_OFFSET_MM, LUCID_OFFSET_MM, 0.0],
                invalid: [Some(65535.0); 3],
            },
            _ if self.per_coordinate_invalid => Coding {
                scale: [1.0; 3],
                offset: [0.0; 3],
                invalid: [None, None, Some(0.0)],
            },
            _ => Coding {
                scale: [1.0; 3],
                offset: [0.0; 3],
                invalid: [Some(f64::NAN); 3],
            },
        }
    }
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
    if h.lucid {
        xml = lucid_xml(xml);
    }
    if h.only_coordinate_c {
        for k in ["A", "B"] {
            xml = remove_entry(&xml, &format!("Coordinate{k}"));
        }
    }
    if h.software_trigger {
        xml = xml
            .replace(
                "<pFeature>AcquisitionFrameRate</pFeature>",
                "<pFeature>AcquisitionFrameRate</pFeature>\n    <pFeature>TriggerSelector</pFeature>\n    \
                 <pFeature>TriggerMode</pFeature>\n    <pFeature>TriggerSource</pFeature>\n    \
                 <pFeature>TriggerSoftware</pFeature>",
            )
            .replace("</RegisterDescription>", TRIGGER_XML);
    }
    if h.gendc {
        xml = xml
            .replace(
                "<pFeature>AcquisitionFrameRate</pFeature>",
                "<pFeature>AcquisitionFrameRate</pFeature>\n    <pFeature>GenDCStreamingMode</pFeature>",
            )
            .replace("</RegisterDescription>", GENDC_XML);
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

/// `xml` without the enumeration entry `name`.
fn remove_entry(xml: &str, name: &str) -> String {
    let mut out = xml.to_owned();
    if let Some(start) = out.find(&format!("<EnumEntry Name=\"{name}\"")) {
        if let Some(len) = out[start..].find("</EnumEntry>") {
            out.replace_range(start..start + len + "</EnumEntry>".len(), "");
        }
    }
    out
}

/// Lucid's formats and its factory-calibration features in place of SFNC's intrinsics.
fn lucid_xml(xml: String) -> String {
    let entry = |name: &str, code: u32| {
        format!(
            "<EnumEntry Name=\"{name}\" NameSpace=\"Custom\">\n      <Value>{code:#010X}</Value>\n    </EnumEntry>\n    "
        )
    };
    let mut xml = remove_entry(&xml, "Coord3D_ABC32f");
    let c16 = xml
        .find("<EnumEntry Name=\"Coord3D_C16\"")
        .unwrap_or(xml.len());
    xml.insert_str(
        c16,
        &(entry("Coord3D_ABCY16", pfnc::COORD3D_ABCY16)
            + &entry("Coord3D_ABC16", pfnc::COORD3D_ABC16)),
    );
    xml.replace(
        "<pFeature>Scan3dFocalLength</pFeature>",
        "<pFeature>CalibFocalLengthX</pFeature>\n    <pFeature>CalibFocalLengthY</pFeature>",
    )
    .replace(
        "<pFeature>Scan3dPrincipalPointU</pFeature>",
        "<pFeature>CalibOpticalCenterX</pFeature>",
    )
    .replace(
        "<pFeature>Scan3dPrincipalPointV</pFeature>",
        "<pFeature>CalibOpticalCenterY</pFeature>",
    )
    .replace(
        "Name=\"Scan3dFocalLength\" NameSpace=\"Standard\"",
        "Name=\"CalibFocalLengthX\" NameSpace=\"Custom\"",
    )
    .replace(
        "Name=\"Scan3dPrincipalPointU\" NameSpace=\"Standard\"",
        "Name=\"CalibOpticalCenterX\" NameSpace=\"Custom\"",
    )
    .replace(
        "Name=\"Scan3dPrincipalPointV\" NameSpace=\"Standard\"",
        "Name=\"CalibOpticalCenterY\" NameSpace=\"Custom\"",
    )
    .replace(
        "</RegisterDescription>",
        r#"  <FloatReg Name="CalibFocalLengthY" NameSpace="Custom">
    <Address>0xA140</Address>
    <Length>8</Length>
    <AccessMode>RO</AccessMode>
    <pPort>Device</pPort>
    <Endianess>BigEndian</Endianess>
    <Unit>px</Unit>
  </FloatReg>
</RegisterDescription>"#,
    )
}

/// `GenDCStreamingMode` of [`VendorHabits::gendc`].
const GENDC_XML: &str = r#"  <Enumeration Name="GenDCStreamingMode" NameSpace="Standard">
    <pIsLocked>TLParamsLocked</pIsLocked>
    <EnumEntry Name="Off" NameSpace="Standard">
      <Value>0</Value>
    </EnumEntry>
    <EnumEntry Name="On" NameSpace="Standard">
      <Value>1</Value>
    </EnumEntry>
    <pValue>GenDCStreamingModeReg</pValue>
  </Enumeration>
  <IntReg Name="GenDCStreamingModeReg" NameSpace="Custom">
    <Address>0xA060</Address>
    <Length>4</Length>
    <AccessMode>RW</AccessMode>
    <pPort>Device</pPort>
    <Sign>Unsigned</Sign>
    <Endianess>BigEndian</Endianess>
  </IntReg>
</RegisterDescription>"#;

/// The trigger features of [`VendorHabits::software_trigger`].
const TRIGGER_XML: &str = r#"  <Enumeration Name="TriggerSelector" NameSpace="Standard">
    <EnumEntry Name="FrameStart" NameSpace="Standard">
      <Value>0</Value>
    </EnumEntry>
    <pValue>TriggerSelectorReg</pValue>
    <pSelected>TriggerMode</pSelected>
    <pSelected>TriggerSource</pSelected>
    <pSelected>TriggerSoftware</pSelected>
  </Enumeration>
  <IntReg Name="TriggerSelectorReg" NameSpace="Custom">
    <Address>0xA054</Address>
    <Length>4</Length>
    <AccessMode>RW</AccessMode>
    <pPort>Device</pPort>
    <Sign>Unsigned</Sign>
    <Endianess>BigEndian</Endianess>
  </IntReg>
  <Enumeration Name="TriggerMode" NameSpace="Standard">
    <EnumEntry Name="Off" NameSpace="Standard">
      <Value>0</Value>
    </EnumEntry>
    <EnumEntry Name="On" NameSpace="Standard">
      <Value>1</Value>
    </EnumEntry>
    <pValue>TriggerModeReg</pValue>
  </Enumeration>
  <IntReg Name="TriggerModeReg" NameSpace="Custom">
    <Address>0xA048</Address>
    <Length>4</Length>
    <AccessMode>RW</AccessMode>
    <pPort>Device</pPort>
    <Sign>Unsigned</Sign>
    <Endianess>BigEndian</Endianess>
  </IntReg>
  <Enumeration Name="TriggerSource" NameSpace="Standard">
    <EnumEntry Name="Software" NameSpace="Standard">
      <Value>0</Value>
    </EnumEntry>
    <EnumEntry Name="Line1" NameSpace="Standard">
      <Value>1</Value>
    </EnumEntry>
    <pValue>TriggerSourceReg</pValue>
  </Enumeration>
  <IntReg Name="TriggerSourceReg" NameSpace="Custom">
    <Address>0xA04C</Address>
    <Length>4</Length>
    <AccessMode>RW</AccessMode>
    <pPort>Device</pPort>
    <Sign>Unsigned</Sign>
    <Endianess>BigEndian</Endianess>
  </IntReg>
  <Command Name="TriggerSoftware" NameSpace="Standard">
    <pValue>TriggerSoftwareReg</pValue>
    <CommandValue>1</CommandValue>
  </Command>
  <IntReg Name="TriggerSoftwareReg" NameSpace="Custom">
    <Address>0xA050</Address>
    <Length>4</Length>
    <AccessMode>RW</AccessMode>
    <pPort>Device</pPort>
    <Sign>Unsigned</Sign>
    <Endianess>BigEndian</Endianess>
  </IntReg>
</RegisterDescription>"#;
