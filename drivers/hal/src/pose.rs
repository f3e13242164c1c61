//! UR's pose convention `p[x, y, z, rx, ry, rz]` (metres, rotation vector in radians).
//! This is the only place in the project that converts, parses or prints it; the UR driver
//! (`handeye_ur::UrPose`) and the core both use this type.

use std::fmt;
use std::str::FromStr;

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

/// A UR pose `p[x, y, z, rx, ry, rz]`: position in metres and a rotation vector (axis × angle,
/// radians, angle in [0, π]). Which frames it relates depends on where it came from (RTDE
/// `actual_TCP_pose` is `base_from_tcp`; `tcp_offset` is `flange_from_tcp`).
///
/// Text: [`FromStr`] reads `x,y,z,rx,ry,rz` or `p[x, y, z, rx, ry, rz]`, [`Display`](fmt::Display)
/// prints `x,y,z,rx,ry,rz` with 6 decimals (µm, µrad). Serde: the array `[x, y, z, rx, ry, rz]`.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(transparent)]
pub struct UrPose(pub [f64; 6]);

impl UrPose {
    /// `[x, y, z, rx, ry, rz]`: metres, then the rotation vector in radians.
    pub fn values(&self) -> [f64; 6] {
        self.0
    }

    /// Format as URScript `p[...]` with full precision.
    pub fn to_script(&self) -> String {
        let v: Vec<String> = self.0.iter().map(|x| format!("{x:.9}")).collect();
        format!("p[{}]", v.join(","))
    }

    /// Whether two poses describe the same transform within `tol_m` metres and `tol_rad`
    /// radians (compares rotations, not vectors: near π both `r` and its mirror are valid).
    pub fn approx_eq(&self, other: &UrPose, tol_m: f64, tol_rad: f64) -> bool {
        let a = Isometry3::from(*self);
        let b = Isometry3::from(*other);
        (a.translation.vector - b.translation.vector).norm() <= tol_m
            && a.rotation.angle_to(&b.rotation) <= tol_rad
    }
}

impl From<UrPose> for Isometry3<f64> {
    fn from(p: UrPose) -> Self {
        let [x, y, z, rx, ry, rz] = p.0;
        Isometry3::from_parts(
            Translation3::new(x, y, z),
            UnitQuaternion::from_scaled_axis(Vector3::new(rx, ry, rz)),
        )
    }
}

impl From<Isometry3<f64>> for UrPose {
    fn from(t: Isometry3<f64>) -> Self {
        let r = t.rotation.scaled_axis();
        let p = t.translation.vector;
        UrPose([p.x, p.y, p.z, r.x, r.y, r.z])
    }
}

impl From<&Isometry3<f64>> for UrPose {
    fn from(t: &Isometry3<f64>) -> Self {
        UrPose::from(*t)
    }
}

impl From<[f64; 6]> for UrPose {
    fn from(v: [f64; 6]) -> Self {
        UrPose(v)
    }
}

/// What a UR pose looks like as text; every parse error starts with it.
const EXPECTED: &str =
    "expected 6 comma-separated numbers x,y,z,rx,ry,rz (metres, rotation vector in radians)";

/// At most this many characters of the offending text are quoted in an error.
const QUOTE_MAX_CHARS: usize = 40;

/// Why a text is not a UR pose ([`UrPose::from_str`]).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum UrPoseParseError {
    /// The text has another number of values than 6.
    #[error("{EXPECTED}, got {count} in `{text}`")]
    Count {
        /// How many comma-separated values there were.
        count: usize,
        /// The text (at most about 40 characters of it).
        text: String,
    },
    /// A value is not a finite number.
    #[error("{EXPECTED}; value {position} `{token}` is not a finite number")]
    NotANumber {
        /// 1-based position of the value.
        position: usize,
        /// The value as given (at most about 40 characters of it).
        token: String,
    },
    /// `p[` without the closing `]`.
    #[error("{EXPECTED}; `{text}` opens `p[` but does not close it with `]`")]
    Unclosed {
        /// The text (at most about 40 characters of it).
        text: String,
    },
}

/// `s`, cut to [`QUOTE_MAX_CHARS`] characters (marked with `…`) for an error message.
fn quote(s: &str) -> String {
    match s.char_indices().nth(QUOTE_MAX_CHARS) {
        Some((end, _)) => format!("{}…", &s[..end]),
        None => s.to_string(),
    }
}

impl FromStr for UrPose {
    type Err = UrPoseParseError;

    /// Reads `x,y,z,rx,ry,rz` or URScript's `p[x, y, z, rx, ry, rz]` (white space anywhere
    /// around the values; every value finite).
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let s = s.trim();
        let body = match s.strip_prefix("p[") {
            Some(rest) => rest
                .strip_suffix(']')
                .ok_or_else(|| UrPoseParseError::Unclosed { text: quote(s) })?,
            None => s,
        };
        let mut v = [0.0; 6];
        let mut count = 0;
        for (i, token) in body.split(',').enumerate() {
            let token = token.trim();
            let x = token
                .parse::<f64>()
                .ok()
                .filter(|x| x.is_finite())
                .ok_or_else(|| UrPoseParseError::NotANumber {
                    position: i + 1,
                    token: quote(token),
                })?;
            if let Some(slot) = v.get_mut(i) {
                *slot = x;
            }
            count = i + 1;
        }
        if count != 6 {
            return Err(UrPoseParseError::Count {
                count,
                text: quote(s),
            });
        }
        Ok(UrPose(v))
    }
}

impl fmt::Display for UrPose {
    /// `x,y,z,rx,ry,rz` with 6 decimals (µm, µrad); [`UrPose::from_str`] reads it back.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let [x, y, z, rx, ry, rz] = self.0;
        write!(f, "{x:.6},{y:.6},{z:.6},{rx:.6},{ry:.6},{rz:.6}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    fn round_trip(r: Vector3<f64>) {
        let p = UrPose([0.1, -0.2, 0.3, r.x, r.y, r.z]);
        let iso = Isometry3::from(p);
        let back = UrPose::from(iso);
        assert!(p.approx_eq(&back, 1e-12, 1e-9), "{p:?} vs {back:?}");
        let angle = Vector3::new(back.0[3], back.0[4], back.0[5]).norm();
        assert!(angle <= PI + 1e-9, "angle {angle} > π");
        let iso2 = Isometry3::from(back);
        assert!((iso.to_homogeneous() - iso2.to_homogeneous()).abs().max() < 1e-9);
    }

    #[test]
    fn round_trip_near_zero() {
        for r in [
            Vector3::zeros(),
            Vector3::new(1e-12, 0.0, 0.0),
            Vector3::new(1e-7, -2e-7, 3e-8),
            Vector3::new(0.0, 0.0, 1e-4),
        ] {
            round_trip(r);
        }
    }

    #[test]
    fn round_trip_near_pi() {
        let axes = [
            Vector3::x(),
            Vector3::y(),
            Vector3::z(),
            Vector3::new(1.0, 1.0, 1.0).normalize(),
            Vector3::new(-0.3, 0.9, 0.1).normalize(),
        ];
        for k in axes {
            for a in [PI, PI - 1e-9, PI - 1e-6, PI - 1e-3] {
                round_trip(k * a);
            }
        }
        // The mirrored vector (1 − 2π/|r|)·r is the same rotation.
        let r = Vector3::new(0.0, 0.0, PI - 1e-4);
        let m = r * (1.0 - 2.0 * PI / r.norm());
        let a = UrPose([0.0, 0.0, 0.0, r.x, r.y, r.z]);
        let b = UrPose([0.0, 0.0, 0.0, m.x, m.y, m.z]);
        assert!(a.approx_eq(&b, 1e-12, 1e-9));
    }

    #[test]
    fn documented_flange_pose_of_ur5e_at_zero() {
        let t = crate::ur_dh::UrModel::Ur5e.dh().forward(&[0.0; 6]);
        let p = UrPose::from(t);
        let expect = UrPose([
            -0.8172,
            -0.2329,
            0.0628,
            std::f64::consts::FRAC_PI_2,
            0.0,
            0.0,
        ]);
        assert!(p.approx_eq(&expect, 1e-9, 1e-9), "{p:?}");
        assert!(p.to_script().starts_with("p[-0.817200000,"));
    }

    #[test]
    fn text_round_trips_in_both_spellings() {
        let p = UrPose([0.1, -0.2, 0.3, 0.0, -0.0, 3.1]);
        let text = p.to_string();
        assert_eq!(
            text,
            "0.100000,-0.200000,0.300000,0.000000,-0.000000,3.100000"
        );
        assert_eq!(text.parse::<UrPose>(), Ok(p));
        // Rounding to 6 decimals keeps a pose to within half a micrometre / microradian.
        let q = UrPose([0.123_456_789, -1e-9, 2.5, -0.5, 1e-7, PI - 1e-9]);
        let back: UrPose = q.to_string().parse().expect("valid");
        for (a, b) in q.values().iter().zip(back.values()) {
            assert!((a - b).abs() <= 5e-7, "{a} vs {b}");
        }
        let script: UrPose = q.to_script().parse().expect("URScript spelling");
        assert!(script.approx_eq(&q, 1e-9, 1e-9));
        for s in [
            " 0.1, -0.2 ,0.3,0,0,1.5 ",
            "p[0.1, -0.2, 0.3, 0, 0, 1.5]",
            "  p[ 0.1,-0.2,0.3,0,0,1.5 ]\n",
        ] {
            assert_eq!(
                s.parse::<UrPose>(),
                Ok(UrPose::from([0.1, -0.2, 0.3, 0.0, 0.0, 1.5])),
                "{s:?}"
            );
        }
    }

    #[test]
    fn parse_errors_say_what_is_expected_and_name_the_bad_value() {
        let err = |s: &str| s.parse::<UrPose>().expect_err(s).to_string();
        let e = err("1,2,3");
        assert!(
            e.starts_with(EXPECTED) && e.contains("got 3 in `1,2,3`"),
            "{e}"
        );
        assert!(err("1,2,3,4,5,6,7").contains("got 7"));
        let e = err("1,2,3,4,5,x");
        assert!(e.starts_with(EXPECTED) && e.contains("value 6 `x`"), "{e}");
        assert!(err("1,2,nan,4,5,6").contains("value 3 `nan`"));
        assert!(err("1,2,3,4,5,inf").contains("`inf`"));
        assert!(err("1,,3,4,5,6").contains("value 2 ``"));
        assert!(err("").contains("value 1 ``"));
        assert!(err("p[1,2,3,4,5,6").contains("does not close"));
        // A long bad value is quoted only in part.
        let long = format!("1,2,3,4,5,{}", "9x".repeat(500));
        let e = err(&long);
        assert!(e.len() < EXPECTED.len() + 100 && e.contains('…'), "{e}");
    }
}
