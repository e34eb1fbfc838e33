//! Extension columns beside the Tolles-Lawson terms: a coupled current's
//! field recovered as a body-frame vector.

use magcomp::model::terms::TermSet;
use magcomp::model::{fit, Extensions, FitOptions, FittedModel, ModelSpec, SourceTerm};
use magcomp::pipeline::choose_vector_sensor;
use magcomp::quality::standard_deviation;
use magcomp::simulate::scenario::{Effect, RawScenario, Scenario};
use magcomp::simulate::simulate;

#[test]
fn a_coupled_current_is_recovered_as_its_body_frame_vector() {
    let coupling = [0.8, -0.5, 1.2];
    let mut raw = RawScenario {
        seed: 11,
        ..RawScenario::default()
    };
    raw.survey.line_count = 1;
    raw.effect.push(Effect::AuxCoupling {
        channel: "mag_1_uc".into(),
        source: "cur_ail".into(),
        nt_per_unit: coupling,
        nt_per_unit_per_s: [0.0; 3],
    });
    let flight = simulate(&Scenario::try_from(raw).unwrap()).unwrap();
    let log = &flight.log;
    let sensor = choose_vector_sensor(log, Some("flux_a")).unwrap();
    // I·u_i: the wire's field fixed in the body frame, seen along the Earth
    // field's direction by the scalar sensor (taken about a level of 0 A).
    let coupled = ModelSpec::new(
        TermSet::default(),
        Extensions {
            sources: vec![SourceTerm::AuxCoupling {
                column: "cur_ail".into(),
                level: 0.0,
            }],
            ..Extensions::default()
        },
    );
    let windows = flight.truth.calibration_windows(5.0);
    let options = FitOptions::default();
    let stores = Default::default();
    let plain = fit(
        log,
        &sensor,
        "mag_1_uc",
        &windows,
        &ModelSpec::default(),
        &options,
        &stores,
    )
    .unwrap();
    let extended = fit(log, &sensor, "mag_1_uc", &windows, &coupled, &options, &stores).unwrap();
    assert_eq!(extended.term_names.len(), 19);
    assert_eq!(&extended.term_names[16..], &["cur_ail_x", "cur_ail_y", "cur_ail_z"]);
    let residual = |m: &FittedModel| {
        standard_deviation(
            &m.windows
                .iter()
                .flat_map(|w| w.band_after_nt.clone())
                .collect::<Vec<_>>(),
        )
    };
    println!(
        "plain {:.4} nT, extended {:.4} nT, coupling {:?}",
        residual(&plain),
        residual(&extended),
        &extended.coefficients[16..]
    );
    // The aileron current follows the roll rate, so on the box it is well
    // excited: the vector comes back to 10 % of its size, and the residual
    // falls to the clean flight's floor (0.016 nT for this seed).
    for (found, true_value) in extended.coefficients[16..].iter().zip(coupling) {
        assert!((found - true_value).abs() < 0.1 * 1.55, "{found} vs {true_value}");
    }
    assert!(residual(&extended) < 0.02 && residual(&plain) > 3.0 * residual(&extended));
    // Held out on its own windows, the model predicts what it fitted.
    let held = extended.held_out(log, &sensor, &windows, &options).unwrap();
    for (a, b) in held.iter().zip(&extended.windows) {
        for (x, y) in a.band_after_nt.iter().zip(&b.band_after_nt) {
            assert!((x - y).abs() < 1e-9);
        }
    }
}
