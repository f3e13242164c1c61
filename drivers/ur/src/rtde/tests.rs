//! Unit tests of the RTDE wire format: the field table, documented wire examples, round trips
//! in both protocol versions, malformed input, the `rtde` fuzz target, and the shared [`Lcg`].

use super::*;
use crate::UrError;

#[test]
fn table_is_sorted_complete_and_typed() {
    assert_eq!(fields::FIELDS.len(), 419);
    assert!(fields::FIELDS.windows(2).all(|w| w[0].0 < w[1].0));
    assert_eq!(field_type("actual_q"), Some(FieldType::Vector6d));
    assert_eq!(field_type("robot_mode"), Some(FieldType::Int32));
    assert_eq!(field_type("runtime_state"), Some(FieldType::Uint32));
    assert_eq!(field_type("joint_mode"), Some(FieldType::Vector6Int32));
    assert_eq!(
        field_type("input_double_register_47"),
        Some(FieldType::Double)
    );
    assert_eq!(field_type("input_double_register_48"), None);
    assert!(is_input_field("input_int_register_3"));
    assert!(is_input_field("speed_slider_fraction"));
    assert!(!is_input_field("actual_q"));
}

#[test]
fn table_matches_the_shared_reference_when_present() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/ref/rtde-field-types.json");
    let Ok(text) = std::fs::read_to_string(&path) else {
        assert!(
            std::env::var_os("CI").is_none(),
            "{} missing in CI",
            path.display()
        );
        // Counted by .ci/run's skip summary, shown past the capture.
        handeye_hal::skips::record(
            "rtde::tests::table_matches_the_shared_reference_when_present",
            &format!("{} not found", path.display()),
        );
        return;
    };
    let map: std::collections::BTreeMap<String, String> =
        serde_json::from_str(&text).expect("json");
    assert_eq!(map.len(), fields::FIELDS.len());
    for (name, ty) in map {
        assert_eq!(
            field_type(&name).map(FieldType::wire_name),
            Some(ty.as_str()),
            "{name}"
        );
    }
}

#[test]
fn documented_wire_examples() {
    let v = ClientPackage::RequestProtocolVersion(2)
        .encode(Protocol::V2)
        .expect("enc");
    assert_eq!(v, [0x00, 0x05, 0x56, 0x00, 0x02]);
    assert_eq!(
        ClientPackage::GetUrcontrolVersion
            .encode(Protocol::V2)
            .expect("enc"),
        [0, 3, 0x76]
    );
    let r = ServerPackage::UrcontrolVersion {
        major: 5,
        minor: 11,
        bugfix: 1,
        build: 108318,
    }
    .encode(Protocol::V2)
    .expect("enc");
    assert_eq!(r.len(), 19);
    assert_eq!(&r[..3], &[0x00, 0x13, 0x76]);
    assert_eq!(&r[15..], &[0x00, 0x01, 0xa7, 0x1e]);
    let (f, used) = Frame::split(&[0, 4, b'V', 1, 0xff])
        .expect("ok")
        .expect("frame");
    assert_eq!(used, 4);
    assert_eq!(
        ServerPackage::decode(&f, Protocol::V2).expect("dec"),
        ServerPackage::ProtocolVersionAccepted(true)
    );
    // ur_rtde's trailing comma.
    let f = Frame::new(PackageType::SetupOutputs, {
        let mut p = 500f64.to_be_bytes().to_vec();
        p.extend_from_slice(b"timestamp,actual_q,robot_mode,");
        p
    });
    assert_eq!(
        ClientPackage::decode(&f, Protocol::V2).expect("dec"),
        ClientPackage::SetupOutputs {
            frequency: Some(500.0),
            names: vec!["timestamp".into(), "actual_q".into(), "robot_mode".into()]
        }
    );
    // Data package of 64 bytes.
    let vals = [
        Value::Double(41.5),
        Value::Vector6d([0.1; 6]),
        Value::Int32(7),
    ];
    let mut body = Vec::new();
    encode_values(&vals, &mut body);
    let pkg = ServerPackage::Data {
        recipe_id: Some(1),
        body: body.clone(),
    }
    .encode(Protocol::V2)
    .expect("e");
    assert_eq!(&pkg[..4], &[0x00, 0x40, 0x55, 0x01]);
    let types: Vec<_> = vals.iter().map(Value::field_type).collect();
    assert_eq!(decode_values(&types, &body).expect("dec"), vals);
}

#[test]
fn round_trips_every_package_in_both_versions() {
    let text = TextMessage {
        message: "hello".into(),
        source: "sim".into(),
        level: 3,
    };
    for proto in [Protocol::V1, Protocol::V2] {
        let client = [
            ClientPackage::RequestProtocolVersion(2),
            ClientPackage::GetUrcontrolVersion,
            ClientPackage::SetupOutputs {
                frequency: (proto == Protocol::V2).then_some(125.0),
                names: vec!["a".into(), "b".into()],
            },
            ClientPackage::SetupInputs {
                names: vec!["input_int_register_24".into()],
            },
            ClientPackage::Start,
            ClientPackage::Pause,
            ClientPackage::Data {
                recipe_id: (proto == Protocol::V2).then_some(3),
                body: vec![1, 2, 3],
            },
            ClientPackage::Text(TextMessage {
                source: if proto == Protocol::V2 {
                    "sim".into()
                } else {
                    String::new()
                },
                ..text.clone()
            }),
        ];
        for c in client {
            let bytes = c.encode(proto).expect("enc");
            let (f, n) = Frame::split(&bytes).expect("split").expect("whole");
            assert_eq!(n, bytes.len());
            assert_eq!(ClientPackage::decode(&f, proto).expect("dec"), c);
        }
        let server = [
            ServerPackage::ProtocolVersionAccepted(true),
            ServerPackage::UrcontrolVersion {
                major: 3,
                minor: 15,
                bugfix: 7,
                build: 1,
            },
            ServerPackage::SetupOutputs {
                recipe_id: (proto == Protocol::V2).then_some(0),
                types: vec!["DOUBLE".into(), "NOT_FOUND".into()],
            },
            ServerPackage::SetupInputs {
                recipe_id: (proto == Protocol::V2).then_some(0),
                types: vec!["IN_USE".into()],
            },
            ServerPackage::Start(true),
            ServerPackage::Pause(false),
            ServerPackage::Data {
                recipe_id: (proto == Protocol::V2).then_some(1),
                body: vec![0; 8],
            },
        ];
        for s in server {
            let bytes = s.encode(proto).expect("enc");
            let (f, _) = Frame::split(&bytes).expect("split").expect("whole");
            assert_eq!(ServerPackage::decode(&f, proto).expect("dec"), s);
        }
    }
}

#[test]
fn rejects_malformed_packages() {
    assert!(Frame::split(&[0, 2, b'V']).is_err());
    assert!(Frame::split(&[0, 3, b'x']).is_err());
    assert!(Frame::split(&[0, 9, b'V', 0]).expect("ok").is_none());
    let f = Frame::new(PackageType::RequestProtocolVersion, vec![1]);
    assert!(ClientPackage::decode(&f, Protocol::V2).is_err());
    let f = Frame::new(
        PackageType::SetupOutputs,
        vec![0x7f, 0xf8, 0, 0, 0, 0, 0, 0],
    );
    assert!(
        ClientPackage::decode(&f, Protocol::V2).is_err(),
        "NaN frequency"
    );
    let long = ClientPackage::SetupInputs {
        names: vec!["a".repeat(1000); 3],
    };
    assert!(matches!(
        long.encode(Protocol::V2),
        Err(UrError::InvalidArgument(_))
    ));
    let f = Frame::new(PackageType::SetupInputs, vec![b'a'; 3000]);
    assert!(
        ClientPackage::decode(&f, Protocol::V2).is_err(),
        "over 2048 bytes"
    );
    let f = Frame::new(PackageType::SetupOutputs, b"\x01DOUBLE,FLOAT".to_vec());
    assert!(ServerPackage::decode(&f, Protocol::V2).is_err());
    assert!(decode_values(&[FieldType::Double], &[0; 7]).is_err());
    assert!(decode_values(&[FieldType::Double], &[0; 9]).is_err());
}

/// Fuzz target `rtde` (hal::fuzz): mutated client and server packages of both protocol
/// versions (version request, output setup, controller version, recipes, text, data)
/// split into frames, each of which decodes as some package of V1 or V2 or is refused with
/// a message; a data package's body decodes against a recipe or is refused.
#[test]
fn fuzz_rtde() {
    let mut seeds: Vec<Vec<u8>> = Vec::new();
    for proto in [Protocol::V1, Protocol::V2] {
        seeds.push(
            ClientPackage::RequestProtocolVersion(2)
                .encode(proto)
                .expect("e"),
        );
        seeds.push(
            ClientPackage::SetupOutputs {
                frequency: Some(500.0),
                names: vec!["actual_q".into(), "timestamp".into()],
            }
            .encode(proto)
            .expect("e"),
        );
        seeds.push(
            ServerPackage::UrcontrolVersion {
                major: 5,
                minor: 11,
                bugfix: 1,
                build: 9,
            }
            .encode(proto)
            .expect("e"),
        );
        seeds.push(
            ServerPackage::SetupOutputs {
                recipe_id: Some(1),
                types: vec!["VECTOR6D".into(), "DOUBLE".into()],
            }
            .encode(proto)
            .expect("e"),
        );
        seeds.push(
            ServerPackage::Text(TextMessage {
                message: "m".into(),
                source: "s".into(),
                level: 1,
            })
            .encode(proto)
            .expect("e"),
        );
        seeds.push(
            ServerPackage::Data {
                recipe_id: Some(1),
                body: vec![0; 56],
            }
            .encode(proto)
            .expect("e"),
        );
    }
    handeye_hal::fuzz::Target::new("rtde", seeds)
        .allocation_cap(16, 1 << 16)
        .run(|b| {
            let mut rest = b;
            while let Some((f, n)) = Frame::split(rest).map_err(|e| e.to_string())? {
                let mut first_error = None;
                let mut decoded = false;
                for proto in [Protocol::V1, Protocol::V2] {
                    match ClientPackage::decode(&f, proto) {
                        Ok(_) => decoded = true,
                        Err(e) => first_error = first_error.or(Some(e.to_string())),
                    }
                    match ServerPackage::decode(&f, proto) {
                        Ok(ServerPackage::Data { body, .. }) => {
                            decoded = true;
                            let types = [FieldType::Double, FieldType::Vector6d];
                            if let Err(e) = decode_values(&types, &body) {
                                first_error = first_error.or(Some(e.to_string()));
                            }
                        }
                        Ok(_) => decoded = true,
                        Err(e) => first_error = first_error.or(Some(e.to_string())),
                    }
                }
                if !decoded {
                    return Err(first_error.unwrap_or_default());
                }
                rest = &rest[n..];
            }
            Ok(())
        });
}

/// Small deterministic generator for the mutation tests.
pub(crate) struct Lcg(pub(crate) u64);
impl Lcg {
    pub(crate) fn next(&mut self) -> u64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        self.0 >> 33
    }
    pub(crate) fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}
