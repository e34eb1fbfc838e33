//! The International Geomagnetic Reference Field, 14th generation, in f64.
//!
//! The main field is the gradient of the internal potential (Alken et al.
//! 2025, IGRF-14; Winch et al. 2005 for the spherical-harmonic conventions)
//!
//! $$V(r,\theta,\phi) = a \sum_{n=1}^{13} \left(\frac{a}{r}\right)^{n+1}
//!   \sum_{m=0}^{n} \left(g_n^m \cos m\phi + h_n^m \sin m\phi\right) P_n^m(\cos\theta)$$
//!
//! with $a$ = 6371.2 km and $P_n^m$ the Schmidt semi-normalised associated
//! Legendre functions. Coefficients are interpolated linearly between the
//! 5-year epochs, and extrapolated with the secular variation after 2025.
//! Positions are geodetic (WGS-84); the field comes back in the local
//! geodetic north-east-down frame, nT.

use std::sync::OnceLock;

/// The coefficient file, unchanged from its published form (see
/// `data/igrf/README.md`).
const COEFFICIENT_FILE: &str = include_str!("../../data/igrf/IGRF14.shc");

/// Geomagnetic reference radius, km.
const REFERENCE_RADIUS_KM: f64 = 6371.2;
/// WGS-84 semi-major axis, km.
const WGS84_A_KM: f64 = 6378.137;
/// WGS-84 flattening.
const WGS84_FLATTENING: f64 = 1.0 / 298.257_223_563;

/// Gauss coefficients of every epoch.
#[derive(Debug, Clone, PartialEq)]
pub struct Igrf {
    /// Maximum degree.
    degree: usize,
    /// Epochs, decimal years.
    epochs: Vec<f64>,
    /// `g[epoch][index(n, m)]`, nT.
    g_nt: Vec<Vec<f64>>,
    /// `h[epoch][index(n, m)]`, nT.
    h_nt: Vec<Vec<f64>>,
}

/// The main field at one place and time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MainField {
    /// North, east and down components, nT (geodetic frame).
    pub north_east_down_nt: [f64; 3],
}

impl MainField {
    /// Total intensity F, nT.
    pub fn total_nt(&self) -> f64 {
        let [x, y, z] = self.north_east_down_nt;
        (x * x + y * y + z * z).sqrt()
    }

    /// Inclination I, degrees, positive down.
    pub fn inclination_deg(&self) -> f64 {
        let [x, y, z] = self.north_east_down_nt;
        z.atan2(x.hypot(y)).to_degrees()
    }

    /// Declination D, degrees, positive east.
    pub fn declination_deg(&self) -> f64 {
        let [x, y, _] = self.north_east_down_nt;
        y.atan2(x).to_degrees()
    }
}

fn index(n: usize, m: usize) -> usize {
    n * (n + 1) / 2 + m
}

impl Igrf {
    /// The IGRF-14 model, parsed once from the vendored coefficient file.
    pub fn fourteenth() -> &'static Igrf {
        static MODEL: OnceLock<Igrf> = OnceLock::new();
        MODEL.get_or_init(|| {
            Igrf::parse(COEFFICIENT_FILE).unwrap_or_else(|e| unreachable!("vendored IGRF-14 file: {e}"))
        })
    }

    /// Parses a coefficient file in the SHC layout: `#` comments, a
    /// parameter line, a line of epochs, then `n m value...` rows with
    /// negative `m` for the `h` coefficients.
    pub fn parse(text: &str) -> Result<Igrf, String> {
        let mut lines = text
            .lines()
            .filter(|l| !l.trim_start().starts_with('#') && !l.trim().is_empty());
        let header: Vec<f64> = numbers(lines.next().ok_or("no parameter line")?)?;
        let degree = *header.get(1).ok_or("parameter line has no maximum degree")? as usize;
        if !(1..=MAX_DEGREE).contains(&degree) {
            return Err(format!(
                "maximum degree {degree}: this evaluator takes 1 to {MAX_DEGREE}"
            ));
        }
        let epochs = numbers(lines.next().ok_or("no epoch line")?)?;
        let size = index(degree, degree) + 1;
        let mut g_nt = vec![vec![0.0; size]; epochs.len()];
        let mut h_nt = vec![vec![0.0; size]; epochs.len()];
        for line in lines {
            let row = numbers(line)?;
            if row.len() != epochs.len() + 2 {
                return Err(format!(
                    "row '{line}' has {} values, expected {}",
                    row.len(),
                    epochs.len() + 2
                ));
            }
            let (n, m) = (row[0] as usize, row[1] as i64);
            if n == 0 || n > degree || m.unsigned_abs() as usize > n {
                return Err(format!("row '{line}' has degree {n}, order {m} outside the model"));
            }
            let target = if m < 0 { &mut h_nt } else { &mut g_nt };
            for (epoch, value) in row[2..].iter().enumerate() {
                target[epoch][index(n, m.unsigned_abs() as usize)] = *value;
            }
        }
        Ok(Igrf {
            degree,
            epochs,
            g_nt,
            h_nt,
        })
    }

    /// First and last epochs the model covers, decimal years.
    pub fn valid_years(&self) -> (f64, f64) {
        (self.epochs[0], self.epochs[self.epochs.len() - 1])
    }

    /// The model's coefficients at `year`, linear in time between epochs
    /// (extrapolated with the secular variation after 2025).
    pub fn at_year(&self, year: f64) -> IgrfEpoch {
        let last = self.epochs.len() - 2;
        let slot = self.epochs.partition_point(|&e| e <= year).saturating_sub(1).min(last);
        let span = self.epochs[slot + 1] - self.epochs[slot];
        let weight = (year - self.epochs[slot]) / span;
        let blend = |table: &[Vec<f64>]| -> Vec<f64> {
            table[slot]
                .iter()
                .zip(&table[slot + 1])
                .map(|(a, b)| a + weight * (b - a))
                .collect()
        };
        IgrfEpoch {
            degree: self.degree,
            g_nt: blend(&self.g_nt),
            h_nt: blend(&self.h_nt),
            roots: RecursionRoots::new(self.degree),
        }
    }

    /// The main field at geodetic latitude and longitude (degrees), height
    /// above the WGS-84 ellipsoid (m) and decimal year.
    pub fn field(&self, latitude_deg: f64, longitude_deg: f64, height_m: f64, year: f64) -> MainField {
        self.at_year(year).field(latitude_deg, longitude_deg, height_m)
    }
}

/// The model's coefficients at one instant.
#[derive(Debug, Clone, PartialEq)]
pub struct IgrfEpoch {
    degree: usize,
    g_nt: Vec<f64>,
    h_nt: Vec<f64>,
    /// The square roots of the Legendre recursions, the same at every
    /// place.
    roots: RecursionRoots,
}

/// The largest degree a model may have: IGRF-14's. The evaluation keeps
/// its tables on the stack.
const MAX_DEGREE: usize = 13;
/// Coefficients up to [`MAX_DEGREE`].
const MAX_TERMS: usize = (MAX_DEGREE + 1) * (MAX_DEGREE + 2) / 2;

/// The square roots the Legendre recursions take, by `index(n, m)`: each
/// is what the recursion would compute in place, computed once.
#[derive(Debug, Clone, PartialEq)]
struct RecursionRoots {
    /// $\sqrt{(2n-1)/2n}$ at `index(n, n)` (1 for $n = 1$).
    diagonal: Vec<f64>,
    /// $\sqrt{n^2-m^2}$ at `index(n, m)`, $m < n$.
    norm: Vec<f64>,
    /// $\sqrt{(n-1)^2-m^2}$ at `index(n, m)`, $m + 2 \le n$.
    weight: Vec<f64>,
}

impl RecursionRoots {
    fn new(degree: usize) -> Self {
        let size = index(degree, degree) + 1;
        let (mut diagonal, mut norm, mut weight) = (vec![0.0; size], vec![0.0; size], vec![0.0; size]);
        for n in 1..=degree {
            diagonal[index(n, n)] = if n == 1 {
                1.0
            } else {
                ((2 * n - 1) as f64 / (2 * n) as f64).sqrt()
            };
            for m in 0..n {
                norm[index(n, m)] = ((n * n - m * m) as f64).sqrt();
                if n >= m + 2 {
                    weight[index(n, m)] = (((n - 1) * (n - 1) - m * m) as f64).sqrt();
                }
            }
        }
        RecursionRoots { diagonal, norm, weight }
    }
}

impl IgrfEpoch {
    /// The main field at geodetic latitude and longitude (degrees) and
    /// height above the WGS-84 ellipsoid (m).
    pub fn field(&self, latitude_deg: f64, longitude_deg: f64, height_m: f64) -> MainField {
        let place = Geocentric::from_geodetic(latitude_deg, height_m / 1000.0);
        let [radial, theta, phi] = self.spherical_components(&place, longitude_deg.to_radians());
        let (north_c, down_c) = (-theta, -radial);
        let (sd, cd) = place.tilt_rad.sin_cos();
        MainField {
            north_east_down_nt: [north_c * cd + down_c * sd, phi, down_c * cd - north_c * sd],
        }
    }

    /// $(B_r, B_\theta, B_\phi)$ in nT from the gradient of the potential.
    fn spherical_components(&self, place: &Geocentric, longitude_rad: f64) -> [f64; 3] {
        let legendre = SchmidtLegendre::new(self.degree, &self.roots, place.colatitude_rad);
        let sin_theta = place.colatitude_rad.sin();
        let ratio = REFERENCE_RADIUS_KM / place.radius_km;
        // sin mφ and cos mφ, each order once.
        let mut turns = [(0.0, 0.0); MAX_DEGREE + 1];
        for (m, turn) in turns.iter_mut().enumerate().take(self.degree + 1) {
            *turn = (m as f64 * longitude_rad).sin_cos();
        }
        let mut field = [0.0; 3];
        let mut scale = ratio * ratio;
        for n in 1..=self.degree {
            scale *= ratio;
            for (m, &(sin_m, cos_m)) in turns.iter().enumerate().take(n + 1) {
                let k = index(n, m);
                let along = self.g_nt[k] * cos_m + self.h_nt[k] * sin_m;
                let across = m as f64 * (self.h_nt[k] * cos_m - self.g_nt[k] * sin_m);
                field[0] += scale * (n + 1) as f64 * along * legendre.value[k];
                field[1] -= scale * along * legendre.derivative[k];
                field[2] -= scale * across * legendre.value[k];
            }
        }
        field[2] /= sin_theta.max(1e-12);
        field
    }
}

fn numbers(line: &str) -> Result<Vec<f64>, String> {
    line.split_whitespace()
        .map(|word| word.parse::<f64>().map_err(|_| format!("'{word}' is not a number")))
        .collect()
}

/// A place in geocentric spherical coordinates.
struct Geocentric {
    radius_km: f64,
    colatitude_rad: f64,
    /// Geodetic minus geocentric latitude, radians.
    tilt_rad: f64,
}

impl Geocentric {
    /// Converts geodetic latitude and ellipsoidal height (km) through
    /// Earth-centred Cartesian coordinates (WGS-84).
    fn from_geodetic(latitude_deg: f64, height_km: f64) -> Self {
        let latitude = latitude_deg.to_radians();
        let (sin_lat, cos_lat) = latitude.sin_cos();
        let e2 = WGS84_FLATTENING * (2.0 - WGS84_FLATTENING);
        let prime_vertical = WGS84_A_KM / (1.0 - e2 * sin_lat * sin_lat).sqrt();
        let axial = (prime_vertical + height_km) * cos_lat;
        let polar = (prime_vertical * (1.0 - e2) + height_km) * sin_lat;
        let geocentric_latitude = polar.atan2(axial);
        Geocentric {
            radius_km: axial.hypot(polar),
            colatitude_rad: std::f64::consts::FRAC_PI_2 - geocentric_latitude,
            tilt_rad: latitude - geocentric_latitude,
        }
    }
}

/// Schmidt semi-normalised $P_n^m(\cos\theta)$ and $dP_n^m/d\theta$.
struct SchmidtLegendre {
    value: [f64; MAX_TERMS],
    derivative: [f64; MAX_TERMS],
}

impl SchmidtLegendre {
    /// Builds the table by the standard recursions: along the diagonal
    /// $P_n^n = \sqrt{(2n-1)/2n}\,\sin\theta\,P_{n-1}^{n-1}$ ($P_1^1 = \sin\theta$),
    /// then down each order
    /// $P_n^m = [(2n-1)\cos\theta P_{n-1}^m - \sqrt{(n-1)^2-m^2}\,P_{n-2}^m]/\sqrt{n^2-m^2}$.
    fn new(degree: usize, roots: &RecursionRoots, colatitude_rad: f64) -> Self {
        let (s, c) = colatitude_rad.sin_cos();
        let mut value = [0.0; MAX_TERMS];
        let mut derivative = [0.0; MAX_TERMS];
        value[0] = 1.0;
        for n in 1..=degree {
            let (k, previous) = (index(n, n), index(n - 1, n - 1));
            let factor = roots.diagonal[k];
            value[k] = factor * s * value[previous];
            derivative[k] = factor * (c * value[previous] + s * derivative[previous]);
        }
        for m in 0..degree {
            for n in (m + 1)..=degree {
                let k = index(n, m);
                let one_back = index(n - 1, m);
                let norm = roots.norm[k];
                let mut p = (2 * n - 1) as f64 * c * value[one_back];
                let mut dp = (2 * n - 1) as f64 * (c * derivative[one_back] - s * value[one_back]);
                if n >= m + 2 {
                    let two_back = index(n - 2, m);
                    let weight = roots.weight[k];
                    p -= weight * value[two_back];
                    dp -= weight * derivative[two_back];
                }
                value[k] = p / norm;
                derivative[k] = dp / norm;
            }
        }
        SchmidtLegendre { value, derivative }
    }
}

/// Decimal year of a calendar date (UTC), counting the days of the year.
pub fn decimal_year(year: i32, month: u32, day: u32, seconds_of_day: f64) -> f64 {
    let leap = (year % 4 == 0 && year % 100 != 0) || year % 400 == 0;
    let lengths = [31, if leap { 29 } else { 28 }, 31, 30, 31, 30, 31, 31, 30, 31, 30, 31];
    let before: u32 = lengths.iter().take(month.saturating_sub(1) as usize).sum();
    let days_in_year = if leap { 366.0 } else { 365.0 };
    year as f64 + (before as f64 + day as f64 - 1.0 + seconds_of_day / 86_400.0) / days_in_year
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_vendored_file_holds_degree_13_from_1900_to_2030() {
        let model = Igrf::fourteenth();
        assert_eq!(model.degree, 13);
        assert_eq!(model.valid_years(), (1900.0, 2030.0));
        // g_1^0 in 2025, the dipole term, as printed in the file.
        assert_eq!(model.g_nt[25][index(1, 0)], -29350.0);
    }

    #[test]
    fn legendre_functions_match_their_closed_forms() {
        // P_2^0 = (3cos²θ − 1)/2, P_2^1 = √3 cosθ sinθ, P_2^2 = √3/2 sin²θ (Schmidt).
        let theta: f64 = 0.7;
        let (s, c) = theta.sin_cos();
        let table = SchmidtLegendre::new(3, &RecursionRoots::new(3), theta);
        let expected = [(1.5 * c * c - 0.5), 3f64.sqrt() * c * s, 3f64.sqrt() / 2.0 * s * s];
        for (m, value) in expected.iter().enumerate() {
            assert!((table.value[index(2, m)] - value).abs() < 1e-15);
        }
        // dP_2^0/dθ = −3 cosθ sinθ.
        assert!((table.derivative[index(2, 0)] + 3.0 * c * s).abs() < 1e-15);
    }

    #[test]
    fn decimal_year_counts_days() {
        assert_eq!(decimal_year(2025, 1, 1, 0.0), 2025.0);
        assert!((decimal_year(2024, 7, 2, 0.0) - (2024.0 + 183.0 / 366.0)).abs() < 1e-12);
    }
}
