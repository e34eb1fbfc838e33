//! The vector stage: the twelve-constant model of each fluxgate, fitted
//! on the calibration, and its compensated vectors.

use crate::ingest::flight_log::FlightLog;
use crate::messages::{Note, VectorSummary, Warning};
use crate::model::FitOptions;

/// What the vector stage produced: models, compensated vectors, words.
#[derive(Default)]
pub(super) struct VectorStage {
    pub(super) models: Vec<crate::vector::VectorModel>,
    pub(super) compensated: Vec<crate::vector::CompensatedVector>,
    pub(super) notes: Vec<Note>,
    pub(super) warnings: Vec<Warning>,
}

/// Fitted direction further than this from IGRF's, degrees: a warning (a
/// wrong attitude convention, date or position, a box without pitches and
/// rolls, or a fluxgate the twelve constants do not describe). IGRF's
/// direction at survey height is good to about 0.1° away from strong
/// anomalies, and on simulated flights the fit lands within 0.2° of it;
/// 0.5° is F·sin 0.5° ≈ 450 nT across the field at 50 000 nT.
pub(super) const VECTOR_DIRECTION_WARNING_DEG: f64 = 0.5;

/// The reference channel's aircraft field swinging by more than this over
/// the box (RMS, nT), or its pinned level's sigma above it, is a warning:
/// the vector's scale rests on its level.
pub(super) const VECTOR_SWING_WARNING_NT: f64 = 10.0;

/// The reference of the vector stage ([`vector_fits`]): the scalar channel
/// with the least aircraft field over the box, its field's size on every
/// row, when `[vector] enabled` and the flight records an INS attitude.
/// Otherwise the stage as it ends: empty when the stage is off, with a
/// note without an attitude, a warning without a reference. It reads the
/// channels' interference only, so the fits that follow need nothing more
/// of the compensation and run beside the channels' assessment.
pub(super) fn vector_reference(
    log: &FlightLog,
    (windows, boxes): (&[crate::calibration::windows::CalibrationWindow], &[(f64, f64)]),
    (compensation, models): (&crate::compensate::Compensation, &[crate::model::FittedModel]),
    options: &crate::vector::VectorOptions,
) -> Result<crate::vector::Reference, VectorStage> {
    let mut stage = VectorStage::default();
    if !options.enabled {
        return Err(stage);
    }
    if log.attitude().is_none() {
        stage.notes.push(Note::NoVectorAttitude);
        return Err(stage);
    }
    // The reference is the channel with the least aircraft field over the
    // box: its level, which the vector's scale rests on, is the surest.
    let reference = compensation
        .channels
        .iter()
        .filter_map(|c| {
            let recorded = log.channel(&c.channel)?.values.as_slice();
            let scalar = compensated_scalar(c, recorded);
            let model = models.iter().find(|m| m.channel == c.channel);
            let pinned = model.is_some_and(|m| m.spec.terms.pins_the_level());
            let mut reference = crate::vector::Reference::levelled(
                log,
                (&c.channel, pinned),
                (&scalar, &c.interference_nt),
                (windows, boxes),
            )?;
            if let Some(model) = model.filter(|_| pinned) {
                let (_, induced) = model.spec.terms.aircraft_field(&model.coefficients);
                let field_nt = crate::model::column_level(&reference.total_nt);
                reference.level_sigma_nt = Some(crate::vector::Reference::level_sigma_nt(&induced, field_nt));
            }
            Some(reference)
        })
        .filter(|r| r.swing_nt.is_finite())
        .min_by(|a, b| a.swing_nt.total_cmp(&b.swing_nt));
    reference.ok_or_else(|| {
        stage.warnings.push(Warning::VectorNoReference);
        stage
    })
}

/// The scalar reading `channel`'s compensation subtracted its interference
/// from, on every row: the recorded reading with what the diagnosis
/// applied to the reading itself (a sensor lag undone), so that the
/// reference and the interference it is levelled by are of the same
/// instants. A late reference taken as recorded puts the lag's error, the
/// interference's and the field's rate times the lag, into every
/// component of the vector. The recorded reading where the compensation
/// has no value (a flagged row).
fn compensated_scalar(channel: &crate::compensate::CompensatedChannel, recorded: &[f64]) -> Vec<f64> {
    (channel.values.iter().zip(&channel.interference_nt).zip(recorded))
        .map(|((&value, &interference), &recorded)| {
            let scalar = value + interference - channel.level_offset_nt;
            if scalar.is_finite() {
                scalar
            } else {
                recorded
            }
        })
        .collect()
}

/// Vector-compensates every fluxgate of `log` with the twelve-constant
/// model fitted on `windows`, the field's size from `reference`
/// ([`vector_reference`]). A fluxgate whose fit fails is a warning, not an
/// error: the scalar outputs stand.
pub(super) fn vector_fits(
    log: &FlightLog,
    (windows, boxes): (&[crate::calibration::windows::CalibrationWindow], &[(f64, f64)]),
    reference: &crate::vector::Reference,
    (options, fit_options): (&crate::vector::VectorOptions, &FitOptions),
) -> VectorStage {
    let mut stage = VectorStage::default();
    for sensor in log.vector_sensors() {
        let stage_options = options.tolles_lawson.then_some(fit_options);
        let fitted = crate::vector::fit(
            log,
            &sensor,
            (windows, boxes),
            reference,
            (options.site.as_ref(), stage_options),
        )
        .and_then(|model| Ok((model.compensate(log)?, model)));
        match fitted {
            Ok((compensated, mut model)) => {
                model.reference_level = crate::vector::ReferenceLevel {
                    pinned: reference.pinned,
                    sigma_nt: reference.level_sigma_nt,
                    component_sigma_nt: (reference.level_sigma_nt).map(|sigma| along_the_field(&compensated, sigma)),
                };
                stage
                    .notes
                    .push(Note::VectorCompensated(Box::new(vector_summary(&model))));
                stage.warnings.extend(vector_model_warnings(&model));
                stage.compensated.push(compensated);
                stage.models.push(model);
            }
            Err(e) => stage.warnings.push(Warning::VectorNotCompensated {
                sensor: sensor.prefix.clone(),
                model: None,
                reason: e.to_string(),
            }),
        }
    }
    stage
}

/// A level's sigma `sigma` (nT) per body-axis component of `vector`: it
/// scales the field, so each component by its share, RMS over the rows.
fn along_the_field(vector: &crate::vector::CompensatedVector, sigma: f64) -> [f64; 3] {
    let [x, y, z] = &vector.body_nt;
    let mut squares = [0.0; 3];
    let mut count = 0usize;
    for k in 0..x.len() {
        let b = [x[k], y[k], z[k]];
        let size = b.iter().map(|v| v * v).sum::<f64>().sqrt();
        if !(size.is_finite() && size > 0.0) {
            continue;
        }
        for (square, v) in squares.iter_mut().zip(b) {
            *square += (v / size).powi(2);
        }
        count += 1;
    }
    squares.map(|square| sigma * (square / count.max(1) as f64).sqrt())
}

/// What a fitted vector model must say: a scale resting on a swinging
/// level, a direction far from IGRF-14's, a sign unverified or axes
/// left-handed, no heading held out, the eddy stage's own warning.
fn vector_model_warnings(model: &crate::vector::VectorModel) -> Vec<Warning> {
    let mut warnings = Vec::new();
    // A pinned level is as sure as its stated sigma; one kept at the
    // recorded mean, as its swing suggests.
    match model.reference_level.sigma_nt {
        Some(sigma_nt) if sigma_nt > VECTOR_SWING_WARNING_NT => warnings.push(Warning::VectorLevelUncertain {
            sensor: model.sensor.clone(),
            reference: model.reference.clone(),
            sigma_nt,
        }),
        None if model.reference_swing_nt > VECTOR_SWING_WARNING_NT => warnings.push(Warning::VectorScaleSwings {
            sensor: model.sensor.clone(),
            reference: model.reference.clone(),
            swing_nt: model.reference_swing_nt,
        }),
        _ => {}
    }
    if let Some(warning) = vector_direction_warning(model) {
        warnings.push(warning);
    }
    warnings.extend(vector_sign_warning(model));
    if model.held_out.is_none() {
        warnings.push(Warning::VectorNotHeldOut {
            sensor: model.sensor.clone(),
        });
    }
    if let Some(reason) = &model.tolles_lawson_warning {
        warnings.push(Warning::VectorTollesLawson {
            sensor: model.sensor.clone(),
            reason: reason.clone(),
        });
    }
    warnings
}

/// Windows closer than this are taken as one box's, and the flight
/// between them (the turns between legs) as the box's too, s.
pub(super) const BOX_GAP_S: f64 = 150.0;

/// The spans of given windows (no detection): windows less than
/// [`BOX_GAP_S`] apart joined, the flight between them included.
pub(super) fn window_hulls(windows: &[crate::calibration::windows::CalibrationWindow]) -> Vec<(f64, f64)> {
    let mut spans: Vec<(f64, f64)> = windows.iter().map(|w| (w.t_start, w.t_end)).collect();
    spans.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut hulls: Vec<(f64, f64)> = Vec::new();
    for (t0, t1) in spans {
        match hulls.last_mut() {
            Some(last) if t0 - last.1 <= BOX_GAP_S => last.1 = last.1.max(t1),
            _ => hulls.push((t0, t1)),
        }
    }
    hulls
}

/// What the vector stage says of a fitted model.
pub(super) fn vector_summary(model: &crate::vector::VectorModel) -> VectorSummary {
    let igrf = match model.start {
        crate::vector::FieldStart::Igrf {
            inclination_deg,
            declination_deg,
            position,
            ..
        } => Some((
            position == crate::vector::PositionSource::Site,
            inclination_deg,
            declination_deg,
        )),
        _ => None,
    };
    VectorSummary {
        sensor: model.sensor.clone(),
        rows: model.rows,
        reference: model.reference.clone(),
        reference_swing_nt: model.reference_swing_nt,
        reference_level: (model.reference_level.sigma_nt).zip(model.reference_level.component_sigma_nt),
        residual_rms_nt: model.residual_rms_nt,
        held_out: model.held_out.as_ref().map(|held| (held.headings, held.rms_nt)),
        inclination_deg: model.inclination_deg,
        declination_deg: model.declination_deg,
        igrf,
        mounting: model.mounting.describe(),
        eddy: model
            .tolles_lawson
            .as_ref()
            .map(|stage| crate::messages::vector::VectorEddy {
                before_nt: stage.band_rms_before_nt,
                after_nt: stage.band_rms_after_nt,
                held_out: stage.held_out.as_ref().map(|held| (held.before_nt, held.after_nt)),
            }),
    }
}

/// A warning when the field's sign could not be checked (no position, no
/// `[site]`), or when IGRF-14 fixed it and the fluxgate's axes came out
/// left-handed.
pub(super) fn vector_sign_warning(model: &crate::vector::VectorModel) -> Option<Warning> {
    use crate::vector::FieldSign;
    let sensor = model.sensor.clone();
    match model.field_sign {
        FieldSign::RightHandedAxes => Some(Warning::VectorSignUnverified {
            sensor,
            inclination_deg: model.inclination_deg,
            declination_deg: model.declination_deg,
            mounting: model.mounting.describe(),
        }),
        FieldSign::Igrf if !model.mounting.right_handed => Some(Warning::VectorLeftHanded { sensor }),
        FieldSign::Igrf => match model.start {
            crate::vector::FieldStart::Igrf {
                position: crate::vector::PositionSource::Site,
                ..
            } => Some(Warning::VectorAtSiteOnly { sensor }),
            _ => None,
        },
    }
}

/// A warning when the fitted field direction is further than
/// [`VECTOR_DIRECTION_WARNING_DEG`] from IGRF's (the angle between them).
pub(super) fn vector_direction_warning(model: &crate::vector::VectorModel) -> Option<Warning> {
    let crate::vector::FieldStart::Igrf {
        inclination_deg,
        declination_deg,
        dated,
        total_nt,
        ..
    } = model.start
    else {
        return None;
    };
    let unit = |inclination: f64, declination: f64| {
        let (i, d) = (inclination.to_radians(), declination.to_radians());
        nalgebra::Vector3::new(i.cos() * d.cos(), i.cos() * d.sin(), i.sin())
    };
    let angle = unit(model.inclination_deg, model.declination_deg)
        .angle(&unit(inclination_deg, declination_deg))
        .to_degrees();
    let d_incl = model.inclination_deg - inclination_deg;
    let d_decl = (model.declination_deg - declination_deg + 540.0).rem_euclid(360.0) - 180.0;
    (angle > VECTOR_DIRECTION_WARNING_DEG).then(|| Warning::VectorDirectionOff {
        sensor: model.sensor.clone(),
        angle_deg: angle,
        inclination_off_deg: d_incl,
        declination_off_deg: d_decl,
        bound_deg: VECTOR_DIRECTION_WARNING_DEG,
        dated,
        across_nt: total_nt * angle.to_radians().sin(),
    })
}
