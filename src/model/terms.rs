//! The Tolles-Lawson design matrix.
//!
//! The aircraft's interference on a scalar magnetometer is written as a
//! linear combination of terms built from the direction cosines
//! $u_i = B_i / |B|$ of the field measured by a vector magnetometer
//! (Tolles & Lawson 1950; Leliak 1961):
//!
//! $$ H = \sum_i p_i u_i + \sum_{i \le j} a_{ij} \, u_i B_j / s + \sum_{i,j} b_{ij} \, u_i \dot B_j / s $$
//!
//! with $s$ = `bt_scale_nt` (50 000 nT by default) keeping the columns of
//! order one. $\dot B_j$ is the per-sample central difference of $B_j$
//! (one-sided at the ends of each contiguous run), in nT per sample.
//! Column order and definitions follow MagNav.jl's `create_TL_A`
//! (Gnadt 2022), so coefficients are interchangeable.

use std::ops::Range;

use serde::{Deserialize, Serialize};

/// Which induced (soft-iron) terms to use.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum InducedTerms {
    /// No induced terms.
    None,
    /// $u_x B_x, u_y B_y, u_z B_z$.
    Three,
    /// All six except $u_z B_z$.
    Five,
    /// $u_i B_j$ for $i \le j$.
    Six,
    /// The six less their isotropic part: the three $u_i B_j$ across the
    /// diagonal and two traceless diagonal combinations,
    /// $(u_x B_x - u_y B_y)/\sqrt 2$ and $(u_x B_x + u_y B_y - 2 u_z B_z)/\sqrt 6$.
    /// The diagonal's sum is $|B|$ itself, the Earth's field: a scalar fit
    /// cannot tell an isotropic induced field from the field it measures,
    /// so that direction only takes in geomagnetic variation (see
    /// [`TermSet`]).
    Traceless,
}

/// Which eddy-current terms to use.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum EddyTerms {
    /// No eddy terms.
    None,
    /// $u_x \dot B_x, u_y \dot B_y, u_z \dot B_z$.
    Three,
    /// All nine except $u_z \dot B_z$.
    Eight,
    /// $u_i \dot B_j$ for every $i, j$.
    Nine,
    /// The nine less their isotropic part $\sum_i u_i \dot B_i = d|B|/dt$:
    /// the six across the diagonal and the two traceless diagonal
    /// combinations, as for [`InducedTerms::Traceless`].
    Traceless,
}

/// The set of Tolles-Lawson terms and their scale.
///
/// The default is Tolles-Lawson's 18 terms less their two isotropic
/// directions (16 columns; [`TermSet::magnav`] has all 18). Of the induced
/// terms, $\sum_i u_i B_i = |B|$;
/// of the eddy terms, $\sum_i u_i \dot B_i = d|B|/dt$. Both are the
/// Earth's own field, which the scalar also reads: fitted, they take in
/// whatever geomagnetic variation (pulsations, crustal field) lies in the
/// fit's band, and on the survey subtract that fraction of the anomalies.
/// On clean simulated flights the 18-term fit scaled the survey's
/// anomalies by up to 0.77 (1.8 nT mean error over 256 channels, 0.06 nT
/// without them). An induced field along B is also what the field of
/// soft iron outside the sensor is not: the field of an isotropically
/// induced dipole, $(3\hat r \hat r^\top - I) m / r^3$, is traceless.
/// `terms = ["permanent", "induced_6", "eddy_9"]` restores them.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TermSet {
    /// The 3 permanent (hard-iron) terms $u_i$.
    pub permanent: bool,
    /// Induced terms.
    pub induced: InducedTerms,
    /// Eddy-current terms.
    pub eddy: EddyTerms,
    /// The 3 field-derivative terms $\dot B_j / s$.
    pub field_derivative: bool,
    /// A constant column.
    pub bias: bool,
    /// Scale $s$ dividing the induced and eddy terms, nT.
    pub bt_scale_nt: f64,
}

impl Default for TermSet {
    /// The 18 terms less their isotropic directions (16) with
    /// $s$ = 50 000 nT.
    fn default() -> Self {
        TermSet {
            permanent: true,
            induced: InducedTerms::Traceless,
            eddy: EddyTerms::Traceless,
            field_derivative: false,
            bias: false,
            bt_scale_nt: 50_000.0,
        }
    }
}

/// Axis letters used in term names.
const AXES: [char; 3] = ['x', 'y', 'z'];

/// One column of the design matrix.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Term {
    Permanent(usize),
    Induced(usize, usize),
    /// Traceless diagonal combination `k` of the induced terms.
    InducedDiagonal(usize),
    Eddy(usize, usize),
    /// Traceless diagonal combination `k` of the eddy terms.
    EddyDiagonal(usize),
    FieldDerivative(usize),
    Bias,
}

/// The traceless diagonal combinations: weights on the xx, yy and zz
/// products, orthonormal, so ridge's penalty treats the diagonal evenly.
pub const TRACELESS_DIAGONALS: [[f64; 3]; 2] = [
    [std::f64::consts::FRAC_1_SQRT_2, -std::f64::consts::FRAC_1_SQRT_2, 0.0],
    [0.408_248_290_463_863, 0.408_248_290_463_863, -0.816_496_580_927_726],
];

/// The products a term sums: (weight, factor, factor), at most three.
type Products = ([(f64, usize, usize); 3], usize);

impl Term {
    /// The weighted products of entries of [`Sample::factors`] that make
    /// this term.
    fn products(self) -> Products {
        let one = |a, b| ([(1.0, a, b), (0.0, 9, 9), (0.0, 9, 9)], 1);
        match self {
            Term::Permanent(i) => one(i, 9),
            Term::Induced(i, j) => one(i, 3 + j),
            Term::Eddy(i, j) => one(i, 6 + j),
            Term::FieldDerivative(j) => one(6 + j, 9),
            Term::Bias => one(9, 9),
            Term::InducedDiagonal(k) | Term::EddyDiagonal(k) => {
                let offset = match self {
                    Term::InducedDiagonal(_) => 3,
                    _ => 6,
                };
                let w = TRACELESS_DIAGONALS[k];
                let products = [(w[0], 0, offset), (w[1], 1, offset + 1), (w[2], 2, offset + 2)];
                (products, if w[2] == 0.0 { 2 } else { 3 })
            }
        }
    }

    fn name(self) -> String {
        let diagonal = ["xx-yy", "xx+yy-2zz"];
        match self {
            Term::Permanent(i) => format!("perm_{}", AXES[i]),
            Term::Induced(i, j) => format!("ind_{}{}", AXES[i], AXES[j]),
            Term::InducedDiagonal(k) => format!("ind_{}", diagonal[k]),
            Term::Eddy(i, j) => format!("eddy_{}{}", AXES[i], AXES[j]),
            Term::EddyDiagonal(k) => format!("eddy_{}", diagonal[k]),
            Term::FieldDerivative(j) => format!("dB_{}", AXES[j]),
            Term::Bias => "bias".into(),
        }
    }
}

/// The value of a term from a sample's factors.
#[inline]
fn combine((products, count): &Products, value: impl Fn(usize, usize) -> f64) -> f64 {
    let (w, a, b) = products[0];
    let mut sum = match count {
        1 => value(a, b),
        _ => w * value(a, b),
    };
    for &(w, a, b) in &products[1..*count] {
        sum += w * value(a, b);
    }
    sum
}

impl TermSet {
    /// MagNav.jl's 18 terms (`create_TL_A`'s default), isotropic
    /// directions included, with $s$ = 50 000 nT.
    pub fn magnav() -> Self {
        TermSet {
            induced: InducedTerms::Six,
            eddy: EddyTerms::Nine,
            ..TermSet::default()
        }
    }

    /// The 18 terms less their isotropic directions (16), with
    /// $s$ = 50 000 nT: the default.
    pub fn traceless() -> Self {
        TermSet::default()
    }

    fn terms(&self) -> Vec<Term> {
        let mut terms = Vec::new();
        if self.permanent {
            terms.extend((0..3).map(Term::Permanent));
        }
        let upper = [(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)];
        let induced: &[(usize, usize)] = match self.induced {
            InducedTerms::None => &[],
            InducedTerms::Three => &[(0, 0), (1, 1), (2, 2)],
            InducedTerms::Five => &upper[..5],
            InducedTerms::Six => &upper,
            InducedTerms::Traceless => &[(0, 1), (0, 2), (1, 2)],
        };
        terms.extend(induced.iter().map(|&(i, j)| Term::Induced(i, j)));
        if self.induced == InducedTerms::Traceless {
            terms.extend([Term::InducedDiagonal(0), Term::InducedDiagonal(1)]);
        }
        let all: Vec<(usize, usize)> = (0..3).flat_map(|i| (0..3).map(move |j| (i, j))).collect();
        let off_diagonal: Vec<(usize, usize)> = all.iter().copied().filter(|(i, j)| i != j).collect();
        let eddy: &[(usize, usize)] = match self.eddy {
            EddyTerms::None => &[],
            EddyTerms::Three => &[(0, 0), (1, 1), (2, 2)],
            EddyTerms::Eight => &all[..8],
            EddyTerms::Nine => &all,
            EddyTerms::Traceless => &off_diagonal,
        };
        terms.extend(eddy.iter().map(|&(i, j)| Term::Eddy(i, j)));
        if self.eddy == EddyTerms::Traceless {
            terms.extend([Term::EddyDiagonal(0), Term::EddyDiagonal(1)]);
        }
        if self.field_derivative {
            terms.extend((0..3).map(Term::FieldDerivative));
        }
        if self.bias {
            terms.push(Term::Bias);
        }
        terms
    }

    /// Whether a fit of these terms pins the mean of the interference it
    /// models: no induced term holds the isotropic direction $|B|$, whose
    /// coefficient only the Earth's field's level would set (none, or the
    /// traceless five). The permanent and anisotropic induced means then
    /// follow from how they vary with the attitude.
    pub fn pins_the_level(&self) -> bool {
        matches!(self.induced, InducedTerms::None | InducedTerms::Traceless)
    }

    /// Number of terms (columns).
    pub fn len(&self) -> usize {
        self.terms().len()
    }

    /// True when no term is selected.
    pub fn is_empty(&self) -> bool {
        self.terms().is_empty()
    }

    /// Term names in column order, e.g. `perm_x`, `ind_xy`, `eddy_zx`.
    pub fn names(&self) -> Vec<String> {
        self.terms().into_iter().map(Term::name).collect()
    }

    /// The aircraft's field as a vector, $P + M B$, from fitted
    /// coefficients whose first [`Self::len`] entries are these terms:
    /// P (nT) from the permanent terms and the symmetric soft-iron tensor M
    /// from the induced ones ($a_{ij} = (M_{ij} + M_{ji}) s$ off the
    /// diagonal). Terms the set leaves out count as zero. The first-order
    /// model sees only $u \cdot (P + M B)$, so M is known up to a multiple
    /// of the identity, which adds a field along B and leaves the part
    /// across B (what the second-order term depends on) unchanged.
    pub fn aircraft_field(&self, coefficients: &[f64]) -> ([f64; 3], [[f64; 3]; 3]) {
        let mut permanent = [0.0; 3];
        let mut tensor = [[0.0; 3]; 3];
        for (term, &c) in self.terms().into_iter().zip(coefficients) {
            match term {
                Term::Permanent(i) => permanent[i] = c,
                Term::Induced(i, j) if i == j => tensor[i][i] = c / self.bt_scale_nt,
                Term::Induced(i, j) => {
                    tensor[i][j] = c / (2.0 * self.bt_scale_nt);
                    tensor[j][i] = tensor[i][j];
                }
                Term::InducedDiagonal(k) => {
                    for (i, w) in TRACELESS_DIAGONALS[k].iter().enumerate() {
                        tensor[i][i] += w * c / self.bt_scale_nt;
                    }
                }
                _ => {}
            }
        }
        (permanent, tensor)
    }

    /// The aircraft's eddy-current field per unit of field rate, E (per
    /// sample, as the eddy terms take the rate), from fitted coefficients
    /// whose first [`Self::len`] entries are these terms: the eddy term
    /// $u_i \dot B_j / s$ has coefficient $E_{ij} s$. Terms the set leaves
    /// out count as zero, so E is known, as M is, up to what the scalar
    /// cannot see (a multiple of the identity for the traceless terms).
    pub fn eddy_tensor(&self, coefficients: &[f64]) -> [[f64; 3]; 3] {
        let mut tensor = [[0.0; 3]; 3];
        for (term, &c) in self.terms().into_iter().zip(coefficients) {
            match term {
                Term::Eddy(i, j) => tensor[i][j] = c / self.bt_scale_nt,
                Term::EddyDiagonal(k) => {
                    for (i, w) in TRACELESS_DIAGONALS[k].iter().enumerate() {
                        tensor[i][i] += w * c / self.bt_scale_nt;
                    }
                }
                _ => {}
            }
        }
        tensor
    }

    /// Builds the design matrix for the vector field `field_nt` (x, y, z
    /// components, nT) over `runs`, the contiguous runs of valid samples.
    /// Rows outside every run are `NaN`.
    pub fn design_matrix(&self, field_nt: [&[f64]; 3], runs: &[Range<usize>]) -> DesignMatrix {
        let rows = field_nt[0].len();
        let terms = self.terms();
        let mut columns = vec![vec![f64::NAN; rows]; terms.len()];
        for run in runs {
            let mut views: Vec<&mut [f64]> = columns.iter_mut().map(|c| &mut c[run.clone()]).collect();
            self.fill_run(&terms, field_nt, run.clone(), &mut views);
        }
        DesignMatrix {
            names: terms.into_iter().map(Term::name).collect(),
            columns,
        }
    }

    /// The design columns over one contiguous run of valid samples only
    /// (each column `run.len()` long).
    pub fn design_columns(&self, field_nt: [&[f64]; 3], run: Range<usize>) -> Vec<Vec<f64>> {
        let terms = self.terms();
        let mut columns = vec![vec![0.0; run.len()]; terms.len()];
        let mut views: Vec<&mut [f64]> = columns.iter_mut().map(Vec::as_mut_slice).collect();
        self.fill_run(&terms, field_nt, run, &mut views);
        columns
    }

    fn fill_run(&self, terms: &[Term], field_nt: [&[f64]; 3], run: Range<usize>, columns: &mut [&mut [f64]]) {
        for (offset, row) in run.clone().enumerate() {
            let factors = Sample::within_run(field_nt, &run, row).factors(self.bt_scale_nt);
            for (column, term) in columns.iter_mut().zip(terms) {
                column[offset] = combine(&term.products(), |a, b| factors[a] * factors[b]);
            }
        }
    }

    /// Writes the design columns with indices `columns` for the samples
    /// `rows` of the contiguous run `run` (absolute sample indices) into
    /// interleaved rows, one per sample: column `columns.start + k` goes to
    /// lane `k`. Derivatives are [`central_difference`]s within the run, so
    /// any piece of a run gives the same values as the whole. This feeds the
    /// multi-lane filter chunk by chunk without materialising the columns.
    pub fn fill_lanes<const L: usize>(
        &self,
        field_nt: [&[f64]; 3],
        run: Range<usize>,
        rows: Range<usize>,
        columns: Range<usize>,
        out: &mut [[f64; L]],
    ) {
        let plan: Vec<Products> = self.terms()[columns].iter().map(|term| term.products()).collect();
        let mut groups = [false; 3];
        for (products, count) in &plan {
            for &(_, a, b) in &products[..*count] {
                for factor in [a, b] {
                    if let Some(group) = groups.get_mut(factor / 3) {
                        *group = true;
                    }
                }
            }
        }
        let mut factors = [[0.0; FACTOR_ROWS]; 10];
        factors[9] = [1.0; FACTOR_ROWS];
        for (first, out) in rows.clone().step_by(FACTOR_ROWS).zip(out.chunks_mut(FACTOR_ROWS)) {
            let count = out.len().min(rows.end - first);
            factor_rows(
                field_nt,
                &run,
                first..first + count,
                self.bt_scale_nt,
                groups,
                &mut factors,
            );
            for (lane, term) in plan.iter().enumerate() {
                for (k, row) in out[..count].iter_mut().enumerate() {
                    row[lane] = combine(term, |a, b| factors[a][k] * factors[b][k]);
                }
            }
        }
    }
}

/// Samples whose factors are formed together, in vector registers.
const FACTOR_ROWS: usize = 64;

/// [`Sample::factors`] of the samples `rows` (at most [`FACTOR_ROWS`]) of
/// the run `run`, one array per factor: the same operations, so the same
/// bits, laid out so that the square roots and divisions vectorise. Only
/// the groups marked in `groups` (direction cosines, field, derivative)
/// are written; the constant factor 9 is left to the caller.
fn factor_rows(
    field_nt: [&[f64]; 3],
    run: &Range<usize>,
    rows: Range<usize>,
    scale: f64,
    groups: [bool; 3],
    factors: &mut [[f64; FACTOR_ROWS]; 10],
) {
    let count = rows.len();
    let per_nt = 1.0 / scale;
    for axis in 0..3 {
        let c = field_nt[axis];
        if groups[1] {
            let b = &c[rows.clone()];
            for k in 0..count {
                factors[3 + axis][k] = b[k] * per_nt;
            }
        }
        if !groups[2] {
            continue;
        }
        // Central differences inside the run, one-sided at its ends.
        let interior = rows.start.max(run.start + 1)..rows.end.min(run.end.saturating_sub(1));
        for i in interior.clone() {
            factors[6 + axis][i - rows.start] = (c[i + 1] - c[i - 1]) / 2.0;
        }
        for i in rows.clone().filter(|i| !interior.contains(i)) {
            let difference = match (run.len() < 2, i == run.start, i + 1 == run.end) {
                (true, _, _) => 0.0,
                (false, true, _) => c[i + 1] - c[i],
                (false, _, true) => c[i] - c[i - 1],
                (false, false, false) => (c[i + 1] - c[i - 1]) / 2.0,
            };
            factors[6 + axis][i - rows.start] = difference;
        }
        for factor in &mut factors[6 + axis][..count] {
            *factor *= per_nt;
        }
    }
    if !groups[0] {
        return;
    }
    let (x, y, z) = (
        &field_nt[0][rows.clone()],
        &field_nt[1][rows.clone()],
        &field_nt[2][rows],
    );
    for k in 0..count {
        let total = (x[k] * x[k] + y[k] * y[k] + z[k] * z[k]).sqrt();
        factors[0][k] = x[k] / total;
        factors[1][k] = y[k] / total;
        factors[2][k] = z[k] / total;
    }
}

/// The field, its direction cosines and its derivative at one sample.
struct Sample {
    b: [f64; 3],
    u: [f64; 3],
    db: [f64; 3],
}

impl Sample {
    /// The sample `row` of the run `run`, with the derivative that
    /// [`central_difference`] gives over the run.
    #[inline]
    fn within_run(field_nt: [&[f64]; 3], run: &Range<usize>, row: usize) -> Self {
        let b = [field_nt[0][row], field_nt[1][row], field_nt[2][row]];
        let total = (b[0] * b[0] + b[1] * b[1] + b[2] * b[2]).sqrt();
        let difference = |c: &[f64]| match (run.len() < 2, row == run.start, row + 1 == run.end) {
            (true, _, _) => 0.0,
            (false, true, _) => c[row + 1] - c[row],
            (false, _, true) => c[row] - c[row - 1],
            (false, false, false) => (c[row + 1] - c[row - 1]) / 2.0,
        };
        Sample {
            b,
            u: [b[0] / total, b[1] / total, b[2] / total],
            db: [
                difference(field_nt[0]),
                difference(field_nt[1]),
                difference(field_nt[2]),
            ],
        }
    }

    /// $[u_x, u_y, u_z, B_x/s, B_y/s, B_z/s, \dot B_x/s, \dot B_y/s, \dot B_z/s, 1]$
    /// for the scale s: every term is the product of two of them.
    #[inline]
    fn factors(&self, scale: f64) -> [f64; 10] {
        let [u0, u1, u2] = self.u;
        let [b0, b1, b2] = self.b;
        let [d0, d1, d2] = self.db;
        let per_nt = 1.0 / scale;
        [
            u0,
            u1,
            u2,
            b0 * per_nt,
            b1 * per_nt,
            b2 * per_nt,
            d0 * per_nt,
            d1 * per_nt,
            d2 * per_nt,
            1.0,
        ]
    }
}

/// Per-sample central difference $(x_{k+1} - x_{k-1})/2$, one-sided
/// $x_1 - x_0$ and $x_{n-1} - x_{n-2}$ at the ends; zero for one sample.
pub fn central_difference(samples: &[f64]) -> Vec<f64> {
    let n = samples.len();
    if n < 2 {
        return vec![0.0; n];
    }
    let mut out = Vec::with_capacity(n);
    out.push(samples[1] - samples[0]);
    out.extend(samples.windows(3).map(|w| (w[2] - w[0]) / 2.0));
    out.push(samples[n - 1] - samples[n - 2]);
    out
}

/// Design-matrix columns with their term names.
#[derive(Debug, Clone, PartialEq)]
pub struct DesignMatrix {
    /// Term names, one per column.
    pub names: Vec<String>,
    /// Columns, each one value per flight-log sample (`NaN` where invalid).
    pub columns: Vec<Vec<f64>>,
}

impl DesignMatrix {
    /// The interference $A\beta$ at `row`, nT.
    pub fn predict_row(&self, row: usize, coefficients: &[f64]) -> f64 {
        self.columns.iter().zip(coefficients).map(|(c, b)| c[row] * b).sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The lanes the filter is fed, in pieces of a run that cross the
    /// factor blocks, equal the design columns to the bit.
    #[test]
    fn lanes_equal_the_design_columns() {
        let n = 300;
        let field: Vec<Vec<f64>> = (0..3)
            .map(|axis| {
                (0..n)
                    .map(|k| 20_000.0 * ((k as f64 * 0.013 + axis as f64).sin()) + 300.0 * axis as f64)
                    .collect()
            })
            .collect();
        let field_nt = [field[0].as_slice(), field[1].as_slice(), field[2].as_slice()];
        for (terms, run) in [TermSet::traceless(), TermSet::magnav()]
            .into_iter()
            .flat_map(|terms| [10..290, 7..8, 0..n].map(|run| (terms, run)))
        {
            let columns = terms.design_columns(field_nt, run.clone());
            for piece in [run.start..run.end, run.start + run.len() / 3..run.end] {
                for group in [0..8, 8..16, 16..terms.len()] {
                    let mut out = vec![[f64::NAN; 8]; piece.len()];
                    terms.fill_lanes(field_nt, run.clone(), piece.clone(), group.clone(), &mut out);
                    for (offset, row) in out.iter().enumerate() {
                        for (lane, column) in group.clone().enumerate() {
                            let expected = columns[column][piece.start - run.start + offset];
                            assert_eq!(row[lane].to_bits(), expected.to_bits(), "run {run:?} column {column}");
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn classic_model_has_18_terms_in_magnav_order() {
        let names = TermSet::magnav().names();
        assert_eq!(names.len(), 18);
        assert_eq!(&names[..4], ["perm_x", "perm_y", "perm_z", "ind_xx"]);
        assert_eq!(names[8], "ind_zz");
        assert_eq!(names[10], "eddy_xy");
        assert_eq!(names[17], "eddy_zz");
    }

    /// The default's 16 terms are the 18 less the isotropic directions: a
    /// traceless induced tensor and eddy tensor predict the same through
    /// both, and the aircraft's field comes back from the 16.
    #[test]
    fn the_traceless_terms_are_the_eighteen_less_the_isotropic_ones() {
        let traceless = TermSet::traceless();
        assert_eq!(
            traceless.names(),
            [
                "perm_x",
                "perm_y",
                "perm_z",
                "ind_xy",
                "ind_xz",
                "ind_yz",
                "ind_xx-yy",
                "ind_xx+yy-2zz",
                "eddy_xy",
                "eddy_xz",
                "eddy_yx",
                "eddy_yz",
                "eddy_zx",
                "eddy_zy",
                "eddy_xx-yy",
                "eddy_xx+yy-2zz"
            ]
        );
        let s = traceless.bt_scale_nt;
        let induced = [[0.004, -0.002, 0.003], [-0.002, -0.007, 0.001], [0.003, 0.001, 0.003]];
        let eddy = [[0.02, 0.01, -0.03], [0.005, 0.01, 0.02], [-0.01, 0.04, -0.03]];
        let permanent = [120.0, -80.0, 45.0];
        // MagNav's 18: ind_ij = (M_ij + M_ji)·s off the diagonal.
        let mut eighteen = permanent.to_vec();
        for (i, j) in [(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)] {
            eighteen.push(if i == j {
                induced[i][i] * s
            } else {
                2.0 * induced[i][j] * s
            });
        }
        eighteen.extend((0..9).map(|k| eddy[k / 3][k % 3] * s));
        let diagonal =
            |m: &[[f64; 3]; 3], k: usize| (0..3).map(|i| TRACELESS_DIAGONALS[k][i] * m[i][i] * s).sum::<f64>();
        let mut sixteen = permanent.to_vec();
        sixteen.extend([
            2.0 * induced[0][1] * s,
            2.0 * induced[0][2] * s,
            2.0 * induced[1][2] * s,
        ]);
        sixteen.extend([diagonal(&induced, 0), diagonal(&induced, 1)]);
        sixteen.extend([(0, 1), (0, 2), (1, 0), (1, 2), (2, 0), (2, 1)].map(|(i, j)| eddy[i][j] * s));
        sixteen.extend([diagonal(&eddy, 0), diagonal(&eddy, 1)]);
        let n = 200;
        let field: Vec<Vec<f64>> = (0..3)
            .map(|axis| {
                (0..n)
                    .map(|k| {
                        30_000.0 * ((k as f64 * 0.05 + 2.0 * axis as f64).sin())
                            + 20_000.0 * (axis == 2) as usize as f64
                    })
                    .collect()
            })
            .collect();
        let field_nt = [field[0].as_slice(), field[1].as_slice(), field[2].as_slice()];
        let whole = 0..n;
        let runs = std::slice::from_ref(&whole);
        let a16 = traceless.design_matrix(field_nt, runs);
        let a18 = TermSet::magnav().design_matrix(field_nt, runs);
        for row in 0..n {
            let (p16, p18) = (a16.predict_row(row, &sixteen), a18.predict_row(row, &eighteen));
            assert!((p16 - p18).abs() < 1e-9 * p18.abs().max(1.0), "{row}: {p16} vs {p18}");
        }
        let (_, tensor) = traceless.aircraft_field(&sixteen);
        for i in 0..3 {
            for j in 0..3 {
                assert!((tensor[i][j] - induced[i][j]).abs() < 1e-15, "{i}{j}");
            }
        }
    }

    #[test]
    fn variants_have_the_documented_sizes() {
        let mut set = TermSet {
            induced: InducedTerms::Five,
            eddy: EddyTerms::Eight,
            ..TermSet::default()
        };
        assert_eq!(set.len(), 16);
        assert!(!set.names().contains(&"ind_zz".to_string()));
        set.induced = InducedTerms::Three;
        set.eddy = EddyTerms::Three;
        set.field_derivative = true;
        set.bias = true;
        assert_eq!(
            set.names()[3..].to_vec(),
            ["ind_xx", "ind_yy", "ind_zz", "eddy_xx", "eddy_yy", "eddy_zz", "dB_x", "dB_y", "dB_z", "bias"]
        );
    }

    #[test]
    fn permanent_terms_are_unit_direction_cosines() {
        let field = [vec![30_000.0, 0.0], vec![40_000.0, 0.0], vec![0.0, 50_000.0]];
        let a = TermSet::magnav().design_matrix([&field[0], &field[1], &field[2]], std::slice::from_ref(&(0..2)));
        assert_eq!([a.columns[0][0], a.columns[1][0], a.columns[2][0]], [0.6, 0.8, 0.0]);
        // u_x B_y / s = 0.6 · 40 000 / 50 000
        assert!((a.columns[4][0] - 0.48).abs() < 1e-15);
        // one-sided difference of B_z at both ends: 50 000 nT per sample
        assert!((a.columns[17][1] - 1.0).abs() < 1e-15);
    }

    #[test]
    fn central_difference_of_a_quadratic_is_exact_inside() {
        let x: Vec<f64> = (0..6).map(|k| (k * k) as f64).collect();
        assert_eq!(central_difference(&x), vec![1.0, 2.0, 4.0, 6.0, 8.0, 9.0]);
    }
}
