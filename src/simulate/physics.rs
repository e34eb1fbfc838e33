//! Fields: rotations into body axes, buried dipoles, geomagnetic variation,
//! the aircraft's own field and the fluxgate's calibration errors.

use std::f64::consts::PI;

use nalgebra::{Matrix3, Vector3};

use crate::simulate::random::Random;

/// A 3-vector, nT unless named otherwise: the simulator's storage type
/// (written to the truth files as `[x, y, z]`); the algebra is nalgebra's.
pub type Vector = [f64; 3];

fn vector3(v: Vector) -> Vector3<f64> {
    Vector3::from(v)
}

/// Dot product.
pub fn dot(a: Vector, b: Vector) -> f64 {
    vector3(a).dot(&vector3(b))
}

/// Euclidean norm.
pub fn norm(a: Vector) -> f64 {
    vector3(a).norm()
}

/// Component-wise sum.
pub fn add(a: Vector, b: Vector) -> Vector {
    (vector3(a) + vector3(b)).into()
}

/// Matrix-vector product, `matrix` given by rows.
pub fn apply(matrix: &[Vector; 3], v: Vector) -> Vector {
    (Matrix3::from_fn(|i, j| matrix[i][j]) * vector3(v)).into()
}

pub use crate::ingest::flight_log::body_to_ned;

/// Rotates a north-east-down vector into body axes: $v_b = R^\top v_{NED}$.
pub fn to_body(ned: Vector, roll_deg: f64, pitch_deg: f64, yaw_deg: f64) -> Vector {
    body_to_ned(roll_deg, pitch_deg, yaw_deg)
        .inverse_transform_vector(&vector3(ned))
        .into()
}

/// Rotates a body vector into north-east-down axes: $R\,v_b$.
pub fn to_ned(body: Vector, roll_deg: f64, pitch_deg: f64, yaw_deg: f64) -> Vector {
    (body_to_ned(roll_deg, pitch_deg, yaw_deg) * vector3(body)).into()
}

/// Field of a point dipole of moment `moment_a_m2` at `offset_m` from the
/// dipole to the observer, nT (Blakely 1995, eq. 4.13):
/// $B = \frac{\mu_0}{4\pi} \frac{3(m\cdot\hat r)\hat r - m}{r^3}$.
pub fn dipole_field_nt(moment_a_m2: Vector, offset_m: Vector) -> Vector {
    let (moment, offset) = (vector3(moment_a_m2), vector3(offset_m));
    let inverse = 1.0 / offset.norm();
    let unit = offset * inverse;
    // μ0/4π = 1e-7 T·m/A = 100 nT·m/A.
    ((3.0 * moment.dot(&unit) * unit - moment) * (100.0 * inverse * inverse * inverse)).into()
}

/// Buried dipoles: the crustal anomaly.
#[derive(Debug, Clone, PartialEq)]
pub struct Crust {
    /// (position north, east, down of the start in m, moment A·m²).
    pub dipoles: Vec<(Vector, Vector)>,
}

impl Crust {
    /// Scatters `count` dipoles under the box `northing × easting` (m),
    /// `depth` m below `ground_down_m`, magnetised mostly along the main
    /// field's direction `main_unit` (induced) with a remanent share.
    pub fn scatter(
        random: &mut Random,
        count: usize,
        northing_m: [f64; 2],
        easting_m: [f64; 2],
        depth_m: [f64; 2],
        moment_a_m2: f64,
        main_unit: Vector,
    ) -> Crust {
        let dipoles = (0..count)
            .map(|_| {
                let position = [
                    random.uniform(northing_m[0], northing_m[1]),
                    random.uniform(easting_m[0], easting_m[1]),
                    random.uniform(depth_m[0], depth_m[1]),
                ];
                let size = moment_a_m2 * random.uniform(0.3, 1.5);
                let remanent = random.vector(0.4);
                let moment = [0, 1, 2].map(|i| size * (main_unit[i] + remanent[i]));
                (position, moment)
            })
            .collect();
        Crust { dipoles }
    }

    /// The anomaly field at `position_m` (north, east, down of the start).
    pub fn field_nt(&self, position_m: Vector) -> Vector {
        let field = self.dipoles.iter().fold(Vector3::zeros(), |sum, (at, moment)| {
            sum + vector3(dipole_field_nt(*moment, (vector3(position_m) - vector3(*at)).into()))
        });
        field.into()
    }

    /// [`Self::field_nt`] at each of `positions_m`, bit for bit: eight
    /// positions at a time, each dipole's arithmetic on all eight at once
    /// (in vector registers where the processor has them; the same
    /// operations in the same order on every path).
    pub fn fields_nt(&self, positions_m: &[Vector]) -> Vec<Vector> {
        let (chunks, rest) = positions_m.as_chunks::<LANES>();
        let mut fields = Vec::with_capacity(positions_m.len());
        for chunk in chunks {
            fields.extend(self.lanes(chunk));
        }
        fields.extend(rest.iter().map(|&at| self.field_nt(at)));
        fields
    }

    /// The field at eight positions, with the processor's widest vectors.
    fn lanes(&self, positions_m: &[Vector; LANES]) -> [Vector; LANES] {
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx512f") {
                // SAFETY: the processor supports AVX-512F, checked just above.
                return unsafe { self.lanes_avx512(positions_m) };
            }
            if std::arch::is_x86_feature_detected!("avx2") {
                // SAFETY: the processor supports AVX2, checked just above.
                return unsafe { self.lanes_avx2(positions_m) };
            }
        }
        self.lanes_of(positions_m)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    unsafe fn lanes_avx512(&self, positions_m: &[Vector; LANES]) -> [Vector; LANES] {
        self.lanes_of(positions_m)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn lanes_avx2(&self, positions_m: &[Vector; LANES]) -> [Vector; LANES] {
        self.lanes_of(positions_m)
    }

    /// [`dipole_field_nt`] summed over the dipoles, as [`Self::field_nt`]
    /// sums it, lane by lane: $r^2 = (x^2 + y^2) + z^2$, $\hat r = r/|r|$,
    /// $(3 (m\cdot\hat r)\,\hat r_i - m_i)\,(100/|r|^3)$.
    #[inline(always)]
    fn lanes_of(&self, positions_m: &[Vector; LANES]) -> [Vector; LANES] {
        let mut sum = [[0.0; LANES]; 3];
        for (at, moment) in &self.dipoles {
            for lane in 0..LANES {
                let offset: Vector = std::array::from_fn(|i| positions_m[lane][i] - at[i]);
                let inverse = 1.0 / (offset[0] * offset[0] + offset[1] * offset[1] + offset[2] * offset[2]).sqrt();
                let unit = offset.map(|o| o * inverse);
                let along = 3.0 * (moment[0] * unit[0] + moment[1] * unit[1] + moment[2] * unit[2]);
                let scale = 100.0 * inverse * inverse * inverse;
                for i in 0..3 {
                    sum[i][lane] += (along * unit[i] - moment[i]) * scale;
                }
            }
        }
        std::array::from_fn(|lane| [sum[0][lane], sum[1][lane], sum[2][lane]])
    }
}

/// Positions the crust's field is computed for at once.
const LANES: usize = 8;

/// Geomagnetic variation of external origin: a daily variation and
/// Pc3–Pc5 pulsations (periods 10–600 s), as NED vectors.
#[derive(Debug, Clone, PartialEq)]
pub struct ExternalField {
    /// (amplitude vector nT, period s, phase rad) of each component.
    waves: Vec<(Vector, f64, f64)>,
}

impl ExternalField {
    /// Draws a daily variation of `diurnal_nt` and pulsations of RMS
    /// `pulsation_nt`. Pulsations are mostly horizontal, the daily
    /// variation mostly in H and Z.
    pub fn draw(random: &mut Random, diurnal_nt: f64, pulsation_nt: f64) -> ExternalField {
        let mut waves = vec![
            (
                [-0.7, 0.2, 0.5].map(|c| c * diurnal_nt),
                86_400.0,
                random.uniform(0.0, 2.0 * PI),
            ),
            (
                [0.3, -0.4, 0.2].map(|c| c * diurnal_nt),
                21_600.0,
                random.uniform(0.0, 2.0 * PI),
            ),
        ];
        let count = 12;
        for _ in 0..count {
            let period = (10f64.ln() + random.uniform(0.0, 1.0) * (60f64).ln()).exp();
            let direction = [
                random.uniform(-1.0, 1.0),
                random.uniform(-1.0, 1.0),
                random.uniform(-0.3, 0.3),
            ];
            let scale = pulsation_nt * (2.0 / count as f64).sqrt() / norm(direction).max(1e-9);
            waves.push((direction.map(|c| c * scale), period, random.uniform(0.0, 2.0 * PI)));
        }
        ExternalField { waves }
    }

    /// Adds pulsations of RMS `amplitude_nt` (the strong-pulsation effect).
    pub fn strengthen(&mut self, random: &mut Random, amplitude_nt: f64) {
        let extra = ExternalField::draw(random, 0.0, amplitude_nt);
        self.waves.extend(extra.waves.into_iter().skip(2));
    }

    /// The variation at time `t_s`, nT.
    pub fn field_nt(&self, t_s: f64) -> Vector {
        let field = self
            .waves
            .iter()
            .fold(Vector3::zeros(), |sum, (amplitude, period, phase)| {
                sum + vector3(*amplitude) * (2.0 * PI * t_s / period + phase).sin()
            });
        field.into()
    }
}

/// The aircraft's field at one sensor: $P + A\,B + E\,\dot B$ with P in nT,
/// A dimensionless and E in s (Tolles & Lawson 1950, in vector form).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AircraftField {
    /// Permanent field, nT.
    pub permanent_nt: Vector,
    /// Induced tensor.
    pub induced: [Vector; 3],
    /// Eddy-current tensor, s.
    pub eddy_s: [Vector; 3],
}

impl AircraftField {
    /// Draws a field of the given sizes. The induced tensor is symmetric
    /// (soft iron), the eddy tensor is not.
    pub fn draw(random: &mut Random, permanent_nt: f64, induced: f64, eddy_s: f64) -> Self {
        let mut tensor = [random.vector(induced), random.vector(induced), random.vector(induced)];
        (tensor[1][0], tensor[2][0], tensor[2][1]) = (tensor[0][1], tensor[0][2], tensor[1][2]);
        AircraftField {
            permanent_nt: random.vector(permanent_nt),
            induced: tensor,
            eddy_s: [random.vector(eddy_s), random.vector(eddy_s), random.vector(eddy_s)],
        }
    }

    /// Whether every constant is finite and of a size an aircraft can
    /// have at a magnetometer.
    pub fn is_plausible(&self) -> bool {
        let all = |rows: &[Vector; 3], limit: f64| rows.iter().flatten().all(|v| v.is_finite() && v.abs() <= limit);
        self.permanent_nt.iter().all(|v| v.is_finite() && v.abs() <= 1e6)
            && all(&self.induced, 1.0)
            && all(&self.eddy_s, 10.0)
    }

    /// The aircraft field for Earth field `field` and eddy drive `rate`
    /// (nT/s), body axes.
    pub fn at(&self, field: Vector, rate: Vector) -> Vector {
        add(
            self.permanent_nt,
            add(apply(&self.induced, field), apply(&self.eddy_s, rate)),
        )
    }
}

/// The parameters of a fluxgate's calibration errors.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FluxgateCalibration {
    /// Scale factor per axis (1 = perfect).
    pub scale: Vector,
    /// Non-orthogonality angles (xy, xz, yz), degrees.
    pub non_orthogonality_deg: Vector,
    /// Offset per axis, nT.
    pub offset_nt: Vector,
}

impl FluxgateCalibration {
    /// Draws residual errors of the given sizes.
    pub fn draw(random: &mut Random, scale_error: f64, non_orthogonality_deg: f64, offset_nt: f64) -> Self {
        FluxgateCalibration {
            scale: random.vector(scale_error).map(|e| 1.0 + e),
            non_orthogonality_deg: random.vector(non_orthogonality_deg),
            offset_nt: random.vector(offset_nt),
        }
    }

    /// The error model these parameters describe.
    pub fn errors(&self) -> FluxgateErrors {
        FluxgateErrors::new(self.scale, self.non_orthogonality_deg, self.offset_nt)
    }
}

/// A fluxgate's scale, non-orthogonality and offset errors:
/// $m = K\,b + o$ with K lower-triangular (Gebre-Egziabher et al. 2006).
#[derive(Debug, Clone, PartialEq)]
pub struct FluxgateErrors {
    /// K.
    pub matrix: [Vector; 3],
    /// o, nT.
    pub offset_nt: Vector,
}

impl FluxgateErrors {
    /// A perfect fluxgate.
    pub fn none() -> Self {
        FluxgateErrors {
            matrix: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            offset_nt: [0.0; 3],
        }
    }

    /// From scale factors, non-orthogonality angles (xy, xz, yz; degrees)
    /// and offsets: the y axis leans by ρ_xy towards x, the z axis by ρ_xz
    /// towards x and ρ_yz towards y.
    pub fn new(scale: Vector, non_orthogonality_deg: Vector, offset_nt: Vector) -> Self {
        let [xy, xz, yz] = non_orthogonality_deg.map(|a| a.to_radians().sin());
        let z_cos = (1.0 - xz * xz - yz * yz).max(0.0).sqrt();
        FluxgateErrors {
            matrix: [
                [scale[0], 0.0, 0.0],
                [scale[1] * xy, scale[1] * (1.0 - xy * xy).sqrt(), 0.0],
                [scale[2] * xz, scale[2] * yz, scale[2] * z_cos],
            ],
            offset_nt,
        }
    }

    /// The reading of true field `b`.
    pub fn read(&self, b: Vector) -> Vector {
        add(apply(&self.matrix, b), self.offset_nt)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The crust's field eight positions at a time is the field at each,
    /// bit for bit, on every path the processor takes (and the rest of a
    /// block that is not a whole eight), and is a dipole's field: it falls
    /// as the cube of the distance.
    #[test]
    fn the_crust_eight_at_a_time_is_the_crust_at_each_bit_for_bit() {
        let mut random = Random::new(7);
        let crust = Crust::scatter(
            &mut random,
            8,
            [-3000.0, 3000.0],
            [-2000.0, 2000.0],
            [150.0, 800.0],
            1.5e8,
            [0.3, 0.1, 0.95],
        );
        let positions: Vec<Vector> = (0..1003)
            .map(|_| {
                [
                    random.uniform(-4000.0, 4000.0),
                    random.uniform(-3000.0, 3000.0),
                    random.uniform(-600.0, -50.0),
                ]
            })
            .collect();
        let fields = crust.fields_nt(&positions);
        assert_eq!(fields.len(), positions.len());
        for (at, field) in positions.iter().zip(&fields) {
            assert_eq!(
                field.map(f64::to_bits),
                crust.field_nt(*at).map(f64::to_bits),
                "at {at:?}"
            );
        }
        let chunk: &[Vector; LANES] = positions[..LANES].try_into().unwrap();
        assert_eq!(crust.lanes_of(chunk), crust.lanes(chunk));
        let one = Crust {
            dipoles: vec![([0.0, 0.0, 500.0], [0.0, 0.0, 1e8])],
        };
        let [near, far] = [one.field_nt([0.0, 0.0, 300.0]), one.field_nt([0.0, 0.0, 100.0])];
        assert!((near[2] / far[2] - 8.0).abs() < 1e-12, "{near:?} {far:?}");
    }

    #[test]
    fn heading_east_puts_north_off_the_left_wing() {
        let b = to_body([1.0, 0.0, 0.0], 0.0, 0.0, 90.0);
        assert!(b[0].abs() < 1e-15 && (b[1] + 1.0).abs() < 1e-15);
        let back = to_ned(to_body([1.0, 2.0, 3.0], 10.0, -4.0, 33.0), 10.0, -4.0, 33.0);
        assert!((0..3).all(|i| (back[i] - [1.0, 2.0, 3.0][i]).abs() < 1e-12));
    }

    #[test]
    fn dipole_on_axis_follows_the_inverse_cube_law() {
        // m = 1e8 A·m² along z, 1000 m away on its axis: B = μ0/4π · 2m/r³ = 20 nT.
        let b = dipole_field_nt([0.0, 0.0, 1e8], [0.0, 0.0, 1000.0]);
        assert!((b[2] - 20.0).abs() < 1e-9 && b[0].abs() < 1e-12);
        // Broadside, half as strong and reversed: −10 nT.
        let b = dipole_field_nt([0.0, 0.0, 1e8], [1000.0, 0.0, 0.0]);
        assert!((b[2] + 10.0).abs() < 1e-9);
    }

    #[test]
    fn pulsation_rms_matches_the_request() {
        let field = ExternalField::draw(&mut Random::new(2), 0.0, 1.0);
        let samples: Vec<f64> = (0..200_000).map(|k| norm(field.field_nt(k as f64 * 0.5))).collect();
        let rms = (samples.iter().map(|v| v * v).sum::<f64>() / samples.len() as f64).sqrt();
        // Twelve sinusoids of random period: the vector RMS over 28 h is the
        // requested 1 nT within the beat of the components (±15 %).
        assert!((rms - 1.0).abs() < 0.15, "rms {rms}");
    }

    #[test]
    fn fluxgate_errors_preserve_a_perfect_sensor() {
        let perfect = FluxgateErrors::new([1.0; 3], [0.0; 3], [0.0; 3]);
        assert_eq!(perfect, FluxgateErrors::none());
    }
}
