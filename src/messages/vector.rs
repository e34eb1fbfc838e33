//! What the vector stage says of each fluxgate it compensated: the
//! twelve-constant model's figures, as a [`VectorSummary`].

use std::fmt;

/// A fluxgate vector-compensated with the twelve-constant model.
#[derive(Debug, Clone, PartialEq)]
pub struct VectorSummary {
    /// The fluxgate.
    pub sensor: String,
    /// Calibration rows fitted.
    pub rows: usize,
    /// The scalar channel giving the field's size.
    pub reference: String,
    /// Its modelled interference's swing over the box, RMS nT.
    pub reference_swing_nt: f64,
    /// Where its level is pinned by its modelled interference: the level's
    /// sigma, nT, and that sigma per body-axis component over the flight.
    pub reference_level: Option<(f64, [f64; 3])>,
    /// Residual per component, nT.
    pub residual_rms_nt: [f64; 3],
    /// Held out by heading: the headings and the residual per component, nT.
    pub held_out: Option<(usize, [f64; 3])>,
    /// The fitted Earth field's inclination, degrees.
    pub inclination_deg: f64,
    /// Its declination, degrees.
    pub declination_deg: f64,
    /// IGRF-14's direction where the fit started from it: (at the
    /// `[site]` rather than the recorded position, inclination, declination).
    pub igrf: Option<(bool, f64, f64)>,
    /// The fluxgate's mounting, in words.
    pub mounting: String,
    /// The vector Tolles-Lawson stage (eddy currents, per axis): the
    /// band-passed residual before and after, and held out by heading.
    pub eddy: Option<VectorEddy>,
}

/// The band-passed residual per axis of the vector Tolles-Lawson stage, nT.
#[derive(Debug, Clone, PartialEq)]
pub struct VectorEddy {
    /// Before, per axis.
    pub before_nt: [f64; 3],
    /// After, per axis.
    pub after_nt: [f64; 3],
    /// Held out by heading: before and after, per axis.
    pub held_out: Option<([f64; 3], [f64; 3])>,
}

/// "x/y/z" to two decimals.
fn axes(v: [f64; 3]) -> String {
    format!("{:.2}/{:.2}/{:.2}", v[0], v[1], v[2])
}

impl fmt::Display for VectorSummary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let [x, y, z] = self.residual_rms_nt;
        match self.reference_level {
            Some((sigma, [sx, sy, sz])) => write!(
                f,
                "{}: vector-compensated with the twelve-constant model on {} calibration rows, the field's size from {} less its whole modelled interference (its terms pin the interference's mean; its modelled interference swings by {:.2} nT RMS over the box); the aircraft's isotropic induced field at that sensor, which no manoeuvre shows, leaves the level uncertain by ±{sigma:.2} nT, which scales the vector: ±{sx:.2}/{sy:.2}/{sz:.2} nT on x/y/z; residual x/y/z {x:.2}/{y:.2}/{z:.2} nT",
                self.sensor, self.rows, self.reference, self.reference_swing_nt
            )?,
            None => write!(
                f,
                "{}: vector-compensated with the twelve-constant model on {} calibration rows, the field's size from {} levelled at its recorded mean over the box (the aircraft's mean field at that sensor, which no manoeuvre pins, scales the vector: δ nT there is up to δ nT on a component; its modelled interference swings by {:.2} nT RMS over the box): residual x/y/z {x:.2}/{y:.2}/{z:.2} nT",
                self.sensor, self.rows, self.reference, self.reference_swing_nt
            )?,
        }
        if let Some((headings, [x, y, z])) = self.held_out {
            write!(f, ", held out by heading ({headings} headings) {x:.2}/{y:.2}/{z:.2} nT")?;
        }
        write!(
            f,
            "; Earth field inclination {:.3}°, declination {:.3}°",
            self.inclination_deg, self.declination_deg
        )?;
        if let Some((at_site, inclination, declination)) = self.igrf {
            let at = if at_site { " at the [site]" } else { "" };
            write!(f, " (IGRF-14{at}: {inclination:.3}°, {declination:.3}°)")?;
        }
        write!(f, "; {}", self.mounting)?;
        if let Some(eddy) = &self.eddy {
            write!(
                f,
                "; vector Tolles-Lawson (eddy currents, per axis): band-passed residual x/y/z {} → {} nT",
                axes(eddy.before_nt),
                axes(eddy.after_nt)
            )?;
            if let Some((before, after)) = eddy.held_out {
                write!(f, ", held out by heading {} → {} nT", axes(before), axes(after))?;
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A summary without a held-out figure, IGRF start or eddy stage.
    fn summary() -> VectorSummary {
        VectorSummary {
            sensor: "flux_a".into(),
            rows: 4200,
            reference: "mag_1_uc".into(),
            reference_swing_nt: 1.234,
            reference_level: None,
            residual_rms_nt: [1.0, 2.0, 3.0],
            held_out: None,
            inclination_deg: 70.1234,
            declination_deg: -12.5,
            igrf: None,
            mounting: "mounted as the aircraft's axes".into(),
            eddy: None,
        }
    }

    #[test]
    fn a_vector_summary_reads_as_the_vector_stage_has_always_said_it() {
        let mut summary = summary();
        assert_eq!(
            summary.to_string(),
            "flux_a: vector-compensated with the twelve-constant model on 4200 calibration rows, the field's size from mag_1_uc levelled at its recorded mean over the box (the aircraft's mean field at that sensor, which no manoeuvre pins, scales the vector: δ nT there is up to δ nT on a component; its modelled interference swings by 1.23 nT RMS over the box): residual x/y/z 1.00/2.00/3.00 nT; Earth field inclination 70.123°, declination -12.500°; mounted as the aircraft's axes"
        );
        summary.held_out = Some((4, [1.5, 2.5, 3.5]));
        summary.igrf = Some((true, 70.0, -12.0));
        summary.eddy = Some(VectorEddy {
            before_nt: [4.0, 5.0, 6.0],
            after_nt: [0.4, 0.5, 0.6],
            held_out: Some(([4.1, 5.1, 6.1], [0.41, 0.51, 0.61])),
        });
        let text = summary.to_string();
        assert!(
            text.contains("nT, held out by heading (4 headings) 1.50/2.50/3.50 nT; Earth field"),
            "{text}"
        );
        assert!(
            text.contains("declination -12.500° (IGRF-14 at the [site]: 70.000°, -12.000°); mounted"),
            "{text}"
        );
        assert!(text.ends_with("; vector Tolles-Lawson (eddy currents, per axis): band-passed residual x/y/z 4.00/5.00/6.00 → 0.40/0.50/0.60 nT, held out by heading 4.10/5.10/6.10 → 0.41/0.51/0.61 nT"), "{text}");
    }

    #[test]
    fn a_pinned_reference_level_is_stated_with_its_sigma_per_component() {
        let summary = VectorSummary {
            reference_level: Some((4.5, [1.0, 2.0, 4.0])),
            ..summary()
        };
        let text = summary.to_string();
        assert!(
            text.contains("the field's size from mag_1_uc less its whole modelled interference"),
            "{text}"
        );
        assert!(
            text.contains("leaves the level uncertain by ±4.50 nT, which scales the vector: ±1.00/2.00/4.00 nT on x/y/z; residual"),
            "{text}"
        );
    }
}
