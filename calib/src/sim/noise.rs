//! What makes real scans hard, each with a knob and a realistic default.

use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, Normal};

use crate::geometry::SensorClass;

/// Imperfections of a 3D camera.
///
/// Defaults are those of a good industrial structured-light camera (Zivid 2+ class) at
/// 0.4–0.8 m; [`ScanNoise::active_stereo`] is a consumer active-stereo camera (RealSense D4xx
/// class), fitted to real frames; [`ScanNoise::time_of_flight`] is a time-of-flight camera
/// (Helios2 / Azure Kinect class); `none()` gives a perfect sensor for geometry tests.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ScanNoise {
    /// Depth noise standard deviation at 1 m (metres); it grows with z^`depth_sigma_exponent`
    /// and with 1/cos of the incidence angle (1/√cos with [`Self::reference_albedo`] set: the
    /// noise of the returned light's amplitude).
    pub depth_sigma_at_1m_m: f64,
    /// How depth noise grows with distance: σ(z) = `depth_sigma_at_1m_m` · z^this (z in
    /// metres). 2 for triangulation (structured light, stereo), 1 for time of flight (the
    /// returned light falls with z² and the phase noise with its square root).
    pub depth_sigma_exponent: f64,
    /// Probability that a pixel on a depth edge becomes a flying pixel (a depth between the
    /// foreground and the background surfaces).
    pub flying_pixel_probability: f64,
    /// A neighbour farther by more than this (metres) makes a pixel a depth edge.
    pub flying_pixel_edge_m: f64,
    /// Incidence angle (degrees from the surface normal) where grazing dropouts start.
    pub dropout_start_deg: f64,
    /// Incidence angle where every point is lost.
    pub dropout_full_deg: f64,
    /// Probability of losing any pixel (specular spots, dark surfaces).
    pub random_dropout_probability: f64,
    /// Relative depth-scale error: measured point = true point · (1 + this).
    pub depth_scale_error: f64,
    /// Depth error that grows across the image, 1/m per unit of the pixel's normalized
    /// coordinates `[x/z, y/z]`: measured depth × (1 + z · (g₀·x/z + g₁·y/z)). A stereo
    /// camera whose two imagers have turned slightly against their calibration measures so:
    /// a disparity bias that varies across the image, whose relative depth error grows with
    /// the depth. Over an object it looks like a turn of the object.
    pub depth_gradient: [f64; 2],
    /// Constant range offset added to every measured distance along the pixel's ray (metres):
    /// a time-of-flight camera's residual phase offset (its error hardly scales with distance,
    /// and it measures the light's path, not the depth).
    pub depth_offset_m: f64,
    /// Nothing is measured beyond this range (metres).
    pub max_range_m: f64,
    /// Depth resolution: reported depths are multiples of this (metres; 0 = continuous). A
    /// RealSense reports whole millimetres.
    pub depth_step_m: f64,
    /// Standard deviation at 1 m of a smooth, spatially correlated depth error (metres; grows
    /// with z²): the wavy surfaces of stereo matching. 0 = none.
    pub ripple_sigma_at_1m_m: f64,
    /// Correlation length of that ripple across the image, pixels: its covariance is
    /// `exp(-r² / 2ℓ²)` at a distance of `r` pixels (0.5 at 1.18 ℓ).
    pub ripple_correlation_px: f64,
    /// Multipath of time-of-flight cameras: light bounced off nearby surfaces that face a pixel's
    /// surface (concave corners: base and floor, plate, links) arrives late and pushes the
    /// measured depth farther by this much (metres) times the share of the pixel's neighbours
    /// (within `multipath_window_px`) whose surfaces face it. 0 = none; flat open surfaces get
    /// none.
    pub multipath_m: f64,
    /// Half-width of the image window (pixels) searched for surfaces facing a pixel's surface.
    pub multipath_window_px: f64,
    /// Reflectivity of the surfaces the sensor's figures are stated for (a time-of-flight
    /// camera's precision is specified on a white or light target). Above 0 the scene's
    /// surfaces have their own reflectivity (the simulator's albedo: a UR's light covers 0.6,
    /// its dark joint caps and base ring 0.08, see `sim::scan`), and the camera reports its
    /// amplitude image as the cloud's intensity: the noise grows as 1/√amplitude (× 1/√(albedo
    /// / this) and 1/√cos of the incidence instead of 1/cos), dark
    /// surfaces read long by [`Self::dark_range_bias_m`], multipath weighs each facing surface
    /// by its albedo over this. 0: every surface alike, no amplitude image (structured light,
    /// active stereo).
    pub reference_albedo: f64,
    /// Range bias of a black surface against one of [`Self::reference_albedo`] (metres,
    /// longer): a surface of albedo `a` reads `this · (1 − a / reference)` long (none at or
    /// above the reference). Time of flight: the intensity-related distance error.
    pub dark_range_bias_m: f64,
    /// 1σ of the range offset's drift from scan to scan (metres): a time-of-flight camera's
    /// offset follows its temperature, and each scan draws its own offset around
    /// [`Self::depth_offset_m`].
    pub offset_drift_m: f64,
    /// A camera that registers a colour image to its depth, pixel for pixel (an active-stereo
    /// camera's RGB imager aligned to the depth): the simulator renders it
    /// (`sim::colour`) and hands it with the scan. `false`: depth only.
    pub colour_image: bool,
    /// 1σ per axis of that image's shift against the depth, pixels: the factory calibration
    /// between the colour imager and the depth, off by a sub-pixel amount (each scan draws its
    /// own).
    pub colour_misalignment_px: f64,
}

/// Albedo of the surfaces a time-of-flight camera's precision is stated for here: a UR's light
/// grey covers in the near infrared (assumed; the datasheets' target is a 90 % white board).
pub const TOF_REFERENCE_ALBEDO: f64 = 0.6;

/// Mixed into a scan's seed for its range offset's drift.
const OFFSET_DRIFT_SEED: u64 = 0x4452_4946_5430;

/// Darkest albedo the simulator's amplitude effects are computed for (a black surface still
/// returns a little light).
const MIN_ALBEDO: f64 = 0.02;

/// Largest `noise.depth_sigma_at_1m_m`, metres.
pub(crate) const MAX_DEPTH_SIGMA_AT_1M_M: f64 = 0.05;
/// Largest |`noise.depth_offset_m`|, metres.
pub(crate) const MAX_DEPTH_OFFSET_M: f64 = 0.05;
/// Largest `noise.multipath_m`, metres.
pub(crate) const MAX_MULTIPATH_M: f64 = 0.1;
/// Largest `noise.multipath_window_px` (the window costs its area per pixel).
pub(crate) const MAX_MULTIPATH_WINDOW_PX: f64 = 64.0;
/// Largest `noise.random_dropout_probability`.
pub(crate) const MAX_RANDOM_DROPOUT: f64 = 0.9;
/// Range of a finite `noise.max_range_m`, metres.
pub(crate) const MIN_RANGE_M: f64 = 0.05;
/// Longest finite `noise.max_range_m`, metres.
pub(crate) const MAX_RANGE_M: f64 = 100.0;

impl Default for ScanNoise {
    fn default() -> Self {
        Self {
            depth_sigma_at_1m_m: 0.000_25,
            depth_sigma_exponent: 2.0,
            flying_pixel_probability: 0.5,
            flying_pixel_edge_m: 0.01,
            dropout_start_deg: 70.0,
            dropout_full_deg: 85.0,
            random_dropout_probability: 0.01,
            depth_scale_error: 0.0015,
            depth_gradient: [0.0, 0.0],
            depth_offset_m: 0.0,
            max_range_m: 2.5,
            depth_step_m: 0.0,
            ripple_sigma_at_1m_m: 0.0,
            ripple_correlation_px: 14.0,
            multipath_m: 0.0,
            multipath_window_px: 12.0,
            reference_albedo: 0.0,
            dark_range_bias_m: 0.0,
            offset_drift_m: 0.0,
            colour_image: false,
            colour_misalignment_px: 0.0,
        }
    }
}

impl ScanNoise {
    /// A perfect sensor: exact depths, no dropouts, no flying pixels, no scale error.
    pub fn none() -> Self {
        Self {
            depth_sigma_at_1m_m: 0.0,
            depth_sigma_exponent: 2.0,
            flying_pixel_probability: 0.0,
            flying_pixel_edge_m: 0.01,
            dropout_start_deg: 90.0,
            dropout_full_deg: 90.0,
            random_dropout_probability: 0.0,
            depth_scale_error: 0.0,
            depth_gradient: [0.0, 0.0],
            depth_offset_m: 0.0,
            max_range_m: f64::INFINITY,
            depth_step_m: 0.0,
            ripple_sigma_at_1m_m: 0.0,
            ripple_correlation_px: 14.0,
            multipath_m: 0.0,
            multipath_window_px: 12.0,
            reference_albedo: 0.0,
            dark_range_bias_m: 0.0,
            offset_drift_m: 0.0,
            colour_image: false,
            colour_misalignment_px: 0.0,
        }
    }

    /// A consumer active-stereo camera (Intel RealSense D4xx class) at 0.3–2.5 m: noise growing
    /// with z², whole-millimetre depths, grazing surfaces lost early, more dropouts and flying
    /// pixels than structured light, a depth-scale error of 1 %, and smooth blobs of depth
    /// error (σ 9 mm at 1 m, correlation length 14 px). Fitted to five real frames of a D4xx
    /// at 0.8–1.8 m (`../shared/realdata/xarm7_realsense`, see `calib/tests/realdata.rs`):
    /// - the per-pixel noise, so that the registration's own estimate
    ///   ([`crate::calib::range::RangeImage::noise_m`]) gives the simulated scan at the real
    ///   camera pose what it gives the real frames;
    /// - the depth error on the arm at the reference pose: real median 12.1 mm, IQR 16.0 mm
    ///   (the white, glossy links at 1.1–1.3 m), simulated 13.5 mm / 17.6 mm; spatial
    ///   correlation 0.5 at 16 px in the real frames;
    /// - the depth gradient: fitted per frame on the arm at the reference pose, the real
    ///   frames' inverse depth grows by 0.009–0.031 /m per unit of y/z down the image (median
    ///   0.015 /m: 2 % of the depth at 1.3 m) and varies by ±0.015 /m per unit of x/z with no
    ///   consistent sign.
    pub fn active_stereo() -> Self {
        Self {
            depth_sigma_at_1m_m: 0.000_46,
            depth_sigma_exponent: 2.0,
            flying_pixel_probability: 0.8,
            flying_pixel_edge_m: 0.01,
            dropout_start_deg: 60.0,
            dropout_full_deg: 80.0,
            random_dropout_probability: 0.03,
            depth_scale_error: 0.01,
            depth_gradient: [0.0, -0.015],
            depth_offset_m: 0.0,
            max_range_m: 2.5,
            depth_step_m: 0.001,
            ripple_sigma_at_1m_m: 0.009,
            ripple_correlation_px: 14.0,
            multipath_m: 0.0,
            multipath_window_px: 12.0,
            reference_albedo: 0.0,
            dark_range_bias_m: 0.0,
            offset_drift_m: 0.0,
            colour_image: true,
            colour_misalignment_px: 0.5,
        }
    }

    /// A time-of-flight camera (LUCID Helios2 / Basler blaze / Azure Kinect class,
    /// continuous-wave phase measurement) at 0.3–2.5 m, sized from published
    /// characterisations (the book's "Time of flight" section lists the sources and which
    /// values are assumed):
    /// - **noise against amplitude**: σ = 1 mm at 1 m on the light covers (albedo
    ///   [`TOF_REFERENCE_ALBEDO`]), linear in z (the returned light falls with z², the phase
    ///   noise with its square root), × 1/√(albedo / reference): the dark caps (0.08) 2.7 ×
    ///   noisier; × 1/√cos(incidence) (the returned light falls with the cosine, as with the
    ///   albedo). The Helios2 and blaze state sub-millimetre to millimetre precision at 1 m on
    ///   a 90 % white target;
    /// - **range bias against reflectivity**: a black surface reads [`Self::dark_range_bias_m`]
    ///   = 3 mm long against the covers (the dark caps: 2.6 mm), the order of the material
    ///   offsets reported for the Kinect v2 and Azure Kinect;
    /// - **multipath** at concave corners (base on the plate or floor, between links): up to
    ///   [`ScanNoise::multipath_m`] = 8 mm farther where most of the window faces the pixel,
    ///   each facing surface weighed by its albedo (the light plate and floor bounce more than
    ///   a dark cable); none on open flat surfaces;
    /// - **flying pixels** at depth edges: probability 0.9 where the depth jumps by more than
    ///   10 mm (the Helios2's own flying-pixel filter uses a 20 mm threshold; unfiltered output
    ///   is simulated);
    /// - **a range offset that drifts with temperature**: 1 mm, plus 1.5 mm 1σ from scan to
    ///   scan (Basler states its ±5 mm accuracy after 20 minutes of warm-up; the Azure Kinect
    ///   needs 40–50 minutes to settle); a depth-scale error of 0.1 % (Microsoft: < 11 mm +
    ///   0.1 % of the distance); depths in 0.25 mm steps (the Helios `Coord3D_C16` scale);
    /// - **an amplitude image** as the cloud's intensity (albedo · cos(incidence) / range²),
    ///   what a Helios2 or blaze delivers beside its depth.
    ///
    /// Not fitted to real frames: there are none of this class in `../shared/realdata`.
    pub fn time_of_flight() -> Self {
        Self {
            depth_sigma_at_1m_m: 0.001,
            depth_sigma_exponent: 1.0,
            flying_pixel_probability: 0.9,
            flying_pixel_edge_m: 0.01,
            dropout_start_deg: 70.0,
            dropout_full_deg: 85.0,
            random_dropout_probability: 0.02,
            depth_scale_error: 0.001,
            depth_gradient: [0.0, 0.0],
            depth_offset_m: 0.001,
            max_range_m: 2.5,
            depth_step_m: 0.000_25,
            ripple_sigma_at_1m_m: 0.0,
            ripple_correlation_px: 14.0,
            multipath_m: 0.008,
            multipath_window_px: 12.0,
            reference_albedo: TOF_REFERENCE_ALBEDO,
            dark_range_bias_m: 0.003,
            offset_drift_m: 0.0015,
            colour_image: false,
            colour_misalignment_px: 0.0,
        }
    }

    /// The noise of a sensor class: structured light is the defaults.
    pub fn of_class(class: SensorClass) -> Self {
        match class {
            SensorClass::StructuredLight => Self::default(),
            SensorClass::ActiveStereo => Self::active_stereo(),
            SensorClass::TimeOfFlight => Self::time_of_flight(),
        }
    }

    /// Whether the knobs make sense for a 3D camera; the message names the key, its unit and
    /// the range it must lie in (NaN, infinities and absurd values are refused; `max_range_m`
    /// may be infinite: no range limit).
    pub fn validate(&self) -> Result<(), String> {
        use handeye_hal::limits::check_range;
        check_range(
            "noise.depth_sigma_at_1m_m",
            self.depth_sigma_at_1m_m,
            0.0,
            MAX_DEPTH_SIGMA_AT_1M_M,
            "m",
            "a 3D camera with more noise than that at 1 m sees no robot",
        )?;
        check_range(
            "noise.depth_sigma_exponent",
            self.depth_sigma_exponent,
            0.0,
            3.0,
            "",
            "how noise grows with distance: 2 for triangulation, 1 for time of flight",
        )?;
        check_range(
            "noise.colour_misalignment_px",
            self.colour_misalignment_px,
            0.0,
            10.0,
            "pixels",
            "the colour image's shift against the depth; a factory calibration is off by a pixel at most",
        )?;
        check_range(
            "noise.flying_pixel_probability",
            self.flying_pixel_probability,
            0.0,
            1.0,
            "",
            "a probability",
        )?;
        check_range(
            "noise.flying_pixel_edge_m",
            self.flying_pixel_edge_m,
            1e-4,
            1.0,
            "m",
            "the depth step that makes an edge",
        )?;
        for (key, v) in [
            ("noise.dropout_start_deg", self.dropout_start_deg),
            ("noise.dropout_full_deg", self.dropout_full_deg),
        ] {
            check_range(
                key,
                v,
                0.0,
                90.0,
                "degrees",
                "an incidence angle from the normal",
            )?;
        }
        if self.dropout_start_deg > self.dropout_full_deg {
            return Err(format!(
                "noise.dropout_start_deg = {} is above noise.dropout_full_deg = {}: dropouts start before every point is lost",
                self.dropout_start_deg, self.dropout_full_deg
            ));
        }
        check_range(
            "noise.random_dropout_probability",
            self.random_dropout_probability,
            0.0,
            MAX_RANDOM_DROPOUT,
            "",
            "a probability; more would leave almost nothing to register",
        )?;
        check_range(
            "noise.depth_scale_error",
            self.depth_scale_error,
            -0.2,
            0.2,
            "",
            "a relative error: 0.01 is 1 %",
        )?;
        for (axis, g) in ["x", "y"].iter().zip(self.depth_gradient) {
            check_range(
                &format!("noise.depth_gradient ({axis})"),
                g,
                -0.2,
                0.2,
                "",
                "1/m per unit of the normalized image coordinate: 0.01 is 1 % of a depth of 1 m",
            )?;
        }
        check_range(
            "noise.depth_offset_m",
            self.depth_offset_m,
            -MAX_DEPTH_OFFSET_M,
            MAX_DEPTH_OFFSET_M,
            "m",
            "a constant depth offset; a camera off by more than that needs its own calibration",
        )?;
        check_range(
            "noise.multipath_m",
            self.multipath_m,
            0.0,
            MAX_MULTIPATH_M,
            "m",
            "the extra depth where every neighbour faces the pixel",
        )?;
        check_range(
            "noise.multipath_window_px",
            self.multipath_window_px,
            1.0,
            MAX_MULTIPATH_WINDOW_PX,
            "pixels",
            "half-width of the window searched for facing surfaces",
        )?;
        check_range(
            "noise.reference_albedo",
            self.reference_albedo,
            0.0,
            1.0,
            "",
            "the albedo the noise figures are stated for; 0 for surfaces all alike",
        )?;
        check_range(
            "noise.dark_range_bias_m",
            self.dark_range_bias_m,
            -MAX_DEPTH_OFFSET_M,
            MAX_DEPTH_OFFSET_M,
            "m",
            "the range bias of a black surface",
        )?;
        check_range(
            "noise.offset_drift_m",
            self.offset_drift_m,
            0.0,
            MAX_DEPTH_OFFSET_M,
            "m",
            "1σ of the range offset's drift from scan to scan",
        )?;
        check_range(
            "noise.depth_step_m",
            self.depth_step_m,
            0.0,
            0.01,
            "m",
            "0 for continuous depths, 0.001 for whole millimetres",
        )?;
        check_range(
            "noise.ripple_sigma_at_1m_m",
            self.ripple_sigma_at_1m_m,
            0.0,
            MAX_DEPTH_SIGMA_AT_1M_M,
            "m",
            "a 3D camera with more ripple than that at 1 m sees no robot",
        )?;
        check_range(
            "noise.ripple_correlation_px",
            self.ripple_correlation_px,
            1.0,
            10_000.0,
            "pixels",
            "the ripple's correlation length across the image",
        )?;
        if self.max_range_m != f64::INFINITY {
            check_range(
                "noise.max_range_m",
                self.max_range_m,
                MIN_RANGE_M,
                MAX_RANGE_M,
                "m",
                "inf for no limit",
            )?;
        }
        Ok(())
    }

    /// Probability that a point seen at `incidence_rad` (angle between the ray and the surface
    /// normal) survives grazing dropout.
    pub(crate) fn grazing_survival(&self, incidence_rad: f64) -> f64 {
        let a = incidence_rad.to_degrees();
        if a <= self.dropout_start_deg {
            1.0
        } else if a >= self.dropout_full_deg {
            0.0
        } else {
            1.0 - (a - self.dropout_start_deg) / (self.dropout_full_deg - self.dropout_start_deg)
        }
    }

    /// A noisy depth for a true depth `z` (metres) seen at `incidence_rad` by a pixel whose ray
    /// is `range_per_depth` long per unit of depth (1 on the optical axis): the range offset
    /// moves the depth by `depth_offset_m / range_per_depth`.
    pub(crate) fn noisy_depth(
        &self,
        z: f64,
        incidence_rad: f64,
        range_per_depth: f64,
        rng: &mut impl Rng,
    ) -> f64 {
        self.noisy_depth_of(z, incidence_rad.cos().max(0.2), range_per_depth, 1.0, rng)
    }

    /// [`Self::noisy_depth`] on a surface of `albedo` ([`Self::reference_albedo`]): its noise
    /// × [`Self::amplitude_noise_factor`], its range [`Self::dark_bias_m`] long. With the
    /// amplitude model on, the incidence enters as the albedo does, through the returned light
    /// (amplitude ∝ albedo · cos(incidence) / range², noise ∝ 1/√amplitude): × 1/√cos rather
    /// than the triangulating sensors' 1/cos.
    pub(crate) fn noisy_depth_on(
        &self,
        z: f64,
        incidence_rad: f64,
        range_per_depth: f64,
        albedo: f64,
        rng: &mut impl Rng,
    ) -> f64 {
        let z = z + self.dark_bias_m(albedo) / range_per_depth;
        let by_incidence = if self.reference_albedo > 0.0 {
            incidence_rad.cos().max(0.2).sqrt()
        } else {
            incidence_rad.cos().max(0.2)
        };
        self.noisy_depth_of(
            z,
            by_incidence,
            range_per_depth,
            self.amplitude_noise_factor(albedo),
            rng,
        )
    }

    /// How much noisier a surface of `albedo` is than one of the reference albedo: the phase
    /// noise grows as 1/√amplitude. 1 when surfaces are all alike.
    pub(crate) fn amplitude_noise_factor(&self, albedo: f64) -> f64 {
        if self.reference_albedo > 0.0 {
            (self.reference_albedo / albedo.max(MIN_ALBEDO)).sqrt()
        } else {
            1.0
        }
    }

    /// The range bias of a surface of `albedo` (metres, longer): [`Self::dark_range_bias_m`]
    /// scaled by how much darker than the reference it is. 0 when surfaces are all alike.
    pub(crate) fn dark_bias_m(&self, albedo: f64) -> f64 {
        if self.reference_albedo > 0.0 {
            self.dark_range_bias_m * (1.0 - albedo / self.reference_albedo).clamp(0.0, 1.0)
        } else {
            0.0
        }
    }

    /// A noisy depth whose σ is the noise at `z` × `sigma_factor` / `by_incidence` (how the
    /// surface's incidence weakens the measurement, 1 head-on).
    fn noisy_depth_of(
        &self,
        z: f64,
        by_incidence: f64,
        range_per_depth: f64,
        sigma_factor: f64,
        rng: &mut impl Rng,
    ) -> f64 {
        let sigma =
            self.depth_sigma_at_1m_m * sigma_factor * self.distance_factor(z) / by_incidence;
        let n = if sigma > 0.0 {
            Normal::new(0.0, sigma).map_or(0.0, |d| d.sample(rng))
        } else {
            0.0
        };
        (z + n) * (1.0 + self.depth_scale_error) + self.depth_offset_m / range_per_depth
    }

    /// These knobs as they are for the scan drawn from `seed`: the range offset drifted by a
    /// draw of [`Self::offset_drift_m`] (its own stream: the scan's other draws are as
    /// without it). Unchanged without drift.
    pub(crate) fn drifted(&self, seed: u64) -> Self {
        if self.offset_drift_m <= 0.0 {
            return *self;
        }
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed ^ OFFSET_DRIFT_SEED);
        let drift = Normal::new(0.0, self.offset_drift_m).map_or(0.0, |d| d.sample(&mut rng));
        Self {
            depth_offset_m: self.depth_offset_m + drift,
            ..*self
        }
    }

    /// The factor [`Self::depth_gradient`] puts on the depth `z` of the pixel whose ray is
    /// `(x/z, y/z, 1)`.
    pub(crate) fn gradient_factor(&self, z: f64, ray: &nalgebra::Vector3<f64>) -> f64 {
        1.0 + z * (self.depth_gradient[0] * ray.x + self.depth_gradient[1] * ray.y)
    }

    /// z^`depth_sigma_exponent` (z² computed as z·z, as it always was).
    fn distance_factor(&self, z: f64) -> f64 {
        if self.depth_sigma_exponent == 2.0 {
            z * z
        } else {
            z.powf(self.depth_sigma_exponent)
        }
    }

    /// `z` rounded to the sensor's depth resolution.
    pub(crate) fn quantized(&self, z: f64) -> f64 {
        if self.depth_step_m > 0.0 {
            (z / self.depth_step_m).round() * self.depth_step_m
        } else {
            z
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_validate_and_bad_knobs_are_named() {
        ScanNoise::default().validate().expect("defaults are valid");
        ScanNoise::none().validate().expect("none is valid");
        let bad = ScanNoise {
            random_dropout_probability: 1.5,
            ..ScanNoise::default()
        };
        let err = bad.validate().expect_err("invalid");
        assert!(err.contains("random_dropout_probability"));
    }

    /// σ of `noisy_depth` at `z` head-on, and its mean.
    fn spread(n: &ScanNoise, z: f64, seed: u64) -> (f64, f64) {
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        let s: Vec<f64> = (0..8000)
            .map(|_| n.noisy_depth(z, 0.0, 1.0, &mut rng))
            .collect();
        let mean = s.iter().sum::<f64>() / s.len() as f64;
        let var = s.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / s.len() as f64;
        (mean, var.sqrt())
    }

    #[test]
    fn time_of_flight_noise_grows_linearly_with_distance_and_is_offset() {
        let tof = ScanNoise::time_of_flight();
        tof.validate().expect("valid");
        let (m05, s05) = spread(&tof, 0.5, 1);
        let (m1, s1) = spread(&tof, 1.0, 2);
        let (m2, s2) = spread(&tof, 2.0, 3);
        // 1 mm at 1 m, linear in z: twice at 2 m, half at 0.5 m (z² would give 4× and ¼).
        assert!((s1 - 0.001).abs() < 5e-5, "{s1}");
        assert!((s2 / s1 - 2.0).abs() < 0.1, "{s1} {s2}");
        assert!((s1 / s05 - 2.0).abs() < 0.1, "{s05} {s1}");
        // a 1 mm offset and 0.1 % scale, the same offset at every distance
        assert!((m1 - (1.001 + 0.001)).abs() < 5e-5, "{m1}");
        assert!((m05 - (0.5005 + 0.001)).abs() < 5e-5, "{m05}");
        assert!((m2 - (2.002 + 0.001)).abs() < 1e-4, "{m2}");
        // the offset is on the range: an off-axis pixel's ray is 1.25 × its depth long
        let mut rng = rand::rngs::StdRng::seed_from_u64(6);
        let n = ScanNoise {
            depth_sigma_at_1m_m: 0.0,
            ..tof
        };
        let off_axis = n.noisy_depth(1.0, 0.0, 1.25, &mut rng);
        assert!(
            (off_axis - (1.001 + 0.001 / 1.25)).abs() < 1e-12,
            "{off_axis}"
        );
        // structured light keeps z²
        let sl = ScanNoise::default();
        let (_, a) = spread(&sl, 1.0, 4);
        let (_, b) = spread(&sl, 2.0, 5);
        assert!((b / a - 4.0).abs() < 0.2, "{a} {b}");
    }

    /// Issue 45: a time-of-flight camera's noise follows the returned light's amplitude
    /// (albedo · cos(incidence) / range²) as 1/√amplitude, the incidence included: at 60° it
    /// is √2 × the head-on noise, not the 2 × of a triangulating sensor (which keeps 1/cos).
    #[test]
    fn issue_45_time_of_flight_noise_grows_with_incidence_as_the_amplitude_falls() {
        let sd = |n: &ScanNoise, albedo: Option<f64>, incidence_deg: f64, seed: u64| {
            let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
            let s: Vec<f64> = (0..20_000)
                .map(|_| match albedo {
                    Some(a) => n.noisy_depth_on(1.0, incidence_deg.to_radians(), 1.0, a, &mut rng),
                    None => n.noisy_depth(1.0, incidence_deg.to_radians(), 1.0, &mut rng),
                })
                .collect();
            let mean = s.iter().sum::<f64>() / s.len() as f64;
            (s.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / s.len() as f64).sqrt()
        };
        let tof = ScanNoise::time_of_flight();
        let a = TOF_REFERENCE_ALBEDO;
        let ratio = sd(&tof, Some(a), 60.0, 7) / sd(&tof, Some(a), 0.0, 8);
        assert!(
            (ratio - 2f64.sqrt()).abs() < 0.05,
            "time of flight at 60°: {ratio}"
        );
        // A dark surface is noisier by the same law: 1/√(albedo / reference).
        let dark = sd(&tof, Some(a / 4.0), 0.0, 9) / sd(&tof, Some(a), 0.0, 8);
        assert!((dark - 2.0).abs() < 0.06, "a quarter of the light: {dark}");
        let sl = ScanNoise::default();
        let ratio = sd(&sl, None, 60.0, 10) / sd(&sl, None, 0.0, 11);
        assert!(
            (ratio - 2.0).abs() < 0.06,
            "structured light at 60°: {ratio}"
        );
    }

    #[test]
    fn new_knobs_are_range_checked_by_name() {
        for (n, key) in [
            (
                ScanNoise {
                    depth_sigma_exponent: 5.0,
                    ..ScanNoise::default()
                },
                "noise.depth_sigma_exponent",
            ),
            (
                ScanNoise {
                    depth_offset_m: f64::NAN,
                    ..ScanNoise::default()
                },
                "noise.depth_offset_m",
            ),
            (
                ScanNoise {
                    multipath_m: -0.01,
                    ..ScanNoise::default()
                },
                "noise.multipath_m",
            ),
            (
                ScanNoise {
                    multipath_window_px: 1000.0,
                    ..ScanNoise::default()
                },
                "noise.multipath_window_px",
            ),
        ] {
            let err = n.validate().expect_err(key);
            assert!(err.contains(key), "{err}");
        }
        assert_eq!(
            ScanNoise::of_class(SensorClass::TimeOfFlight),
            ScanNoise::time_of_flight()
        );
    }

    #[test]
    fn depth_noise_grows_with_distance_and_scale_error_is_applied() {
        let n = ScanNoise {
            depth_scale_error: 0.01,
            ..ScanNoise::default()
        };
        let mut rng = rand::rngs::StdRng::seed_from_u64(1);
        let spread = |z: f64, rng: &mut rand::rngs::StdRng| {
            let s: Vec<f64> = (0..4000).map(|_| n.noisy_depth(z, 0.0, 1.0, rng)).collect();
            let mean = s.iter().sum::<f64>() / s.len() as f64;
            let var = s.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / s.len() as f64;
            (mean, var.sqrt())
        };
        let (m1, s1) = spread(0.5, &mut rng);
        let (m2, s2) = spread(1.0, &mut rng);
        assert!((m2 - 1.01).abs() < 2e-5, "{m2}");
        assert!((m1 - 0.505).abs() < 1e-5, "{m1}");
        assert!(s2 > 3.0 * s1, "{s1} {s2}");
        assert!((s2 - 0.000_25 * 1.01).abs() < 2e-5, "{s2}");
        assert_eq!(n.grazing_survival(0.0), 1.0);
        assert_eq!(n.grazing_survival(89f64.to_radians()), 0.0);
    }
}
